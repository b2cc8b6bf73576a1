"""Frames sent again at camera rolls (`evaluation.rolls`, `posedesc evaluate --rolls`): the turned frame
shows the turned pose (checked with the real renderer), roll 0 is the frame itself, centres that leave
the frame are dropped and counted, and the service protocol sends every frame at every roll."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from evaluation.masks import visible_masks
from evaluation.queries import frame_files
from evaluation.rolls import RolledFrames, homography, inside, parse_rolls, roll_image, roll_instance
from index.data.bop import BopDataset
from posedesc.cli import main

# the session's tiny BOP dataset and untrained models: made once, on one worker
pytestmark = pytest.mark.xdist_group("tiny-bop")
# every test of the tiny dataset (rendered frames, untrained models made for it) is `slow`: `make test`


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.mark.slow
@pytest.mark.parametrize("degrees", [30.0, 90.0, 200.0])
def test_the_turned_frame_shows_the_turned_pose(tiny_bop, renderer, degrees):
    dataset = BopDataset(tiny_bop)
    inst = next(dataset.instances(2))
    mesh = dataset.mesh(inst.obj_id)
    mask = visible_masks(renderer, [inst], {inst.obj_id: mesh}, 640, 480)[0]
    turned = roll_image(mask.astype(np.uint8), inst.K, degrees, depth=True).astype(bool)
    rolled = roll_instance(inst, degrees)
    expected = visible_masks(renderer, [rolled], {inst.obj_id: mesh}, 640, 480)[0]
    assert _iou(turned, expected) > 0.93  # a rasterised outline, resampled: ±½ px
    # the other way round is another pose: the check can fail
    wrong = visible_masks(renderer, [roll_instance(inst, -degrees)], {inst.obj_id: mesh}, 640, 480)[0]
    assert _iou(turned, wrong) < 0.8
    u, v = inst.centre_uv
    p = homography(inst.K, degrees) @ np.array([u, v, 1.0])
    np.testing.assert_allclose(p[:2] / p[2], rolled.centre_uv, atol=1e-6)
    # the object's own in-plane angle turns with the camera; its distance stays
    assert rolled.view.distance == pytest.approx(inst.view.distance)
    np.testing.assert_allclose(rolled.R @ rolled.R.T, np.eye(3), atol=1e-9)


@pytest.mark.slow
def test_roll_zero_is_the_frame_itself_and_centres_that_leave_are_dropped(tiny_bop):
    dataset = BopDataset(tiny_bop)
    instances = [i for i in dataset.instances(2) if i.frame_id < 2]
    frames = list(frame_files(dataset, instances, "rgb", "real", 0))
    near_corner = replace(instances[0], t=np.linalg.inv(instances[0].K) @ np.array([630.0, 470.0, 1.0]) * 700)
    assert inside(near_corner, 640, 480) and not inside(roll_instance(near_corner, 90), 640, 480)
    frames.append(([near_corner], frames[0][1], None, 1.0))
    rolled = RolledFrames(frames, (0.0, 90.0, 180.0))
    sent = list(rolled)
    assert len(sent) == 2 * 3 + 2  # the corner instance: at 0 and at 180, not at 90
    assert rolled.dropped == 1
    assert sum(len(g) for g, *_ in sent) + rolled.dropped == 3 * (len(instances) + 1)
    group, rgb, depth, scale, roll = sent[0]
    assert roll == 0 and rgb is frames[0][1] and group is frames[0][0]
    _, rgb90, _, _, roll90 = sent[1]
    image = cv2.imdecode(np.frombuffer(rgb90, np.uint8), cv2.IMREAD_COLOR)
    original = cv2.imdecode(np.frombuffer(rgb, np.uint8), cv2.IMREAD_COLOR)
    assert roll90 == 90 and image.shape == original.shape and not np.array_equal(image, original)


def test_depth_is_turned_without_inventing_values():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    depth = np.zeros((480, 640), np.uint16)
    depth[200:280, 250:400] = 812
    depth[220:240, 300:320] = 790
    turned = roll_image(depth, K, 33.0, depth=True)
    assert turned.dtype == np.uint16 and set(np.unique(turned)) <= {0, 790, 812}
    assert (turned == 790).sum() == pytest.approx((depth == 790).sum(), rel=0.1)


def test_parse_rolls():
    assert parse_rolls("0, 72,144") == (0.0, 72.0, 144.0)
    for bad in ("", "a", "0,0", "360", "-5", "nan"):
        with pytest.raises(ValueError):
            parse_rolls(bad)


@pytest.mark.slow
def test_service_protocol_sends_every_frame_at_every_roll(tiny_bop, untrained_models, tmp_path, capsys):
    out = tmp_path / "rolled.json"
    args = ["evaluate", "--dataset", str(tiny_bop), "--modality", "rgb", "--methods", "ours"]
    args += ["--model", str(untrained_models["rgb"]), "--frames", "0-1", "--inplane-step", "90"]
    assert main([*args, "--rolls", "0,120,240", "--json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["n_samples"] == 2 * 2 * 3 and s["rolls"] == [0, 120, 240] and s["rolls_dropped"] == 0
    assert s["timing_ms"]["calls"] == 12 and any("camera rolls of 0, 120, 240" in n for n in s["notes"])
    capsys.readouterr()
    assert main([*args, "--rolls", "0,0", "--json", str(out)]) == 2
    assert "--rolls" in capsys.readouterr().err
    assert main([*args, "--protocol", "paper", "--rolls", "0,90", "--json", str(out)]) == 2
    assert "needs the service protocol" in capsys.readouterr().err
