"""Open-set rejection over HTTP: `posedesc serve` on loopback answers a registered object's patch and says
"best": null, with a reason, for the patch of an object it does not know (threshold from the setting, so
the test does not depend on any model's calibration)."""

from __future__ import annotations

import importlib.util
import shutil

import httpx
from service_helpers import ROOT, Server, png, register

from index.features.embed import Embedder
from index.geometry.pose import View
from service.pipeline.calibration import settings_of, stale
from service.rejection import Calibration, read_calibrations, served_score
from service.settings import Settings

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


def calibrated_models(folder, models, settings: dict[str, object], graph: str | None = None):
    """A copy of the test models, the rgb one with a descriptor calibration made with `settings` on the
    network `graph` (written as `scripts/calibrate_reject.py` writes it)."""
    spec = importlib.util.spec_from_file_location(
        "calibrate_reject", ROOT / "scripts" / "calibrate_reject.py"
    )
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    shutil.copytree(models, folder)
    cal = Calibration("descriptor", 0.5, 10.0, 0.4, settings=settings, graph=graph)
    model = folder / "posedesc-rgb.onnx"
    script.write_metadata(model, model, {"descriptor": cal.to_json()})
    return folder


def test_calibration_settings_that_differ_from_the_running_ones_are_said(tmp_path, posedesc_models):
    running = Settings(level=2)  # the test server's
    rgb = Embedder(posedesc_models / "posedesc-rgb.onnx")
    made = settings_of(running, rgb, "descriptor")
    assert made == {"level": 2, "inplane_step": 0.0, "inplane_extent": 0.0, "query_turns": 1}
    same = calibrated_models(tmp_path / "same", posedesc_models, made)
    assert stale(running, {"rgb": Embedder(same / "posedesc-rgb.onnx")}) == {}
    models = calibrated_models(tmp_path / "other", posedesc_models, {**made, "level": 3, "query_turns": 2})
    with Server(tmp_path / "data", models) as server:
        server.wait_ready()
        ready = httpx.get(f"{server.url}/readyz", timeout=30).json()
    server.stop()
    said = "level 3 (calibrated) != 2 (running), query_turns 2 (calibrated) != 1 (running)"
    assert (
        list(ready["calibration"]) == ["rgb"] and said in ready["calibration"]["rgb"]
    )  # the others have none
    log = server.log.read_text()
    assert said in log and "its rejection and confidences were measured on other scores" in log


def test_the_shipped_calibrations_were_made_on_the_shipped_models_with_the_shipped_settings():
    """Retrain a model, or change a default setting its scores depend on, and this fails until
    scripts/calibrate_reject.py has calibrated it again (the command is in docs/results/reject-*.json)."""
    settings = Settings()
    shipped = {m: Embedder(ROOT / "models" / f"posedesc-{m}.onnx") for m in ("rgb", "depth", "rgbd")}
    for modality, e in shipped.items():
        cal = read_calibrations(e.info.extra, e.path.name).get(served_score(settings, e))
        assert cal is not None, f"{e.path.name}: no calibration of the score it is served with"
        assert cal.graph == e.graph_digest and cal.settings is not None, modality
    assert stale(settings, shipped) == {}


def test_a_calibration_of_another_network_is_stale(tmp_path, posedesc_models):
    running = Settings(level=2)
    rgb = Embedder(posedesc_models / "posedesc-rgb.onnx")
    made = settings_of(running, rgb, "descriptor")
    own = calibrated_models(tmp_path / "own", posedesc_models, made, rgb.graph_digest) / "posedesc-rgb.onnx"
    assert stale(running, {"rgb": Embedder(own)}) == {}
    other = calibrated_models(tmp_path / "other", posedesc_models, made, "0" * 16) / "posedesc-rgb.onnx"
    said = stale(running, {"rgb": Embedder(other)})["rgb"]
    assert "measured on another network (graph 0000000000000000, this file's " in said
