"""scripts/docs_pictures.py, the README's and docs/templates.md's pictures: real LM-O patches above their
templates and the sensor model's version of them, and a strip of one object's templates."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[2]
LMO = ROOT.parent / "shared" / "data" / "lmo"

pytestmark = pytest.mark.slow  # renders every LM-O object


def test_both_pictures_are_written_at_their_sizes(tmp_path: Path) -> None:
    if not (LMO / "models" / "models_info.json").is_file():
        pytest.skip(f"LM-O not present at {LMO}")
    command = [sys.executable, "scripts/docs_pictures.py", "--lmo", str(LMO), "--out", str(tmp_path)]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    grid = cv2.imread(str(tmp_path / "real_vs_template.png"))
    # three rows of 64 px patches (real, template, through the sensor model), one column an object, x2
    assert grid.shape[0] == 3 * 64 * 2 and grid.shape[1] % (64 * 2) == 0 and grid.shape[1] >= 64 * 2
    strip = cv2.imread(str(tmp_path / "templates.png"))
    assert strip.shape[0] == 2 * 64 and strip.shape[1] == 19 * 64  # colour above depth, 19 viewpoints
    assert strip[:64].std() > 5  # an object was rendered, not an empty strip
