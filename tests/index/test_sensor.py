import numpy as np

from index.sensor import SensorModel, fractal_noise, random_background


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
