"""The web page at `/`, in a real headless browser (Debian's chromium driven by selenium) against `posedesc
serve` on loopback with the shipped models: the example mesh registered through the page (behind the API key
the page asks for), the example frame clicked on and its answer drawn and listed, the object deleted; the
API's errors shown on the page. And, without a browser, what the page is made of: its files served from this
server only, nothing else of the package reachable through them, all of them shipped by a non-editable
install."""

from __future__ import annotations

import fnmatch
import re
import tomllib

import httpx
import pytest
from browser import HANG, OBJECT_UV, chromium, click_on_frame, drawn_width, object_names, text
from fastapi.testclient import TestClient
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.ui import WebDriverWait
from service_helpers import ROOT, K, Server, W, service_settings

from service.main import create_app
from service.routes.page import EXAMPLE_FILES, STATIC, STATIC_FILES

# the module's server and browser started once, on one worker
pytestmark = pytest.mark.xdist_group("page")

MODELS = ROOT / "models"
EXAMPLES = ROOT / "service" / "examples"
API_KEY = "page-test-key"
CAMERA = dict(zip(("fx", "fy", "cx", "cy"), (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), strict=True))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    if not all((MODELS / f"posedesc-{m}.onnx").is_file() for m in ("rgb", "depth", "rgbd")):
        pytest.skip(f"no shipped models in {MODELS}")
    # level 1: the example mesh registers in about a second; SYNC_SECONDS 0: POST /objects answers 202 with
    # a job, so the page follows the job as it does for any mesh that takes longer than a request
    env = {"POSEDESC_LEVEL": "1", "POSEDESC_SYNC_SECONDS": "0", "POSEDESC_API_KEY": API_KEY}
    with Server(tmp_path_factory.mktemp("page") / "data", MODELS, env) as s:
        s.wait_ready()
        yield s
        s.stop()


@pytest.fixture(scope="module")
def browser():
    driver = chromium()
    yield driver
    driver.quit()


@pytest.mark.slow  # a real server and a browser: about 15 s
def test_register_recognise_and_delete_through_the_page(server, browser):
    b, wait = browser, WebDriverWait(browser, HANG)
    b.get(f"{server.url}/")
    wait.until(lambda d: text(d, "objects-note") == "No object is registered yet.")
    assert not b.find_element(By.ID, "key-section").is_displayed()

    # Registration: the service wants its key, the page asks for it, then follows the job to the end.
    b.find_element(By.ID, "mesh").send_keys(str(EXAMPLES / "part.ply"))
    assert b.find_element(By.ID, "name").get_attribute("value") == "part"  # the file's name
    b.find_element(By.ID, "register").click()
    wait.until(EC.text_to_be_present_in_element((By.ID, "reg-error"), "401: missing or wrong API key"))
    assert b.find_element(By.ID, "key-section").is_displayed()
    b.find_element(By.ID, "api-key").send_keys(API_KEY)
    b.find_element(By.CSS_SELECTOR, "#key-form button").click()
    b.find_element(By.ID, "register").click()
    wait.until(lambda d: object_names(d) == ["part"])
    assert re.fullmatch(r"Registered part \(id \d+\): \d+ templates in [\d.]+ s\.", text(b, "reg-status"))
    assert text(b, "reg-error") == ""
    metrics = httpx.get(f"{server.url}/metrics").text
    assert 'route="/objects",status="202"} 1.0' in metrics  # through the job, polled by the page

    # The camera is entered once: kept over a reload; the example puts its own back.
    fx = b.find_element(By.ID, "fx")
    assert float(fx.get_attribute("value")) == CAMERA["fx"]  # prefilled: the examples' camera
    fx.clear()
    fx.send_keys("600\t")
    b.refresh()
    assert b.find_element(By.ID, "fx").get_attribute("value") == "600"
    b.find_element(By.ID, "example-frame").click()
    wait.until(lambda d: d.execute_script("return document.getElementById('frame').naturalWidth") == W)
    assert [float(b.find_element(By.ID, n).get_attribute("value")) for n in CAMERA] == list(CAMERA.values())

    # Recognition: a click on the object asks about that point; its answer is drawn and listed.
    click_on_frame(b, OBJECT_UV)
    u, v = (float(b.find_element(By.ID, n).get_attribute("value")) for n in ("u", "v"))
    assert abs(u - OBJECT_UV[0]) <= 2 and abs(v - OBJECT_UV[1]) <= 2  # the frame's pixel, at any scale
    wait.until(lambda d: drawn_width(d) == W)
    rows = [r.text for r in b.find_elements(By.CSS_SELECTOR, "#answers tbody tr")]
    assert len(rows) == 5 and all(r.startswith("part") for r in rows), rows  # k = 5; the only object
    assert rows[0].startswith(("part (best", "part (rejected")), rows[0]
    # the best answer fitted to the frame says so, its origin where the fit put it; with depth the first
    # twenty are fitted to re-order them (`DEPTH_RERANK`); those the fit left where they were are at the click
    assert "fitted" in rows[0] and all(f"({u:.0f}, {v:.0f})" in r for r in rows if "fitted" not in r), rows
    assert text(b, "rec-error") == ""

    # Find objects: the frame searched whole, drawn again, and whatever was found listed (or why not).
    b.find_element(By.ID, "find").click()  # hides the last drawing at once (the click's handler)
    assert drawn_width(b) == 0
    wait.until(lambda d: drawn_width(d) == W)
    found = b.find_elements(By.CSS_SELECTOR, "#answers tbody tr")
    assert found or text(b, "answers-note") == "no registered object was found in the frame"
    assert text(b, "rec-error") == ""

    # Deletion, confirmed: gone from the page's list and from the service.
    row = b.find_element(By.CSS_SELECTOR, '#objects tbody tr[data-name="part"]')
    row.find_element(By.CSS_SELECTOR, 'button[aria-label="Delete part"]').click()
    wait.until(EC.alert_is_present()).accept()
    wait.until(lambda d: object_names(d) == [])
    assert httpx.get(f"{server.url}/objects").json() == []
    assert text(b, "obj-error") == ""


@pytest.mark.slow  # a real server and a browser
def test_the_api_s_errors_are_shown_on_the_page(server, browser):
    b, wait = browser, WebDriverWait(browser, HANG)
    b.get(f"{server.url}/")

    # A mesh sent as the colour image: the service's own message, word for word.
    b.find_element(By.ID, "rgb").send_keys(str(EXAMPLES / "part.ply"))
    b.find_element(By.ID, "find").click()
    sent = {"files": {"rgb": ("part.ply", (EXAMPLES / "part.ply").read_bytes())}, "data": CAMERA | {"k": 5}}
    refused = httpx.post(f"{server.url}/recognize", **sent)
    assert refused.status_code == 422
    wait.until(EC.text_to_be_present_in_element((By.ID, "rec-error"), f"422: {refused.json()['detail']}"))
    assert drawn_width(b) == 0 and b.find_elements(By.CSS_SELECTOR, "#answers tbody tr") == []

    # No camera: the frame is taken for a patch, and the service says what a frame needs.
    b.find_element(By.ID, "example-frame").click()
    wait.until(lambda d: "example frame" in text(d, "rec-status"))
    for name in CAMERA:
        b.find_element(By.ID, name).clear()
    b.find_element(By.ID, "find").click()
    wait.until(EC.text_to_be_present_in_element((By.ID, "rec-error"), "422: a patch must be square"))
    assert "a full frame needs its camera" in text(b, "rec-error")


@pytest.mark.slow  # a real server and a browser
def test_a_colour_frame_a_users_own_camera_and_what_the_page_offers(server, browser):
    """A click in a colour frame without depth and without a distance is not sent (it would be a 422) and
    wipes nothing; after Find objects, a click inside an object found takes that object's distance. A frame
    of the user's own with the example's camera still in the fields says so. The find's settings are sent,
    the answer can be downloaded as JSON, and a registration's bar only moves forward."""
    from index.templates.shapes import demo_shapes

    robot = demo_shapes()["robot"].export(file_type="ply")
    headers = {"X-API-Key": API_KEY}
    r = httpx.post(f"{server.url}/objects", files={"mesh": ("robot.ply", robot)}, data={"name": "robot"},
                   headers=headers, timeout=HANG)  # fmt: skip
    assert r.status_code in (201, 202), r.text
    b, wait = browser, WebDriverWait(browser, HANG)
    try:
        wait.until(lambda _: [o["name"] for o in httpx.get(f"{server.url}/objects").json()] == ["robot"])
        b.get(f"{server.url}/")
        b.find_element(By.ID, "example-frame").click()
        wait.until(lambda d: d.execute_script("return document.getElementById('frame').naturalWidth") == W)
        assert text(b, "camera-note") == ""  # the example, with its own camera
        b.find_element(By.ID, "clear-depth").click()  # colour only
        b.find_element(By.ID, "distance").clear()

        # no distance and nothing found yet: said at once, nothing sent
        before = httpx.get(f"{server.url}/metrics").text.count('route="/recognize"')
        click_on_frame(b, OBJECT_UV)
        wait.until(EC.text_to_be_present_in_element((By.ID, "rec-error"), "needs the object's distance"))
        assert httpx.get(f"{server.url}/metrics").text.count('route="/recognize"') == before

        # Find objects, its settings sent: at most one object; then a click inside it takes its distance
        b.find_element(By.ID, "max_detections").clear()
        b.find_element(By.ID, "max_detections").send_keys("1")
        b.find_element(By.ID, "find").click()
        wait.until(lambda d: drawn_width(d) == W)
        found = b.execute_script("return found")
        assert len(found) <= 1
        link = b.find_element(By.ID, "download-json")
        assert link.is_displayed() and link.get_attribute("href").startswith("blob:")
        assert (
            link.get_attribute("download") == "answer.json"
        )  # (the page's CSP keeps a test from reading it)
        if found:  # the robot found in colour: click in its box
            x0, y0, x1, y1 = found[0]["box"]
            click_on_frame(b, ((x0 + x1) / 2, (y0 + y1) / 2))
            wait.until(EC.text_to_be_present_in_element((By.ID, "rec-status"), "from the object found there"))
            assert float(b.find_element(By.ID, "distance").get_attribute("value")) == found[0]["distance"]
            assert text(b, "rec-error") == "" and drawn_width(b) == W
        # a click outside every object found, with no distance of the user's: refused on the page, and the
        # last answer and its drawing stay
        rows = len(b.find_elements(By.CSS_SELECTOR, "#answers tbody tr"))
        b.find_element(By.ID, "distance").clear()
        b.execute_script("distanceFound = false; found = []")
        click_on_frame(b, (5, 5))
        wait.until(EC.text_to_be_present_in_element((By.ID, "rec-error"), "needs the object's distance"))
        assert drawn_width(b) == W and len(b.find_elements(By.CSS_SELECTOR, "#answers tbody tr")) == rows

        # the user's own image: the example's camera is not used silently
        b.find_element(By.ID, "rgb").send_keys(str(EXAMPLES / "robot-rgb.png"))
        wait.until(EC.text_to_be_present_in_element((By.ID, "camera-note"), "example frame's camera values"))
        fx = b.find_element(By.ID, "fx")
        fx.clear()
        fx.send_keys("600\t")
        wait.until(lambda d: text(d, "camera-note") == "")

        # K pasted as OpenCV and BOP write it fills the four fields; a malformed one is said, nothing changed
        paste = b.find_element(By.ID, "cam_K")
        paste.send_keys("[572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1]\t")
        wait.until(lambda d: d.find_element(By.ID, "cx").get_attribute("value") == "325.3")
        camera = [b.find_element(By.ID, n).get_attribute("value") for n in ("fx", "fy", "cx", "cy")]
        assert camera == ["572.4", "573.6", "325.3", "242"] and paste.get_attribute("value") == ""
        paste.send_keys("572.4 0 325.3\t")
        wait.until(EC.text_to_be_present_in_element((By.ID, "camera-note"), "9 numbers row by row"))
        assert b.find_element(By.ID, "fx").get_attribute("value") == "572.4"
        # distortion coefficients are sent with the frame: too few are the API's 422, shown on the page
        b.find_element(By.ID, "dist_coeffs").send_keys("0.1 0.2\t")
        b.find_element(By.ID, "find").click()
        wait.until(EC.text_to_be_present_in_element((By.ID, "rec-error"), "dist_coeffs"))
        b.find_element(By.ID, "dist_coeffs").clear()

        # the registration's bar: percent of the whole, never back when the stage (and its count) changes
        shown = b.execute_script(
            "const out = [];"
            "for (const p of [null, {stage: 'render', done: 40, total: 100}, {stage: 'embed', done: 30, total: 100},"
            " {stage: 'embed', done: 100, total: 100}, {stage: 'store', done: 0, total: 400},"
            " {stage: 'store', done: 400, total: 400}]) {"
            " showProgress(p); out.push(document.getElementById('reg-progress').value); }"
            "return [out, document.getElementById('reg-status').textContent]"
        )
        values, status = shown
        assert values[1:] == sorted(values[1:]) and values[-1] == 100, values
        assert status == "Registering: 100 % (400 of 400 templates stored) ..."
    finally:
        for o in httpx.get(f"{server.url}/objects").json():
            httpx.delete(f"{server.url}/objects/{o['object_id']}", headers=headers)


def page_client() -> TestClient:
    """The app without its lifespan: the page's files need no models, store or state."""
    return TestClient(create_app(service_settings(ROOT / "data" / "never-made", MODELS)))


def test_the_page_loads_its_own_files_only():
    c = page_client()
    r = c.get("/")
    assert r.status_code == 200 and r.headers["content-type"] == "text/html; charset=utf-8"
    assert "default-src 'self'" in r.headers["content-security-policy"]  # no other origin, no inline script
    assert "<script>" not in r.text and "http://" not in r.text and "https://" not in r.text
    assets = re.findall(r"""<(?:script|link)\b[^>]*(?:src|href)="([^"]+)\"""", r.text)
    assert sorted(assets) == ["/static/app.js", "/static/style.css"]
    for url, kind in zip(sorted(assets), ("text/javascript", "text/css"), strict=True):
        got = c.get(url)
        assert got.status_code == 200 and got.headers["content-type"].startswith(kind)
        assert got.content == (STATIC / url.rsplit("/", 1)[-1]).read_bytes()
    assert c.get("/examples/robot-rgb.png").content == (EXAMPLES / "robot-rgb.png").read_bytes()


@pytest.mark.parametrize(
    "url",
    [
        "/static/index.html.bak",
        "/static/..%2F..%2Fsettings.py",
        "/static/%2Fetc%2Fpasswd",
        "/examples/make_examples.py",  # in the folder, but not an example
        "/examples/..%2Fmain.py",
        "/examples/",
    ],
)
def test_nothing_else_is_served_through_the_page_s_routes(url):
    r = page_client().get(url)
    assert r.status_code == 404 and r.headers["content-type"] == "application/json"
    assert "detail" in r.json()


def test_a_non_editable_install_ships_the_page_and_its_examples():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    served = [STATIC / "index.html", *STATIC_FILES.values(), *EXAMPLE_FILES.values()]
    assert {p.name for p in EXAMPLE_FILES.values()} >= {"robot-rgb.png", "robot-depth.png", "part.ply"}
    unshipped = [
        p
        for p in served
        if not any(fnmatch.fnmatch(str(p.relative_to(ROOT / "service")), g) for g in data["service"])
    ]
    assert unshipped == []
