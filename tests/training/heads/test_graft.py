"""A fine-tuned mask head put into exported models (`posedesc export --onto`): rgb gets the head's mask,
RGB-D the pixels both its depth band and the head keep; descriptors and local features unchanged."""

import json

import numpy as np
import pytest
import torch

from index.features.embed import Embedder
from posedesc.cli import main
from training.export import export_onnx
from training.heads.graft import LocalMap, graft_local, graft_mask
from training.heads.local import LocalTrunk
from training.heads.mask import MaskNet
from training.model import DescriptorNet, NetConfig

# trains and grafts real heads: `make test`, not `make check`; the module's models exported once, on one worker
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("graft")]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(2)
    folder = tmp_path_factory.mktemp("graft")
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    rgb = export_onnx(
        net, folder / "rgb.onnx", 200.0, {"arch": "trunk", "reject_above": "{}"}, mask=MaskNet().eval()
    )
    rgbd = export_onnx(net, folder / "rgbd.onnx", 200.0, {"arch": "trunk"}, depth_mask=(40.0, 90.0))
    mask = MaskNet(own_stem=True)
    with torch.no_grad():  # a copy that is not ImageNet's any more
        for p in mask.stem.parameters():
            p.mul_(1.3)
    return rgb, rgbd, mask.eval()


def test_an_rgb_model_takes_the_head_and_keeps_its_descriptors(exported, tmp_path):
    rgb, _, mask = exported
    out = graft_mask(rgb, mask, tmp_path / "g.onnx", {"step": 7})
    before, after = Embedder(rgb), Embedder(out)
    x = np.random.default_rng(0).normal(size=(3, 3, 64, 64)).astype(np.float32)
    np.testing.assert_array_equal(before(x), after(x))
    np.testing.assert_array_equal(before.local(x), after.local(x))
    with torch.no_grad():
        logits = mask(torch.from_numpy(x)).numpy()[:, 0]
    decided = np.abs(logits) > 1e-3
    np.testing.assert_array_equal(after.mask(x)[decided], (logits > 0)[decided])
    assert (after.mask(x) != before.mask(x)).any()  # the old head is gone
    assert json.loads(after.info.extra["mask"]) == {"step": 7, "from": "learnt"}
    assert after.info.extra["arch"] == "trunk"  # the rest of the metadata carried over
    assert "reject_above" in before.info.extra and "reject_above" not in after.info.extra  # stale


def test_an_rgbd_model_keeps_what_depth_and_head_both_keep(exported, tmp_path):
    _, rgbd, mask = exported
    out = graft_mask(rgbd, mask, tmp_path / "g.onnx")
    before, after = Embedder(rgbd), Embedder(out)
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3, 4, 64, 64)).astype(np.float32)
    x[:, 3] = rng.uniform(-1.0, 1.0, (3, 64, 64))  # depth across the band's edges
    np.testing.assert_array_equal(before(x), after(x))
    with torch.no_grad():
        learnt = mask(torch.from_numpy(x[:, :3])).numpy()[:, 0] > 0
    both = before.mask(x) & learnt
    assert 0 < both.sum() < before.mask(x).sum()
    np.testing.assert_array_equal(after.mask(x), both)
    assert json.loads(after.info.extra["mask"])["from"] == "depth and learnt"


def test_what_cannot_take_a_head(exported, posedesc_models, tmp_path):
    rgb, _, mask = exported
    with pytest.raises(ValueError, match="mask-finetune"):
        graft_mask(rgb, MaskNet().eval(), tmp_path / "a.onnx")  # shares the descriptor's trunk
    with pytest.raises(ValueError, match="not a colour trunk model"):
        graft_mask(posedesc_models / "posedesc-depth.onnx", mask, tmp_path / "b.onnx")


def test_local_features_of_a_fine_tuned_trunk_replace_the_models(exported, tmp_path, posedesc_models):
    """`graft_local`: the model's local output is the trunk copy's map (unit length, flattened, from the
    colour channels, RGB-D too); descriptor and mask stay node for node the model's."""
    rgb, rgbd, _ = exported
    trunk = LocalTrunk()
    with torch.no_grad():
        for p in trunk.features[2:].parameters():
            p.mul_(1.2)
    x = np.random.default_rng(3).normal(size=(3, 4, 64, 64)).astype(np.float32)
    for model, channels in ((rgb, 3), (rgbd, 4)):
        out = graft_local(model, trunk, tmp_path / f"l{channels}.onnx", {"step": 5})
        before, after = Embedder(model), Embedder(out)
        np.testing.assert_array_equal(before(x[:, :channels]), after(x[:, :channels]))
        np.testing.assert_array_equal(before.mask(x[:, :channels]), after.mask(x[:, :channels]))
        with torch.no_grad():
            want = LocalMap(trunk)(torch.from_numpy(x[:, :channels])).numpy()
        np.testing.assert_allclose(after.local(x[:, :channels]), want, atol=2e-3)  # stored as float16
        assert np.abs(after.local(x[:, :channels]) - before.local(x[:, :channels])).max() > 1e-3
        assert json.loads(after.info.extra["local"]) == {"step": 5}
    with pytest.raises(ValueError, match="no local features"):
        graft_local(posedesc_models / "posedesc-depth.onnx", trunk, tmp_path / "d.onnx")


def test_the_export_command_says_what_onto_needs(tmp_path, capsys):
    model = tmp_path / "m.onnx"
    model.write_bytes(b"")
    for options, says in [
        ((), "--onto needs --mask MASK_RUN"),
        (("--local", str(tmp_path)), "has no local.pt"),
        (("--mask", str(tmp_path)), "has no mask.pt"),
        (("--local", str(tmp_path), "--as-rgbd", "1:2"), "no run folder, no --as-rgbd"),
    ]:
        assert main(["export", "--onto", str(model), "--out", str(tmp_path / "o.onnx"), *options]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err
