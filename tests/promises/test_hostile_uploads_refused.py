"""Hostile uploads against `posedesc serve` on a loopback port: images that claim or decompress to huge
sizes, meshes that expand to millions of faces or thousands of parts, NaN and infinite vertices, broken
GLB (`benchmarks.serving.hostile.UPLOADS`). Each is refused with a 4xx and a one-line JSON message, and the
server's memory stays bounded: its peak resident memory (VmHWM, reset before each upload) grows by far
less than the unguarded code took (2-4.6 GB for the large meshes). How long a refusal takes is a figure of
`posedesc bench --only guards`, not a test."""

from __future__ import annotations

import threading
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_helpers import Server, depth_png, png

from benchmarks.serving.hostile import UPLOADS, ply_polygons

# uploads of tens of MB, parses of 12 M triangles: `make test`, not `make check`
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("hostile")]  # one server, on one worker


@pytest.fixture(scope="module")
def server(tmp_path_factory, posedesc_models):
    data_dir = tmp_path_factory.mktemp("hostile") / "data"
    with Server(data_dir, posedesc_models, env={"POSEDESC_LEVEL": "1"}) as s:
        s.wait_ready()
        with httpx.Client(base_url=s.url, timeout=120) as c:  # warm up: sessions, first allocations
            assert c.post(
                "/recognize", files={"rgb": ("p.png", png(np.zeros((64, 64, 3), np.uint8)))}
            ).is_success
        yield s
        assert "Traceback" not in s.log.read_text()


def reset_peak(server: Server) -> float:
    """Resets the server's peak resident memory to its current one (Linux: clear_refs 5); returns it."""
    Path(f"/proc/{server.proc.pid}/clear_refs").write_text("5")
    return server.memory_mb()[1]


def send(url: str, field: str, filename: str, content: bytes) -> httpx.Response:
    endpoint = "/objects" if field == "mesh" else "/recognize"
    data = {"name": "hostile"} if field == "mesh" else {}
    with httpx.Client(base_url=url, timeout=120) as c:
        return c.post(endpoint, files={field: (filename, content)}, data=data)


@pytest.mark.parametrize("case", list(UPLOADS))
def test_hostile_upload_is_refused_in_bounded_memory(server, case):
    u = UPLOADS[case]
    content = u.make()
    before = reset_peak(server)
    r = send(server.url, u.field, u.filename, content)
    grew = server.memory_mb()[1] - before
    assert r.status_code == u.status, r.text
    assert r.headers["content-type"] == "application/json"
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and u.words in detail, detail
    assert grew < u.megabytes, f"peak memory grew by {grew:.0f} MB"
    assert server.proc.poll() is None


def test_concurrent_bombs_are_parsed_one_at_a_time(server):
    """Three 12 M-triangle PLYs and six 4096 x 4096 depth images at once: meshes are parsed one at a
    time (each ~1.1 GB, freed before the next) and images decoded two at a time (~0.2 GB each), so the
    peak is about one parse and two decodes, not the sum of all of them (4.5 GB)."""
    bomb, big_depth = ply_polygons(48_000), depth_png(np.zeros((4096, 4096)))
    uploads = [("mesh", "m.ply", bomb)] * 3 + [("depth", "d.png", big_depth)] * 6
    statuses: list[int] = []
    before = reset_peak(server)
    threads = [
        threading.Thread(target=lambda u=u: statuses.append(send(server.url, *u).status_code))
        for u in uploads
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=600)  # only against a hang: a slow machine is no failure
    grew = server.memory_mb()[1] - before
    assert sorted(statuses) == [413] * 3 + [422] * 6
    assert grew < 2000, f"peak memory grew by {grew:.0f} MB"
    with httpx.Client(base_url=server.url, timeout=60) as c:  # and the service still serves
        assert c.get("/readyz").status_code == 200
