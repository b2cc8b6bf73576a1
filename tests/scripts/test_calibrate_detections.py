"""scripts/calibrate_detections.py on hand-made detect runs: each video is measured with the curve fitted on the
others, the curve follows the fit score, and the model gets it in its metadata with its graph unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from index.features.embed import Embedder
from service.detection.report import read_detect_confidence


def run(scene: int, seed: int, tmp_path) -> str:
    """A video's detect result: 40 detections from depth, the right ones explained better by the depth (with
    overlap), the verifier's confidence the same for all; a colour one and an ignored one the script skips."""
    rng = np.random.default_rng(seed)
    right = rng.random(40) < 0.6
    fit = np.clip(np.where(right, 0.7, 0.35) + rng.normal(0, 0.15, 40), 0, 1)
    cues = [
        {"source": "depth", "verifier": 0.4, "fit": round(float(f), 4), "confidence": 0.4,
         "outcome": "tp" if r else "fp"}
        for f, r in zip(fit, right, strict=True)
    ]  # fmt: skip
    cues += [
        {"source": "colour", "verifier": 0.9, "fit": 0.1, "confidence": 0.8, "outcome": "fp"},
        {"source": "depth", "verifier": 0.4, "fit": 0.9, "confidence": 0.4, "outcome": "ignored"},
    ]
    path = tmp_path / f"detect-{scene}.json"
    path.write_text(json.dumps({"scene": scene, "targets": int(right.sum()) + 5, "posedesc": {"cues": cues}}))
    return str(path)


def test_each_video_is_measured_with_the_others_curve_and_the_model_gets_the_curve(
    script, posedesc_models, tmp_path
):
    runs = [run(v, v, tmp_path) for v in range(3)]
    model, out, figures = (
        posedesc_models / "posedesc-depth.onnx",
        tmp_path / "depth.onnx",
        tmp_path / "c.json",
    )
    cli = script("calibrate_detections")
    assert cli.main([str(model), *runs, "--out", str(out), "--json", str(figures)]) == 0
    result = json.loads(figures.read_text())
    assert set(result["leave_one_video_out"]) == {"0000", "0001", "0002"}
    for video in result["leave_one_video_out"].values():
        assert video["detections"] == 40  # the colour and the ignored detections left out
        assert video["verifier"]["ap50"] < video["calibrated"]["ap50"]  # one confidence for all: no ranking
        assert video["fitted_on_the_others"] != result["calibration"]
    curve = read_detect_confidence(Embedder(out).info.extra)
    assert curve is not None and curve.to_json() == result["calibration"]
    assert curve(0.9) > 0.5 > curve(0.1)  # more of it explained, more likely right
    assert Embedder(out).graph_digest == Embedder(model).graph_digest


def test_a_run_without_cues_or_a_single_video_is_refused(script, posedesc_models, tmp_path):
    cli = script("calibrate_detections")
    model = str(posedesc_models / "posedesc-depth.onnx")
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"scene": 0, "targets": 3, "posedesc": {"all": {}}}))
    with pytest.raises(SystemExit):
        cli.main([model, str(old), run(1, 1, tmp_path)])
    with pytest.raises(SystemExit):
        cli.main([model, run(1, 1, tmp_path)])
