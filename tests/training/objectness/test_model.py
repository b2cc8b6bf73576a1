"""training/objectness/: the targets a crop's objects make, the network's shapes, the loss's sign, the export."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from index.features.objectness import ObjectnessNet as OnnxNet  # noqa: E402
from training.objectness.config import STRIDE, ObjectnessConfig  # noqa: E402
from training.objectness.model import ObjectnessNet, Scored, centre_loss  # noqa: E402
from training.objectness.samples import _targets  # noqa: E402
from training.objectness.train import export  # noqa: E402


def test_a_target_peaks_at_its_cell_with_its_offset_and_sizes() -> None:
    cfg = ObjectnessConfig(crop=64)
    u, v = 8 * 3 + 3.5 + 2.0, 8 * 5 + 3.5 - 1.0  # 2 px right of cell (5, 3)'s centre, 1 px above
    heat, weight, reg, reg_w = _targets(np.array([[u, v, 64.0, 32.0, 1.0, 0]]), cfg)
    assert heat.shape == (8, 8) and heat[5, 3] == 1.0 and (heat < 1).sum() == 63
    assert weight.min() == 1.0
    assert reg[0, 5, 3] == pytest.approx(2 / STRIDE) and reg[1, 5, 3] == pytest.approx(-1 / STRIDE)
    assert reg[2, 5, 3] == pytest.approx(0.0) and reg[3, 5, 3] == pytest.approx(math.log(0.5))
    assert reg_w[5, 3] == 1.0 and reg_w[0, 0] == 0.0


def test_objects_out_of_the_heads_range_are_ignored_near_it_and_background_far_from_it() -> None:
    cfg = ObjectnessConfig(crop=64)
    near = _targets(np.array([[30.0, 30.0, 120.0, 100.0, 1.0, 0]]), cfg)  # in the band around the range
    far = _targets(np.array([[30.0, 30.0, 300.0, 200.0, 1.0, 0]]), cfg)
    hidden = _targets(np.array([[30.0, 30.0, 64.0, 60.0, 0.2, 0]]), cfg)  # in range, too hidden
    assert near[0].max() == 0 and near[1][3, 3] == 0 and near[1][0, 7] == 1
    assert far[0].max() == 0 and far[1].min() == 1
    assert hidden[0].max() == 0 and hidden[1][3, 3] == 0


def test_a_held_out_object_is_neither_target_nor_background_and_unknown_cells_are_unscored() -> None:
    cfg = ObjectnessConfig(crop=64)
    held = _targets(np.array([[20.0, 20.0, 64.0, 60.0, 1.0, 2]]), cfg)  # kind 2: held out
    assert held[0].max() == 0 and held[1][2, 2] == 0 and held[1][7, 7] == 1
    unknown = np.ones((8, 8), bool)  # a real crop whose background nobody labelled
    one = _targets(np.array([[20.0, 20.0, 64.0, 60.0, 1.0, 0]]), cfg, unknown)
    assert one[0][2, 2] == 1.0 and one[1][2, 2] == 1 and one[1][7, 7] == 0  # scored around it only
    assert _targets(np.zeros((0, 6)), cfg, unknown)[1].max() == 0


def test_shuffled_tiles_keep_the_crops_pixels() -> None:
    from training.objectness.samples import _shuffled_tiles

    img = np.random.default_rng(0).integers(0, 255, (96, 96, 3), dtype=np.uint8)
    out = _shuffled_tiles(img, np.random.default_rng(1))
    assert out.shape == img.shape and not np.array_equal(out, img)
    assert (
        abs(float(out.mean()) - float(img.mean())) < 10
    )  # tiles moved, not invented (edge tiles may be cut)


def test_the_network_maps_a_frame_to_cells_and_the_loss_prefers_the_truth() -> None:
    net = ObjectnessNet(width=8, pretrained=False)
    with torch.no_grad():
        y = Scored(net).eval()(torch.zeros(2, 3, 48, 80))
    assert y.shape == (2, 5, 6, 10) and float(y[:, 0].min()) >= 0 and float(y[:, 0].max()) <= 1
    heat = torch.zeros(1, 6, 10)
    heat[0, 2, 3] = 1.0
    weight = torch.ones(1, 6, 10)
    right = torch.full((1, 6, 10), -5.0)
    right[0, 2, 3] = 5.0
    wrong = torch.full((1, 6, 10), -5.0)
    wrong[0, 4, 7] = 5.0
    assert float(centre_loss(right, heat, weight)) < float(centre_loss(wrong, heat, weight))


# torch.onnx.export: ~9 s on 2 cores
@pytest.mark.slow
def test_the_export_runs_in_onnxruntime_as_in_torch_at_any_size(tmp_path: Path) -> None:
    net = ObjectnessNet(width=8, pretrained=False).eval()
    path = export(net, ObjectnessConfig(width=8), tmp_path / "o.onnx", {"command": "test"})
    onnx_net = OnnxNet(path)
    assert onnx_net.stride == STRIDE and onnx_net.metadata["command"] == "test"
    x = np.random.default_rng(0).uniform(0, 255, (1, 3, 64, 112)).astype(np.float32)
    with torch.no_grad():
        expected = Scored(net)(torch.from_numpy(x))[0].numpy()
    np.testing.assert_allclose(onnx_net(x), expected, atol=1e-4)
