"""The evaluation's progress bars: shown on a terminal, silent in logs and tests (tqdm's disable=None)."""

from __future__ import annotations

from tqdm import tqdm


def bar(total: int, desc: str, unit: str = "patch") -> tqdm:
    return tqdm(total=total, desc=desc, unit=unit, disable=None, leave=False)
