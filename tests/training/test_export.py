"""ONNX export: torch and onnxruntime agree to 1e-4, and the metadata says how to make the input."""

import numpy as np
import pytest
import torch

from index.embed import Embedder
from training.export import export_onnx, torch_descriptors
from training.model import DescriptorNet, NetConfig


@pytest.mark.parametrize("modality", ["rgb", "depth", "rgbd"])
def test_onnx_matches_torch(modality, tmp_path):
    torch.manual_seed(0)
    net = DescriptorNet(NetConfig(modality, 16))
    path = export_onnx(net, tmp_path / "m.onnx", 200.0, {"command": "posedesc train ...", "data": "[]"})
    emb = Embedder(path)
    assert emb.info.modality == modality and emb.dim == 16 and emb.info.window_mm == 200.0
    assert emb.info.extra["command"] == "posedesc train ..."
    x = np.random.default_rng(0).normal(size=(5, net.cfg.channels, 64, 64)).astype(np.float32)
    np.testing.assert_allclose(emb(x), torch_descriptors(net, x), atol=1e-4)
    np.testing.assert_allclose(emb(x[:1]), torch_descriptors(net, x[:1]), atol=1e-4)  # dynamic batch
