"""The BOP reader on the real LM-O data (skipped where ../shared is absent) and on a scene it writes."""

import json

import cv2
import numpy as np
import pytest

from index.data.bop import BopDataset, instance_patch
from index.geometry.pose import View, view_to_pose
from index.geometry.symmetry import symmetry_rotations


def test_lmo_models_and_symmetries(lmo):
    ds = BopDataset(lmo)
    assert len(ds.obj_ids) >= 2
    for o in ds.obj_ids:
        info = ds.models_info[o]
        sym = ds.symmetry(o)
        assert (sym != "none") == bool(info.get("symmetries_discrete") or info.get("symmetries_continuous"))
        assert len(symmetry_rotations(sym)) >= 1


def test_lmo_instances(lmo):
    ds = BopDataset(lmo)
    all_insts = list(ds.instances(2))
    visible = list(ds.instances(2, min_visib=0.5))
    assert 0 < len(visible) < len(all_insts)
    assert all(i.visib_fract >= 0.5 for i in visible)
    inst = visible[0]
    assert inst.obj_id in ds.obj_ids and inst.depth_path is None
    # the pose as a view and back
    R, t = view_to_pose(inst.view, ray=inst.t)
    assert np.allclose(R, inst.R, atol=1e-3) and np.allclose(t, inst.t, atol=1e-6)  # annotations: 1e-4
    u, v = inst.centre_uv
    x, y, w, h = inst.bbox_visib
    assert x - w < u < x + 2 * w and y - h < v < y + 2 * h
    rgb, depth, view = instance_patch(inst)
    assert rgb.shape == (64, 64, 3) and depth is None and view.inplane == 0.0
    assert rgb.std() > 10  # a real picture, not a border


def test_patch_of_a_scene_written_here(tmp_path, renderer, l_shape):
    """A BOP scene with depth, written by the test: the patch at the true centre matches the template."""
    K = np.array([[572.4, 0, 325.3], [0, 573.6, 242.0], [0, 0, 1]])
    view = View(30, 40, 20, 700)
    R, t = view_to_pose(view, ray=[-0.2, 0.1, 1])
    rgb, depth = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    scene = tmp_path / "ds" / "test" / "000007"
    (scene / "rgb").mkdir(parents=True)
    (scene / "depth").mkdir()
    (tmp_path / "ds" / "models").mkdir()
    (tmp_path / "ds" / "models" / "models_info.json").write_text(json.dumps({"3": {"diameter": 150.0}}))
    cv2.imwrite(str(scene / "rgb" / "000000.png"), rgb[..., ::-1])
    cv2.imwrite(str(scene / "depth" / "000000.png"), (depth * 10).astype(np.uint16))  # 0.1 mm units
    gt = {"0": [{"obj_id": 3, "cam_R_m2c": R.ravel().tolist(), "cam_t_m2c": t.tolist()}]}
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    (scene / "scene_camera.json").write_text(
        json.dumps({"0": {"cam_K": K.ravel().tolist(), "depth_scale": 0.1}})
    )
    ds = BopDataset(tmp_path / "ds")
    (inst,) = list(ds.instances(7))
    assert inst.visib_fract == 1.0 and inst.depth_path is not None
    assert inst.view.inplane == pytest.approx(20, abs=1e-6)
    prgb, pdepth, v = instance_patch(inst)
    tmpl = renderer.render(l_shape, [View(30, 40, 0, 700)])
    a, b = tmpl.depth[0] > 0, pdepth > 0
    assert (a != b).mean() < 0.03
    assert np.abs(tmpl.depth[0][a & b] - pdepth[a & b]).mean() < 3  # depth_scale applied, mm along the axis


def test_annotated_rotations_are_rotations(lmo):
    """LM-O stores cam_R_m2c to a few digits (up to 1 % off orthonormal): the reader gives rotations."""
    from index.data.bop import BopDataset

    ds = BopDataset(lmo)
    for inst in list(ds.instances(ds.scene_dirs("test")[0]))[:50]:
        assert np.allclose(inst.R @ inst.R.T, np.eye(3), atol=1e-9)
        assert abs(np.linalg.det(inst.R) - 1.0) < 1e-9
