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


def test_trunk_model_exports_with_its_pretrained_weights(tmp_path):
    """The pretrained trunk travels inside the ONNX file: serving needs no weights package."""
    torch.manual_seed(0)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    path = export_onnx(net, tmp_path / "t.onnx", 200.0, {"arch": "trunk", "inplane_step": "30.0"})
    emb = Embedder(path)
    assert emb.dim == 32 and emb.info.inplane_step == 30.0
    x = np.random.default_rng(1).normal(size=(3, 3, 64, 64)).astype(np.float32)
    np.testing.assert_allclose(emb(x), torch_descriptors(net, x), atol=1e-4)


def test_trunk_is_imagenet_mobilenet_and_frozen():
    from training.trunk import Trunk

    trunk = Trunk()
    w = trunk.features[0][0].weight
    assert w.shape == (32, 3, 3, 3) and not w.requires_grad
    assert float(w.abs().sum()) > 1.0  # loaded, not zero-initialised
    trunk.train()
    assert not trunk.training  # BatchNorm keeps ImageNet's statistics
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    trainable = [n for n, p in net.named_parameters() if p.requires_grad]
    assert trainable and all(n.startswith("body.") for n in trainable)
    with pytest.raises(ValueError, match="colour only"):
        DescriptorNet(NetConfig("depth", 32, arch="trunk"))
