"""The BOP reader on the one real Kinect depth frame (../shared/data/lmo-depth; skipped where absent)."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from index.data.bop import BopDataset, instance_patch

LMO_DEPTH = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "lmo-depth"


@pytest.fixture(scope="module")
def lmo_depth() -> Path:
    if not (LMO_DEPTH / "models" / "models_info.json").is_file():
        pytest.skip(f"real depth not present at {LMO_DEPTH}")
    return LMO_DEPTH


def test_depth_is_read_in_mm(lmo_depth):
    ds = BopDataset(lmo_depth)
    insts = list(ds.instances(2))
    assert len(insts) == 7 and {i.frame_id for i in insts} == {3}
    inst = insts[0]
    assert inst.depth_path is not None and inst.depth_scale == 1.0
    depth = inst.load_depth()
    assert depth.shape == (480, 640) and depth.dtype == np.float32
    assert 0.9 < (depth > 0).mean() < 1.0  # a real sensor: some holes
    for inst in insts:
        if inst.visib_fract < 0.9:
            continue
        # the surface at the object's centre lies in front of its origin, by less than its radius
        u, v = (int(c) for c in inst.centre_uv)
        window = depth[v - 7 : v + 8, u - 7 : u + 8]
        surface = float(np.median(window[window > 0]))
        radius = ds.models_info[inst.obj_id]["diameter"] / 2
        assert inst.t[2] - radius < surface < inst.t[2] + 10, inst.obj_id


def test_depth_scale_is_applied(lmo_depth, tmp_path):
    """The same frame stored in 0.1 mm with depth_scale 0.1 reads as the same millimetres."""
    src = lmo_depth / "test" / "000002"
    scene = tmp_path / "test" / "000002"
    (scene / "depth").mkdir(parents=True)
    (tmp_path / "models").mkdir()
    shutil.copy(lmo_depth / "models" / "models_info.json", tmp_path / "models")
    for name in ("scene_gt.json", "scene_gt_info.json"):
        shutil.copy(src / name, scene)
    cams = json.loads((src / "scene_camera.json").read_text())
    for cam in cams.values():
        cam["depth_scale"] = 0.1
    (scene / "scene_camera.json").write_text(json.dumps(cams))
    raw = cv2.imread(str(src / "depth" / "000003.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    cv2.imwrite(str(scene / "depth" / "000003.png"), (raw.astype(np.uint32) * 10).astype(np.uint16))

    mm = next(BopDataset(lmo_depth).instances(2)).load_depth()
    inst = next(BopDataset(tmp_path).instances(2))
    assert inst.depth_scale == pytest.approx(0.1) and inst.rgb_path is None
    np.testing.assert_allclose(inst.load_depth(), mm, atol=1e-3)


def test_real_depth_agrees_with_the_ground_truth(lmo_depth, renderer):
    """Real depth, camera and poses agree: the frame rendered from its annotations matches the Kinect's
    depth on the objects to millimetres, and the depth patch at an object's centre holds it."""
    ds = BopDataset(lmo_depth)
    insts = list(ds.instances(2))
    real = insts[0].load_depth()
    scene = [(ds.mesh(i.obj_id, max_faces=5000), i.R, i.t) for i in insts]
    _, rendered = renderer.render_frame(scene, insts[0].K, 640, 480)
    on = (rendered > 0) & (real > 0)
    assert (real[rendered > 0] > 0).mean() > 0.95  # objects are well measured
    residual = real[on] - rendered[on]
    assert abs(np.median(residual)) < 5.0 and np.median(np.abs(residual)) < 10.0
    inst = max(insts, key=lambda i: i.visib_fract)
    _, patch, view = instance_patch(inst, rgb=np.zeros((480, 640, 3), np.uint8), depth=real)
    centre = patch[24:40, 24:40]
    assert (centre > 0).mean() > 0.9
    assert view.distance - 150 < np.median(centre[centre > 0]) < view.distance + 10
