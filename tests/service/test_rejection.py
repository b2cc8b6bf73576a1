"""Open-set rejection over HTTP: `posedesc serve` on loopback answers a registered object's patch and says
"best": null, with a reason, for the patch of an object it does not know (threshold from the setting, so
the test does not depend on any model's calibration)."""

from __future__ import annotations

import httpx
from service_helpers import Server, png, register

from index.pose import View

# A template view of the tests' level (2): the registered object's patch is one of its own templates.
VIEW = View(azimuth=0.0, elevation=90.0, inplane=0.0, distance=400.0)
THRESHOLD = 1e-3


def test_unregistered_object_is_answered_unknown(tmp_path, posedesc_models, renderer, l_shape, t_shape):
    l_patch = png(renderer.render(l_shape, [VIEW]).rgb[0])
    t_patch = png(renderer.render(t_shape, [VIEW]).rgb[0])
    env = {"POSEDESC_REJECT_ABOVE": str(THRESHOLD)}
    with Server(tmp_path / "data", posedesc_models, env) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            l_id = register(c, l_shape, "L")["object_id"]
            known = c.post("/recognize", files={"rgb": ("l.png", l_patch)}, data={"k": "3"}).json()
            assert known["best"] is not None and known["best"]["object_id"] == l_id, known
            assert known["reason"] is None
            assert known["matches"][0]["distance"] <= THRESHOLD
            # the untrained test model has no calibration: no confidence to give
            assert known["matches"][0]["confidence"] is None

            unknown = c.post("/recognize", files={"rgb": ("t.png", t_patch)}, data={"k": "3"}).json()
            assert unknown["matches"], unknown  # the nearest answers are still listed, for whoever wants them
            assert unknown["matches"][0]["distance"] > THRESHOLD
            assert unknown["best"] is None
            assert "no registered object is close enough" in unknown["reason"]
            assert "POSEDESC_REJECT_ABOVE" in unknown["reason"]
    assert server.stop() in (0, -9)
