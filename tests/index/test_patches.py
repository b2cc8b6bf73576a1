import numpy as np
import pytest

from index.patches import (
    PatchSpec,
    batch_inputs,
    fill_depth,
    network_input,
    normalise_depth,
    normalise_rgb,
    surface_depth,
)


def test_known_depth_maps_to_known_value():
    # window 200 mm: +-100 mm around the centre maps to [-1, 1]
    d = np.array([[900.0, 950.0, 1000.0], [1050.0, 1100.0, 1500.0], [0.0, 700.0, 1000.0]])
    n = normalise_depth(d, centre_mm=1000.0, window_mm=200.0)
    assert n[0, 0] == pytest.approx(-1.0) and n[0, 1] == pytest.approx(-0.5) and n[0, 2] == 0
    assert n[1, 0] == pytest.approx(0.5) and n[1, 1] == pytest.approx(1.0)
    assert n[1, 2] == 1.0 and n[2, 1] == -1.0  # clipped
    assert n[2, 0] == 1.0  # empty = far


def test_fill_closes_holes_with_neighbour_medians():
    d = np.full((16, 16), 800.0, np.float32)
    d[:, 8:] = 900.0
    d[5:9, 2:5] = 0  # a hole inside the 800 region
    d[0, 15] = 0
    f = fill_depth(d)
    assert (f > 0).all()
    assert np.all(f[5:9, 2:5] == 800.0)
    assert f[0, 15] == 900.0
    assert np.array_equal(f[d > 0], d[d > 0])  # valid pixels untouched


def test_fill_leaves_all_empty_alone():
    assert (fill_depth(np.zeros((8, 8))) == 0).all()


def test_rgb_zero_mean_unit_variance():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    x = normalise_rgb(rgb)
    assert x.shape == (3, 64, 64)
    assert np.allclose(x.mean(axis=(1, 2)), 0, atol=1e-4)
    assert np.allclose(x.std(axis=(1, 2)), 1, atol=1e-2)
    # brightness and contrast changes do not change the input
    assert np.allclose(normalise_rgb((rgb * 0.5 + 20).astype(np.uint8)), x, atol=0.05)


def test_surface_depth_ignores_far_background():
    d = np.full((64, 64), 2000.0)
    d[20:44, 20:44] = 980.0
    assert surface_depth(d, 1000.0, 200.0) == 980.0
    assert surface_depth(np.zeros((64, 64)), 1000.0, 200.0) == 1000.0


def test_network_input_shapes_and_errors():
    rgb = np.zeros((64, 64, 3), np.uint8)
    depth = np.full((64, 64), 400.0, np.float32)
    assert network_input("rgb", rgb, None, 400, 200).shape == (3, 64, 64)
    assert network_input("depth", None, depth, 400, 200).shape == (1, 64, 64)
    assert network_input("rgbd", rgb, depth, 400, 200).shape == (4, 64, 64)
    assert batch_inputs("rgbd", rgb[None].repeat(2, 0), depth[None].repeat(2, 0), 400, 200).shape == (
        2,
        4,
        64,
        64,
    )
    with pytest.raises(ValueError, match="needs a depth"):
        network_input("rgbd", rgb, None, 400, 200)
    with pytest.raises(ValueError, match="unknown modality"):
        network_input("ir", rgb, depth, 400, 200)
    assert PatchSpec().size == 64 and PatchSpec().window_mm == 200
