"""A real browser for the tests and scripts/page_screenshot.py: Debian's chromium, headless, driven by
selenium with the system driver (nothing downloaded), and the page's few interactions."""

from __future__ import annotations

from pathlib import Path

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webdriver import WebDriver
from service_helpers import H, W

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
HANG = 60.0  # seconds: only stops a wait that would never end, not a measure of speed
WIDTH = 1024  # the narrowest screen the page is made for
OBJECT_UV = (380, 250)  # where the demo robot stands in the example frame (README: "Try it")


def chromium(width: int = WIDTH, height: int = 900) -> WebDriver:
    """Debian's chromium, headless, its window `width` x `height` px (also for scripts/page_screenshot.py)."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.is_file()]
    if missing:
        pytest.fail(f"{' and '.join(missing)} missing: `make setup` installs chromium", pytrace=False)
    options = Options()
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        f"--window-size={width},{height}",
    ):
        options.add_argument(arg)
    options.binary_location = str(CHROMIUM)
    # the driver's path given, selenium-manager does not run (it would download a browser and a driver)
    return webdriver.Chrome(options=options, service=Service(str(CHROMEDRIVER)))


def text(b: WebDriver, element_id: str) -> str:
    return b.find_element(By.ID, element_id).text


def object_names(b: WebDriver) -> list[str]:
    # in one script: the list may be redrawn between two calls
    return b.execute_script(
        "return Array.from(document.querySelectorAll('#objects tbody tr'), r => r.dataset.name)"
    )


def drawn_width(b: WebDriver) -> int:
    """The drawn answer's width once it is shown and decoded, else 0."""
    return b.execute_script(
        "const i = document.getElementById('drawn'); return !i.hidden && i.complete ? i.naturalWidth : 0"
    )


def click_on_frame(b: WebDriver, uv: tuple[float, float]) -> None:
    """A click on the pixel `uv` of the frame shown, whatever its scale on the page."""
    frame = b.find_element(By.ID, "frame")
    # whole in the window: an action's offset counts from the centre of the element's visible part
    b.execute_script("arguments[0].scrollIntoView({block: 'center'})", frame)
    size = frame.size
    dx, dy = ((c / n - 0.5) * s for c, n, s in zip(uv, (W, H), (size["width"], size["height"]), strict=True))
    ActionChains(b).move_to_element_with_offset(frame, round(dx), round(dy)).click().perform()
