"""BOP's VSD in the evaluation's "bop" blocks (`evaluation.bop.vsd`): on a frame whose recorded depth is a
real render of a box with a bump on its back, a pose whose difference from the truth is hidden (the bump
turned to elsewhere on the back) is right by VSD and wrong by MSSD; a pose 100 mm off is wrong by both; the
detect protocol's matching takes VSD as it takes the others; frames without recorded depth get no VSD."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from evaluation.bop.csv import Estimate
from evaluation.bop.recall import VSD_TAUS
from evaluation.bop.scores import Best, bop_block, detections_block, object_model
from evaluation.bop.vsd import NO_VSD_NOTE, VSD_NOTE, vsd_for
from evaluation.paper.samples import REAL, SYNTHETIC
from index.data.bop import Instance

K = np.array([[572.4, 0.0, 320.0], [0.0, 573.6, 240.0], [0.0, 0.0, 1.0]])
W, H = 640, 480
#: turned half a turn about the camera's axis: the front face's outline is the same, the bump moves
HALF_TURN = np.diag([-1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def bumped() -> trimesh.Trimesh:
    """A 60 x 40 x 30 mm box, its -z face towards a camera looking along +z, a bump on its back (+z) face
    off the middle."""
    box = trimesh.creation.box(extents=[60, 40, 30])
    bump = trimesh.creation.box(extents=[15, 15, 20])
    bump.apply_translation([17, 0, 25])
    return trimesh.util.concatenate([box, bump])


@pytest.fixture(scope="module")
def scene(bumped, renderer, tmp_path_factory):
    """One instance of the box 600 mm in front of the camera, with the render of it as its recorded depth
    (16-bit PNG, 0.1 mm units, as YCB-Video stores it)."""
    R, t = np.eye(3), np.array([0.0, 0.0, 600.0])
    _, depth = renderer.render_frame([(bumped, R, t)], K, W, H)
    path = tmp_path_factory.mktemp("vsd") / "000000.png"
    cv2.imwrite(str(path), np.round(depth * 10).astype(np.uint16))
    inst = Instance(1, 0, 0, 1, R, t, K, None, path, 0.1, 1.0, None)
    info = {"diameter": float(np.linalg.norm(bumped.extents))}
    return inst, {1: object_model(info, bumped)}, {1: bumped}


def vsd_of(inst, models, meshes):
    return vsd_for([inst], meshes, {o: m.diameter for o, m in models.items()}, REAL)


def test_a_hidden_difference_is_right_by_vsd_and_wrong_by_mssd(scene):
    inst, models, meshes = scene
    turned = Best(1, HALF_TURN, inst.t, 0.9, 0.1)
    far = Best(1, inst.R, inst.t + np.array([0.0, 0.0, 100.0]), 0.9, 0.1)
    vsd = vsd_of(inst, models, meshes)
    try:
        exact = bop_block([inst], [Best(1, inst.R, inst.t, 0.9, 0.1)], models, W, 0.5, vsd)
        hidden = bop_block([inst], [turned], models, W, 0.5, vsd)
        off = bop_block([inst], [far], models, W, 0.5, vsd)
        missing = bop_block([inst], [None], models, W, 0.5, vsd)
    finally:
        vsd.close()
    assert exact["ar_vsd"] == 1.0 and exact["ar"] == 1.0 and exact["vsd"] == VSD_NOTE
    assert max(exact["per_instance"][0]["vsd"]) < 0.01
    row = hidden["per_instance"][0]
    assert len(row["vsd"]) == len(VSD_TAUS) and max(row["vsd"]) < 0.05  # the camera sees the same surface
    assert row["mssd"] > 0.3 * models[1].diameter and hidden["ar_mssd"] < 0.5  # the bump moved 34 mm
    assert hidden["ar_vsd"] == 1.0 and hidden["ar"] == pytest.approx(
        (1.0 + hidden["ar_mssd"] + hidden["ar_mspd"]) / 3
    )
    assert min(off["per_instance"][0]["vsd"]) > 0.9 and off["ar_vsd"] == 0.0
    assert missing["per_instance"][0]["vsd"] is None and missing["ar_vsd"] == 0.0


def test_detections_are_matched_by_vsd_as_by_the_other_errors(scene):
    inst, models, meshes = scene
    est = [
        Estimate(1, 0, 1, 0.9, HALF_TURN, inst.t),  # best-scored: the hidden turn, right by VSD only
        Estimate(1, 0, 1, 0.5, inst.R, inst.t),  # the exact pose, not counted: one target, one estimate
    ]
    vsd = vsd_of(inst, models, meshes)
    try:
        b = detections_block([inst], est, models, W, vsd)
    finally:
        vsd.close()
    assert b["ar_vsd"] == 1.0 and b["ar_mssd"] < 0.5 and b["vsd"] == VSD_NOTE
    assert b["per_object"]["1"]["ar_vsd"] == 1.0


def test_no_vsd_without_recorded_depth_or_on_synthetic_frames(scene):
    inst, models, meshes = scene
    diam = {1: models[1].diameter}
    assert vsd_for([inst], meshes, diam, SYNTHETIC) is None
    no_depth = Instance(1, 0, 0, 1, inst.R, inst.t, K, None, None, 1.0, 1.0, None)
    assert vsd_for([no_depth], meshes, diam, REAL) is None
    b = bop_block([no_depth], [Best(1, inst.R, inst.t, 0.9, 0.1)], models, W, 0.5)
    assert b["ar_vsd"] is None and b["vsd"] == NO_VSD_NOTE and "vsd" not in b["per_instance"][0]
