"""What the doc-figure tests share (tests/docs/): a doc's text with its whitespace normalised, a committed
result of docs/results/, and a figure formatted as the docs write it, so that a test reads the JSON and
asserts that the doc's sentence holds the JSON's figure."""

from __future__ import annotations

import functools
import json
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


@functools.cache
def doc(path: str) -> str:
    """The doc at `path` (from the repository's root), its whitespace runs made one space."""
    return " ".join((ROOT / path).read_text().split())


@functools.cache
def result(name: str) -> Any:
    """docs/results/`name`, parsed."""
    return json.loads((RESULTS / name).read_text())


def _rounded(d: Decimal, digits: int) -> str:
    return str(d.quantize(Decimal(1).scaleb(-digits), ROUND_HALF_EVEN))


def num(x: float, digits: int = 1) -> str:
    """`x` to `digits` decimals as written in the JSON (its repr, not the binary float), a half to the even
    digit as Python's round() does: 0.625 -> '0.62', 0.0455 -> '0.046'."""
    return _rounded(Decimal(repr(x)), digits)


def pct(x: float, digits: int = 1) -> str:
    """A share as the docs write a percentage: 0.7009 -> '70.1', with digits=0 '70'; 0.625 -> '62'."""
    return _rounded(Decimal(repr(x)) * 100, digits)


def missing(text: str, fragments: list[str]) -> list[str]:
    """The fragments (whitespace normalised) that `text` does not hold: a test asserts it is empty."""
    return [f for f in fragments if " ".join(f.split()) not in text]
