"""scripts/answers_picture.py, the README's picture: a real LM-O frame searched whole, drawn twice (the
template's pose, the fitted pose), with the shipped models; one object registered to keep it short."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[2]
LMO = ROOT.parent / "shared" / "data" / "lmo"

# registers a real LM-O object and searches a real frame whole: `make test`, not `make check`
pytestmark = pytest.mark.slow


def test_the_picture_is_two_frames_side_by_side(tmp_path):
    if not (LMO / "models" / "models_info.json").is_file():
        pytest.skip(f"LM-O not present at {LMO}")
    out = tmp_path / "answers.jpg"
    command = [sys.executable, "scripts/answers_picture.py", "--dataset", str(LMO), "--frame", "808"]
    done = subprocess.run(
        [*command, "--objects", "1", "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    picture = cv2.imread(str(out))
    assert picture.shape[1] == 1280 and 400 < picture.shape[0] < 500  # two 640 x 480 frames, halved
    left, right = picture[:, :636], picture[:, 644:]
    assert abs(left.astype(float) - right.astype(float)).mean() < 20  # the same frame twice
