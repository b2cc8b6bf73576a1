"""ONNX export: torch and onnxruntime agree to 1e-4, and the metadata says how to make the input."""

import numpy as np
import pytest
import torch

from index.features.embed import Embedder
from training.export import export_onnx, torch_descriptors
from training.model import DescriptorNet, NetConfig


@pytest.mark.slow  # over ~2 s (an export, a render): `make test`, not `make check`
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


@pytest.mark.slow  # over ~2 s (an export, a render): `make test`, not `make check`
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


@pytest.mark.slow
def test_mask_head_exports_as_a_third_output(tmp_path):
    """A model with a mask head answers its logits as a third output, as torch computes them; the
    embedder reads them as where the centred object is."""
    from training.heads.mask import MaskNet

    torch.manual_seed(0)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    mask = MaskNet().eval()  # as initialised: some pixels in, some out
    path = export_onnx(net, tmp_path / "m.onnx", 200.0, {"arch": "trunk"}, mask=mask)
    emb = Embedder(path)
    assert emb.has_mask and emb.has_local and emb.local_grid == 16
    x = np.random.default_rng(3).normal(size=(2, 3, 64, 64)).astype(np.float32)
    with torch.no_grad():
        logits = mask.head(*net.stem.stages(torch.from_numpy(x))).numpy()[:, 0]
    keep = emb.mask(x)
    decided = np.abs(logits) > 1e-4  # float32 on two runtimes: leave out the ties
    np.testing.assert_array_equal(keep[decided], (logits > 0)[decided])
    with torch.no_grad():  # nothing is the object
        mask.head.out.bias.fill_(-1e3)
    path = export_onnx(net, tmp_path / "none.onnx", 200.0, {"arch": "trunk"}, mask=mask)
    assert not Embedder(path).mask(x).any()
    with pytest.raises(ValueError, match="trunk"):
        export_onnx(DescriptorNet(NetConfig("rgb", 16)), tmp_path / "p.onnx", 200.0, mask=mask)


@pytest.mark.slow
def test_a_fine_tuned_mask_runs_its_own_trunk(tmp_path):
    """A mask head fine-tuned with its own copy of the trunk (`--mask-finetune`) exports that copy: the
    mask follows the copy's weights, the descriptor and local features the frozen trunk's."""
    from training.heads.mask import MaskNet

    torch.manual_seed(0)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    mask = MaskNet(own_stem=True)
    assert mask.backbone() and all(p.requires_grad for p in mask.stem.parameters())
    with torch.no_grad():  # the copy drifts from the descriptor's trunk
        for p in mask.stem.parameters():
            p.mul_(1.5)
    mask.eval()
    path = export_onnx(net, tmp_path / "own.onnx", 200.0, {"arch": "trunk"}, mask=mask)
    emb = Embedder(path)
    x = np.random.default_rng(4).normal(size=(2, 3, 64, 64)).astype(np.float32)
    with torch.no_grad():
        own = mask(torch.from_numpy(x)).numpy()[:, 0]
        shared = mask.head(*net.stem.stages(torch.from_numpy(x))).numpy()[:, 0]
    keep = emb.mask(x)
    decided = np.abs(own) > 1e-3
    np.testing.assert_array_equal(keep[decided], (own > 0)[decided])
    assert ((own > 0) != (shared > 0)).any()  # the copy, not the shared trunk, made the mask
    np.testing.assert_allclose(emb(x), torch_descriptors(net, x), atol=1e-4)


@pytest.mark.slow
def test_a_colour_model_exports_as_rgbd_with_its_mask_cut_from_depth(tmp_path):
    """The RGB-D model is the colour model on the colour channels (same descriptors and local features),
    and its mask is where the depth lies within NEAR in front of the centre's surface and FAR behind
    (under half the window: the network's depth input is clipped there)."""
    torch.manual_seed(0)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    rgb_path = export_onnx(net, tmp_path / "rgb.onnx", 200.0, {"arch": "trunk"})
    path = export_onnx(net, tmp_path / "rgbd.onnx", 200.0, {"arch": "trunk"}, depth_mask=(50.0, 90.0))
    rgbd, rgb = Embedder(path), Embedder(rgb_path)
    assert rgbd.modality == "rgbd" and rgbd.has_mask and rgbd.has_local
    colour = np.random.default_rng(4).integers(0, 255, (2, 64, 64, 3), dtype=np.uint8)
    depth = np.full((2, 64, 64), 600.0, np.float32)  # a wall behind everything
    depth[:, 16:48, 16:48] = 400.0  # the object, facing the camera: the surface at the centre
    depth[:, 20:30, 20:30] = 320.0  # something 80 mm in front of it
    np.testing.assert_allclose(
        rgbd.embed_patches(colour, depth, 400.0), rgb.embed_patches(colour, None, 400.0), atol=1e-5
    )
    from index.features.patches import batch_inputs

    keep = rgbd.mask(batch_inputs("rgbd", colour, depth, 400.0, 200.0))
    want = (depth > 400.0 - 50.0) & (depth < 400.0 + 90.0)
    assert want.any() and not want.all()
    np.testing.assert_array_equal(keep, want)
    with pytest.raises(ValueError, match="trunk"):
        export_onnx(DescriptorNet(NetConfig("rgb", 16)), tmp_path / "p.onnx", 200.0, depth_mask=(50.0, 90.0))
    with pytest.raises(ValueError, match="half the window"):
        export_onnx(net, tmp_path / "far.onnx", 200.0, depth_mask=(50.0, 150.0))
