"""scripts/page_screenshot.py, the README's picture of the page: the service's page in headless chromium
with the demo robot's answer drawn, saved as a palette PNG."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow  # a real server with the demo objects, and a browser


def test_the_page_is_shot_with_an_answer_drawn(tmp_path: Path) -> None:
    out = tmp_path / "page.png"
    command = [sys.executable, "scripts/page_screenshot.py", "--out", str(out), "--level", "0"]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    page = Image.open(out)
    assert page.mode == "P" and page.width == 1024  # a palette image of the page at its width
    assert 300 < page.height <= 1600
    assert len(page.getcolors(256) or []) > 8  # the page, drawn: not one flat colour
