"""`index.geometry.sensor`, the model that makes renders look like a real Kinect's frames: noise growing with
distance, quantisation and edge holes, backgrounds, and the support plane of real frames."""

import numpy as np
import pytest

from index.geometry.sensor import SensorModel, fractal_noise, random_background


def test_sensor_noise_grows_with_distance():
    rng = np.random.default_rng(0)
    s = SensorModel(quantise=False, edge_dropout=0, random_dropout=0)
    near = s.apply(None, np.full((64, 64), 500.0), rng)[1]
    far = s.apply(None, np.full((64, 64), 1500.0), rng)[1]
    assert 0.5 < near.std() < far.std() < 6


def test_quantisation_steps_and_edge_holes():
    rng = np.random.default_rng(1)
    d = np.full((64, 64), 1000.0, np.float32)
    d[:, 32:] = 1200.0
    _, out = SensorModel(depth_noise=False, random_dropout=0, edge_dropout=1.0).apply(None, d, rng)
    assert (out[:, 31:33] == 0).all()  # the depth edge is gone
    assert len(np.unique(out[:, :20])) == 1 and abs(out[0, 0] - 1000) < 3  # quantised, close


def test_background_composited_where_empty():
    rng = np.random.default_rng(2)
    rgb = np.full((32, 32, 3), 128, np.uint8)
    depth = np.zeros((32, 32), np.float32)
    depth[8:24, 8:24] = 600
    bg_rgb, bg_depth = random_background((32, 32), rng, 600)
    assert (bg_depth > 600).all()
    out_rgb, out_depth = SensorModel(edge_dropout=0, random_dropout=0).apply(
        rgb, depth, rng, bg_rgb, bg_depth
    )
    assert (out_depth[0] > 600).all() and abs(out_depth[16, 16] - 600) < 10
    assert out_rgb.dtype == np.uint8 and out_rgb.shape == rgb.shape


def test_fractal_noise_range():
    n = fractal_noise((40, 50), np.random.default_rng(3))
    assert n.shape == (40, 50) and n.min() == 0 and abs(n.max() - 1) < 1e-5


def test_support_plane_depth_meets_the_object_bottom():
    from index.geometry.pose import View, view_to_pose
    from index.geometry.sensor import plane_depth, support_plane

    K = np.array([[300.0, 0, 63.5], [0, 300.0, 63.5], [0, 0, 1]])
    R, t = view_to_pose(View(30.0, 40.0, 0.0, 400.0))
    n, d = support_plane(R, t, -50.0)
    z = plane_depth(K, n, d, (128, 128))
    for p_obj in ([0, 0, -50.0], [40, -30, -50.0]):  # points on the object's own plane z = -50
        p = R @ np.array(p_obj) + t
        u, v = (K @ p / p[2])[:2]
        assert abs(z[int(round(v)), int(round(u))] - p[2]) < 4.0
    assert z[0, 64] == 0 or z[0, 64] > z[127, 64]  # the plane recedes upwards in the image
    assert z[127, 64] > 0


def test_fit_plane_and_table_of_real_frames(lmo):
    from pathlib import Path

    from index.data.bop import BopDataset, table_depth
    from index.geometry.sensor import fit_plane

    n, d, residual = fit_plane(np.array([[0, 0, 1000.0], [100, 0, 1000], [0, 100, 1100], [100, 100, 1100]]))
    assert residual < 1e-6 and n @ np.array([0, 0, 1000.0]) == pytest.approx(d) and d < 0

    ds = BopDataset(Path(lmo))
    insts = list(ds.instances(ds.scene_dirs("test")[0]))
    frame = [i for i in insts if i.frame_id == insts[0].frame_id]
    meshes = [ds.mesh(i.obj_id, max_faces=2000) for i in frame]
    z = table_depth(frame, meshes, 640, 480)
    assert (z > 0).mean() > 0.5  # LM-O's objects stand on one table
    for inst, m in zip(frame, meshes, strict=True):
        (x0, y0, z0), (x1, y1, _) = m.bounds
        p = inst.R @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, z0]) + np.ravel(inst.t)
        u, v = (inst.K @ p / p[2])[:2]
        if 0 <= u < 640 and 0 <= v < 480:
            assert abs(z[int(v), int(u)] - p[2]) < 20.0
    assert not table_depth(frame[:2], meshes[:2], 640, 480).any()  # two objects do not make a table


def test_a_steep_smooth_surface_keeps_its_depth():
    yy, xx = np.mgrid[0:64, 0:64].astype(np.float32)
    slope = 600.0 + 12.0 * yy + 3.0 * xx  # 12 mm a pixel: a table seen at a grazing angle
    _, out = SensorModel(depth_noise=False, quantise=False, random_dropout=0, edge_dropout=1.0).apply(
        None, slope, np.random.default_rng(3)
    )
    assert (out[1:-1, 1:-1] > 0).all()
