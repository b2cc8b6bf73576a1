"""Start-up: /readyz says 503 until the start-up work is done; the service never imports torch."""

from __future__ import annotations

import subprocess
import sys
import threading

from fastapi.testclient import TestClient
from service_helpers import service_settings, wait_ready

import service.main


def test_readyz_is_503_until_startup_work_is_done(tmp_path, posedesc_models, monkeypatch):
    release = threading.Event()
    real = service.main.startup

    def slow(state):
        release.wait(30)
        real(state)

    monkeypatch.setattr(service.main, "startup", slow)
    with TestClient(service.main.create_app(service_settings(tmp_path, posedesc_models))) as c:
        r = c.get("/readyz")
        assert r.status_code == 503 and r.json()["status"] == "starting"
        assert c.get("/healthz").status_code == 200
        release.set()
        assert wait_ready(c)["status"] == "ready"


def test_the_service_never_imports_torch():
    code = "import sys, service.main, posedesc.commands.serve; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0
