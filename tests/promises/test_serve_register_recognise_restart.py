"""`posedesc serve` for real: uvicorn on a loopback port, driven over HTTP, restarted."""

from __future__ import annotations

import signal
import threading

import httpx
import pytest
from service_helpers import Server, expected_templates, frame, frame_fields, png, register

from index.geometry.pose import View
from index.geometry.pose_error import view_error

TRUE_VIEW = View(azimuth=250.0, elevation=55.0, inplane=0.0, distance=700.0)
UV = (260.0, 300.0)


@pytest.mark.slow  # a real uvicorn process, registration, restart: about 8 s
def test_serve_register_recognise_parallel_delete_restart(
    tmp_path, posedesc_models, renderer, l_shape, t_shape
):
    data_dir = tmp_path / "data"
    rgb, _ = frame(renderer, l_shape, TRUE_VIEW, UV)
    query = {"files": {"rgb": ("f.png", png(rgb))}, "data": frame_fields(UV, distance_mm=700)}
    server = Server(data_dir, posedesc_models)
    try:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            l_id = register(c, l_shape, "L")["object_id"]
            body = c.post("/recognize", **query).json()
            assert body["best"]["object_id"] == l_id
            errors = [view_error(m["azimuth"], m["elevation"], 250.0, 55.0) for m in body["matches"]]
            assert min(errors) <= 20.0, errors

            # Recognitions in parallel with registrations and removals: none fails, none sees an
            # object that is not (or no longer, or not yet wholly) there.
            stop, failures, count = threading.Event(), [], [0]
            seen: set[tuple[int, str]] = set()

            def recognise_forever():
                with httpx.Client(base_url=server.url, timeout=60) as rc:
                    while not stop.is_set():
                        r = rc.post("/recognize", **query)
                        if r.status_code != 200:
                            failures.append(r.text)
                        else:
                            seen.update((m["object_id"], m["name"]) for m in r.json()["matches"])
                        count[0] += 1

            added: dict[int, str] = {}
            threads = [threading.Thread(target=recognise_forever) for _ in range(3)]
            for t in threads:
                t.start()
            try:
                for i in range(3):
                    oid = register(c, t_shape, f"T{i}")["object_id"]
                    added[oid] = f"T{i}"
                    if i % 2 == 0:
                        assert c.delete(f"/objects/{oid}").status_code == 204
            finally:
                stop.set()
                for t in threads:
                    t.join()
            assert failures == [] and count[0] >= 6
            assert seen <= {(l_id, "L"), *added.items()}  # only real objects, each with its own name
            names = {o["name"] for o in c.get("/objects").json()}
            assert names == {"L", "T1"}

            assert c.delete(f"/objects/{l_id}").status_code == 204
            body = c.post("/recognize", **query).json()
            assert l_id not in {m["object_id"] for m in body["matches"]}
            before = c.get("/objects").json()
        # uvicorn shuts down gracefully, then re-raises the signal: exit status -SIGTERM, no traceback
        assert server.stop() in (0, -signal.SIGTERM)
        assert "Traceback" not in server.log.read_text()
    finally:
        if server.proc.poll() is None:
            server.proc.kill()

    again = Server(data_dir, posedesc_models)
    try:
        again.wait_ready()
        with httpx.Client(base_url=again.url, timeout=60) as c:
            assert c.get("/objects").json() == before
            assert c.get("/readyz").json()["templates"]["rgb"] == expected_templates(posedesc_models, "rgb")
    finally:
        again.stop()
