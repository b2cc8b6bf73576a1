"""The README's service examples run as written: its curl block in bash and its Python block (the
`posedesc.client` one on the demo robot), taken from README.md with only the server's address changed, against `posedesc serve` on a loopback port with the
shipped models and the demo objects, as `make serve` starts it. A README example that stops working fails
here."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import httpx
import pytest
from service_helpers import ROOT, Server

# runs the README's examples against real servers: `make test`, not `make check`
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("readme")]  # its two servers started once each

MODELS = ROOT / "models"
DEMO = ["demo-mug", "demo-lamp", "demo-robot", "demo-duck"]


def blocks(lang: str, needle: str) -> list[str]:
    """The README's fenced `lang` code blocks that contain `needle`."""
    found = re.findall(rf"^```{lang}\n(.*?)^```", (ROOT / "README.md").read_text(), re.M | re.S)
    return [b for b in found if needle in b]


# A registration answers 201 when done within SYNC_SECONDS, else 202 and a job: the examples handle both.
@pytest.fixture(scope="module", params=["30", "0"], ids=["201", "202"])
def server(request, tmp_path_factory):
    if not all((MODELS / f"posedesc-{m}.onnx").is_file() for m in ("rgb", "depth", "rgbd")):
        pytest.skip(f"no shipped models in {MODELS}")
    env = {"POSEDESC_DEMO_OBJECTS": "true", "POSEDESC_SYNC_SECONDS": request.param}
    with Server(tmp_path_factory.mktemp("readme") / "data", MODELS, env) as s:
        s.wait_ready(timeout=300)
        s.registered = "202" if request.param == "0" else "201"  # what POST /objects answers
        yield s
        s.stop()


def names(server: Server) -> list[str]:
    return [o["name"] for o in httpx.get(f"{server.url}/objects").json()]


def registrations(server: Server) -> str:
    """The metrics' count of POST /objects answered as the server's set-up makes it answer."""
    code = server.registered  # type: ignore[attr-defined]
    wanted = f'posedesc_requests_total{{method="POST",route="/objects",status="{code}"}} '
    lines = httpx.get(f"{server.url}/metrics").text.splitlines()
    return next((x.split()[-1] for x in lines if x.startswith(wanted)), "0")


def test_the_curl_examples(server):
    assert shutil.which("curl"), "curl is needed (make setup installs it)"
    (script,) = blocks("sh", "curl -s localhost:8000/recognize")
    assert names(server) == DEMO
    before = float(registrations(server))
    script = script.replace("localhost:8000", server.url.removeprefix("http://"))
    (ROOT / "out" / "answer.png").unlink(missing_ok=True)  # the drawing is the example's own
    r = subprocess.run(
        ["bash", "-e", "-o", "pipefail", "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr
    out = r.stdout
    assert '"detail":"' not in out  # no error answered (errors are {"detail": "..."})
    # the three recognitions of the demo robot's frame and patch, and the frame searched whole: its first
    # detection's best is the answer's best too
    assert out.count('"best":{"object_id":3,"name":"demo-robot"') == 5, out[:3000]
    assert '"detections":[{"u":' in out
    assert '"name":"part"' in out and re.search(r"\}204\n", out)  # registered, shown, then deleted
    assert "posedesc_requests_total" in out  # the metrics
    drawn = ROOT / "out" / "answer.png"  # the drawing, where the example writes it
    assert drawn.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    drawn.unlink()
    assert names(server) == DEMO  # the part is gone and the demo objects (the mug is id 1) are not
    assert float(registrations(server)) == before + 1


def test_the_python_example(server):
    (code,) = blocks("python", "robot-rgb.png")
    assert names(server) == DEMO
    before = float(registrations(server))
    code = code.replace("http://localhost:8000", server.url)
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("{'object_id': 3, 'name': 'demo-robot'"), r.stdout[:500]  # as its comment says
    assert "'name': 'part'" in lines[1] and "'part'" in lines[1].rsplit("[", 1)[1]  # registered, then listed
    assert "404" in lines[2] or "no object" in lines[2], lines[2]  # the second delete: an ApiError
    assert "'status': 'ready'" in lines[3]  # health
    assert lines[4].startswith("[('demo-robot', ["), lines[4]  # the frame searched whole: the robot first
    assert names(server) == DEMO
    assert float(registrations(server)) == before + 1


def test_the_own_object_example(server, tmp_path):
    """`posedesc render --patches`, then the Python block that registers the mesh and sends a query of it."""
    (script,) = blocks("sh", "--patches out/queries/")
    (code,) = blocks("python", 'api.register("service/examples/part.ply"')
    queries = str(tmp_path / "queries")
    script = script.replace(".venv/bin/posedesc", str(ROOT / ".venv" / "bin" / "posedesc"))
    r = subprocess.run(
        ["bash", "-e", "-c", script.replace("out/queries", queries)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "queries" / "query-00.json").is_file()
    code = code.replace("http://localhost:8000", server.url).replace("out/queries", queries)
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr
    answered, truth, patch = r.stdout.splitlines()
    assert answered.startswith("part "), r.stdout  # the query of the part is answered the part
    assert truth.startswith("true: ["), r.stdout
    assert patch == "part", r.stdout  # and so is its patch, sent with its window
    assert names(server) == DEMO  # deleted again
