"""Start-up: /readyz says 503 until the start-up work is done; the service never imports torch."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading

from fastapi.testclient import TestClient
from service_helpers import service_settings, wait_ready

import service.main
from service.settings import unknown_variables


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


def test_a_posedesc_variable_that_is_no_setting_is_named_at_start(
    tmp_path, posedesc_models, monkeypatch, caplog
):
    # a setting that became a stage's constant, and a misspelt one: both would change nothing
    monkeypatch.setenv("POSEDESC_DETECT_SUNK_SHARE", "1")
    monkeypatch.setenv("POSEDESC_RERNAK", "200")
    monkeypatch.setenv(
        "POSEDESC_IMAGE", "posedesc:latest"
    )  # the compose files' image: not a setting, not ours
    unknown = unknown_variables(os.environ)
    assert {"POSEDESC_DETECT_SUNK_SHARE", "POSEDESC_RERNAK"} <= set(
        unknown
    ) and "POSEDESC_IMAGE" not in unknown
    app = service.main.create_app(service_settings(tmp_path, posedesc_models))
    with caplog.at_level(logging.WARNING, logger="service"), TestClient(app) as c:
        assert c.get("/healthz").status_code == 200
    warned = [r.getMessage() for r in caplog.records if "no such setting" in r.getMessage()]
    assert warned and "POSEDESC_DETECT_SUNK_SHARE" in warned[0] and "POSEDESC_RERNAK" in warned[0]
