"""docs/page.png: the web page at `/` with an answer drawn, as a person sees it 1024 px wide.

Serves the shipped models with the demo objects on a temporary data dir (as `make serve` does), loads the
example frame on the page, clicks on the robot, waits for the drawn answer and its list, and saves the
page (reduced to a palette, to keep the file small).

    PYTHONPATH=$PWD .venv/bin/python scripts/page_screenshot.py [--out docs/page.png]
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "helpers"))

from browser import HANG, OBJECT_UV, WIDTH, chromium, click_on_frame, drawn_width  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402
from service_helpers import Server, W  # noqa: E402

HEIGHT = 1600  # the window: the header and the recognition section (fields, images, answers) fit in it
COLOURS = 128  # palette size: the page is flat colours and two small frames; ~150 kB instead of ~600


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "page.png")
    ap.add_argument("--level", default="2", help="POSEDESC_LEVEL of the server (the demo objects' templates)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        env = {"POSEDESC_DEMO_OBJECTS": "true", "POSEDESC_LEVEL": args.level}
        with Server(Path(tmp) / "data", ROOT / "models", env) as server:
            server.wait_ready(timeout=600)
            browser = chromium(WIDTH, HEIGHT)
            try:
                page = shoot(browser, server.url)
            finally:
                browser.quit()
            server.stop()
    image = page.quantize(COLOURS, method=Image.Quantize.MEDIANCUT)
    image.save(args.out, optimize=True)
    print(f"{args.out}: {image.width} x {image.height}, {args.out.stat().st_size / 1024:.0f} kB")


def shoot(b, url: str) -> Image.Image:
    """The page from its top to the end of the recognition section, a drawn answer in it."""
    wait = WebDriverWait(b, HANG)
    b.get(f"{url}/")
    b.find_element(By.ID, "example-frame").click()
    wait.until(lambda d: d.execute_script("return document.getElementById('frame').naturalWidth") == W)
    click_on_frame(b, OBJECT_UV)
    wait.until(lambda d: drawn_width(d) == W)
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#answers tbody tr"))
    b.execute_script("window.scrollTo(0, 0)")
    bottom = b.execute_script(
        "return document.querySelector(\"section[aria-labelledby='rec-title']\").getBoundingClientRect().bottom"
    )
    page = Image.open(io.BytesIO(b.get_screenshot_as_png())).convert("RGB")
    return page.crop((0, 0, page.width, min(page.height, round(bottom))))


if __name__ == "__main__":
    main()
