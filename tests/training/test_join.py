"""training/join.py (`python -m training.join`): depth networks as one model, served as any model is."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from index.features.embed import Embedder

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("n", [2, 3])
def test_the_joined_descriptor_is_each_side_by_side_and_the_calibration_is_dropped(
    posedesc_models, tmp_path, n
):
    depth = posedesc_models / "posedesc-depth.onnx"
    out = tmp_path / "posedesc-depth.onnx"
    run = subprocess.run(
        [sys.executable, "-m", "training.join", *[str(depth)] * n, "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    x = np.random.default_rng(0).uniform(-1, 1, (3, 1, 64, 64)).astype(np.float32)
    one = ort.InferenceSession(str(depth)).run(None, {"patch": x})[0]
    both = ort.InferenceSession(str(out)).run(None, {"patch": x})[0]
    assert both.shape == (3, n * one.shape[1])
    np.testing.assert_allclose(both * n**0.5, np.concatenate([one] * n, axis=1), rtol=1e-5, atol=1e-6)
    # the same network twice: the same distances as the network alone
    assert np.isclose(np.linalg.norm(both[0] - both[1]), np.linalg.norm(one[0] - one[1]), rtol=1e-5)
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert (
        "reject_above" not in meta
        and "detect_confidence" not in meta
        and meta["descriptor_dim"] == str(16 * n)
    )
    e = Embedder(out)  # the service reads it as a depth model of 16 n values
    assert e.modality == "depth" and e.dim == 16 * n


def test_models_that_cannot_be_joined_are_one_line(posedesc_models, tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "training.join", str(posedesc_models / "posedesc-depth.onnx"),
         str(posedesc_models / "posedesc-rgb.onnx"), "--out", str(tmp_path / "x.onnx")],
        cwd=ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode != 0
    assert run.stderr.strip().count("\n") == 0 and run.stderr.startswith("error: ")
    assert not (tmp_path / "x.onnx").exists()
