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


def test_mask_head_exports_and_blacks_out_what_is_not_the_object(tmp_path):
    """A model with a mask head answers its logits as a third output, equal to torch's; a query patch
    is blacked out where they are negative before it is described, and a template is not."""
    from training.mask import MaskHead

    torch.manual_seed(0)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    head = MaskHead()
    with torch.no_grad():  # a head whose answer is known: nothing is the object
        for p in head.parameters():
            p.zero_()
        head.out.bias.fill_(-1.0)
    path = export_onnx(net, tmp_path / "m.onnx", 200.0, {"arch": "trunk"}, mask=head)
    emb = Embedder(path)
    assert emb.has_mask and emb.has_local
    rgb = np.random.default_rng(2).integers(0, 255, (2, 64, 64, 3), dtype=np.uint8)
    x = np.random.default_rng(3).normal(size=(2, 3, 64, 64)).astype(np.float32)
    with torch.no_grad():
        want = head.eval()(*net.stem.stages(torch.from_numpy(x))).numpy()[:, 0] > 0
    np.testing.assert_array_equal(emb.mask(x), want)
    assert not want.any()  # bias -1 everywhere: nothing is the object
    out, _ = emb.foreground(rgb, None, 400.0)
    assert not out.any()
    assert not np.allclose(
        emb.embed_patches(rgb, None, 400.0, masked=True), emb.embed_patches(rgb, None, 400.0)
    )
    with torch.no_grad():
        head.out.bias.fill_(1.0)  # everything is the object: the query is described as it is
    path = export_onnx(net, tmp_path / "all.onnx", 200.0, {"arch": "trunk"}, mask=head)
    emb = Embedder(path)
    np.testing.assert_allclose(
        emb.embed_patches(rgb, None, 400.0, masked=True), emb.embed_patches(rgb, None, 400.0), atol=1e-5
    )
    with pytest.raises(ValueError, match="trunk"):
        export_onnx(DescriptorNet(NetConfig("rgb", 16)), tmp_path / "p.onnx", 200.0, mask=head)
