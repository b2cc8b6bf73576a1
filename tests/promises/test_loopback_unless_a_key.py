"""Where `posedesc serve` listens: loopback by default; a busy port stops it at once, in one line, before
the models load; on an address other hosts can reach, writes need an API key or an explicit opt-in; and
one log line says when it is ready (/readyz 200), where, and what it serves. Real servers on free ports."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import time

import httpx
import pytest
from service_helpers import ROOT, Server, free_port, ply_bytes, serve_command

OPEN = "POSEDESC_ALLOW_OPEN_WRITES"
HANG = 300.0  # seconds: only stops a test that would never end, not a measure of speed


def test_a_busy_port_stops_serve_at_once_in_one_line(tmp_path, posedesc_models):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        data_dir = tmp_path / "data"
        r = subprocess.run(
            serve_command(port, data_dir, posedesc_models),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=HANG,
        )
    assert r.returncode == 2, r.stderr
    assert r.stderr == f"posedesc serve: error: cannot listen on 127.0.0.1:{port}: Address already in use\n"
    # "at once": the store was never opened, nor the models loaded (the time it takes: `posedesc bench
    # --only guards`)
    assert not (data_dir / "store.sqlite").exists()


#: every line `posedesc serve` logs: local time (ISO 8601, ms), level, logger, message
LOG_LINE = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3} (DEBUG|INFO|WARNING|ERROR) [\w.]+: \S")


def test_the_ready_line_comes_when_readyz_is_200(tmp_path, posedesc_models):
    with Server(tmp_path / "data", posedesc_models, log_level="info") as server:
        end = time.monotonic() + HANG
        while "ready on" not in server.log.read_text():
            assert server.proc.poll() is None and time.monotonic() < end, server.log.read_text()
            time.sleep(0.05)
        r = httpx.get(f"{server.url}/readyz", timeout=10)
        assert r.status_code == 200, r.text
        lines = server.log.read_text().splitlines()
        line = next(x for x in lines if "ready on" in x)
        sizes = ", ".join(f"{m} {n}" for m, n in sorted(r.json()["templates"].items()))
        said = line.split(" ", 1)[1]
        assert said == (
            f"INFO service: ready on {server.url}: 0 objects; templates searched (all objects, viewpoints x "
            f"in-plane angles): {sizes}"
        ), line
        # the app's lines and uvicorn's (start-up, each request) all carry the time of day
        assert server.stop() in (0, -signal.SIGTERM)
    lines = [x for x in server.log.read_text().splitlines() if x.strip()]
    assert all(LOG_LINE.match(x) for x in lines), "\n".join(x for x in lines if not LOG_LINE.match(x))
    loggers = {x.split(" ")[2] for x in lines}
    assert {"posedesc:", "service:", "uvicorn.error:", "uvicorn.access:"} <= loggers, loggers
    assert any('"GET /readyz HTTP/1.1" 200' in x for x in lines)


@pytest.mark.slow
def test_writes_on_a_public_address_need_a_key_or_an_opt_in(tmp_path, posedesc_models, t_shape):
    mesh = {"files": {"mesh": ("t.ply", ply_bytes(t_shape))}, "data": {"name": "T"}}
    with Server(tmp_path / "a", posedesc_models, host="0.0.0.0") as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            for r in (c.post("/objects", **mesh), c.delete("/objects/1")):
                assert r.status_code == 403, r.text
                detail = r.json()["detail"]
                assert (
                    "0.0.0.0 without an API key" in detail and "POSEDESC_API_KEY" in detail and OPEN in detail
                )
            assert c.get("/objects").json() == [] and c.get("/readyz").status_code == 200  # reads are open
        log = server.log.read_text()
        assert log.count("writes are refused") == 1, log  # said once, at start

    with Server(tmp_path / "b", posedesc_models, host="0.0.0.0", env={OPEN: "1"}) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            assert c.post("/objects", **mesh).status_code in (201, 202)
        assert "writes are open to anyone who can reach http://0.0.0.0:" in server.log.read_text()

    with Server(tmp_path / "c", posedesc_models, host="0.0.0.0", env={"POSEDESC_API_KEY": "k"}) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            assert c.post("/objects", **mesh).status_code == 401  # the key decides, as on loopback
            assert c.post("/objects", **mesh, headers={"X-API-Key": "k"}).status_code in (201, 202)


def test_loopback_is_the_default(tmp_path, posedesc_models):
    port = free_port()
    cmd = serve_command(port, tmp_path / "data", posedesc_models)
    cmd.remove("--host")
    cmd.remove("127.0.0.1")
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + HANG
        while True:
            listening = subprocess.run(["ss", "-Hltn", f"sport = :{port}"], capture_output=True, text=True)
            if listening.stdout.strip() or proc.poll() is not None or time.monotonic() > end:
                break
            time.sleep(0.1)
        assert listening.stdout.split()[3] == f"127.0.0.1:{port}", listening.stdout
    finally:
        proc.kill()
        proc.wait(timeout=HANG)


def test_make_serve_takes_host_and_port():
    def command(*variables: str) -> str:
        out = subprocess.run(["make", "-n", "serve", *variables], cwd=ROOT, capture_output=True, text=True)
        # under `make test` this make is a sub-make: it also prints "Entering/Leaving directory" lines
        return [line for line in out.stdout.splitlines() if "posedesc serve" in line][-1]

    assert "posedesc serve --host 127.0.0.1 --port 8000 " in command()
    assert "posedesc serve --host 0.0.0.0 --port 9123 " in command("HOST=0.0.0.0", "PORT=9123")


def test_which_addresses_count_as_public():
    from service.deps import open_writes_refused, public
    from service.settings import Settings

    assert [public(h) for h in ("0.0.0.0", "::", "192.168.1.20", "127.0.0.1", "127.0.0.2", "::1")] == [
        True,
        True,
        True,
        False,
        False,
        False,
    ]
    assert not public("testserver") and not public(None)  # not an IP (TestClient), or unknown
    assert "0.0.0.0 without an API key" in (open_writes_refused(Settings(), "0.0.0.0") or "")
    assert open_writes_refused(Settings(api_key="k"), "0.0.0.0") is None  # the key decides
    assert open_writes_refused(Settings(allow_open_writes=True), "0.0.0.0") is None
    assert open_writes_refused(Settings(), "127.0.0.1") is None
