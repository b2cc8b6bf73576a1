"""`index.features.patches`, what the network sees: depth normalised to known values and its holes filled,
colour standardised, the batch path equal to the per-patch reference, and patches cut at any roll."""

import cv2
import numpy as np
import pytest

from index.features.patches import (
    MODALITY_CHANNELS,
    PatchSpec,
    batch_inputs,
    crop,
    crops,
    fill_depth,
    network_input,
    normalise_depth,
    normalise_rgb,
    patch_camera,
    surface_depth,
    turn_masks,
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


def test_fill_of_what_is_needed_is_the_whole_fill_there():
    # a fill told which pixels a mask keeps stops early, and they hold what the whole fill gives them
    rng = np.random.default_rng(0)
    d = rng.uniform(700.0, 900.0, (6, 32, 32)).astype(np.float32)
    d[rng.random(d.shape) < 0.3] = 0  # scattered holes
    d[:, 10:30, 12:30] = 0  # a large one, many rounds to close
    d[4] = 0  # nothing to fill from
    needed = np.zeros(d.shape, bool)
    needed[:, 8:16, 8:16] = True  # the large hole's edge and what is left around it
    needed[5] = False  # a patch that needs nothing
    whole, some = fill_depth(d), fill_depth(d, needed=needed)
    assert np.array_equal(some[needed], whole[needed])
    measured = needed.copy()
    measured[4] = False  # the patch without depth stays empty
    assert (some[measured] > 0).all() and (some[4] == 0).all()
    assert (some[1:4][~needed[1:4] & (whole[1:4] != d[1:4])] == 0).any()  # it stopped before the rest
    assert np.array_equal(some[5], d[5])  # nothing needed: left as it was


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


def test_rgb_normalised_to_the_bit_as_numpy_std_gives():
    """The registration's faster standard deviation is numpy's own, to the last bit (a flat patch too)."""
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (7, 64, 64, 3), dtype=np.uint8)
    rgb[0] = 0
    x = np.moveaxis(rgb, -1, -3).astype(np.float32, order="C")
    want = (x - x.mean(axis=(-2, -1), keepdims=True)) / (x.std(axis=(-2, -1), keepdims=True) + 1e-3 * 255)
    assert np.array_equal(normalise_rgb(rgb), want)


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


def _reference_fill(depth: np.ndarray) -> np.ndarray:
    """The documented fill, pixel by pixel: each round, every hole with a valid 3x3 neighbour takes
    their median, until no hole is left (an all-empty patch stays empty)."""
    d = depth.astype(np.float64)
    if (d <= 0).all():
        return d
    while (d <= 0).any():
        new = d.copy()
        for y, x in zip(*np.nonzero(d <= 0), strict=True):
            around = d[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2]
            if (around > 0).any():
                new[y, x] = np.median(around[around > 0])
        d = new
    return d


def _reference_input(modality, rgb, depth, nominal, window, fill):
    """The documented formulas, one patch at a time, in float64."""
    channels = []
    if modality in ("rgb", "rgbd"):
        x = rgb.astype(np.float64)
        channels += [(x[..., c] - x[..., c].mean()) / (x[..., c].std() + 0.255) for c in range(3)]
    if modality in ("depth", "rgbd"):
        d = _reference_fill(depth) if fill else depth.astype(np.float64)
        s = d.shape[0]
        q = d[3 * s // 8 : 5 * s // 8, 3 * s // 8 : 5 * s // 8]
        near = q[(q > 0) & (np.abs(q - nominal) < window / 2)]
        centre = np.median(near) if near.size else nominal
        n = np.clip((d - centre) / (window / 2), -1, 1)
        n[d <= 0] = 1
        channels.append(n)
    return np.stack(channels)


def _awkward_patches(s: int = 32):
    """Patches that take every branch: holes, a large hole, no depth at all, a central quarter with no
    valid depth near the nominal distance (far, or empty), a flat colour; whole-mm depths so that float32
    and float64 fills agree exactly."""
    rng = np.random.default_rng(3)
    nominal = np.array([400.0, 400.0, 600.0, 400.0, 500.0, 500.0, 400.0, 450.0])
    n, c = len(nominal), slice(3 * s // 8, 5 * s // 8)
    depth = (nominal[:, None, None] + rng.integers(-150, 150, (n, s, s))).astype(np.float32)
    rgb = rng.integers(0, 256, (n, s, s, 3), dtype=np.uint8)
    depth[1][rng.random((s, s)) < 0.3] = 0  # sensor holes
    depth[2, 4:20, 6:26] = 0  # one large hole: several fill rounds
    depth[2][rng.random((s, s)) < 0.1] = 0
    depth[3] = 0  # no depth at all
    depth[4, c, c] = 900.0  # central quarter valid but far from the nominal 500 mm
    depth[4][rng.random((s, s)) < 0.2] = 0
    depth[5, c, c] = 0  # central quarter empty: filled from around it, or nominal without fill
    depth[6, :, : s // 2] = 0  # half empty, as a render's background
    rgb[6] = (10, 200, 30)  # one flat colour: zero variance
    return rgb, depth, nominal


@pytest.mark.parametrize("fill", [False, True])
@pytest.mark.parametrize("modality", ["rgb", "depth", "rgbd"])
def test_batch_matches_per_patch_reference(modality, fill):
    rgb, depth, nominal = _awkward_patches()
    x = batch_inputs(modality, rgb, depth, nominal, 200.0, fill)
    ref = np.stack(
        [
            _reference_input(modality, r, d, m, 200.0, fill)
            for r, d, m in zip(rgb, depth, nominal, strict=True)
        ]
    )
    assert x.dtype == np.float32 and x.shape == ref.shape == (8, MODALITY_CHANNELS[modality], 32, 32)
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-5)
    # one patch at a time is the same code with N = 1
    for i in range(len(nominal)):
        one = network_input(modality, rgb[i], depth[i], float(nominal[i]), 200.0, fill)
        assert np.array_equal(one, x[i])


def test_reference_sees_what_the_awkward_patches_are_for():
    # guards the parity test: its patches really take the branches they are named for
    _, depth, nominal = _awkward_patches()
    assert (fill_depth(depth)[[0, 1, 2, 4, 5, 6]] > 0).all() and (fill_depth(depth)[3] == 0).all()
    centre = surface_depth(depth, nominal, 200.0)
    assert centre[3] == 400.0 and centre[4] == 500.0 and centre[5] == 500.0  # fallback to nominal
    assert surface_depth(fill_depth(depth), nominal, 200.0)[5] != 500.0  # filled centre has depth
    assert centre.shape == (8,) and fill_depth(depth[1]).shape == (32, 32)


def test_batch_input_shapes_are_checked():
    rgb, depth, _ = _awkward_patches()
    assert batch_inputs("rgbd", rgb[:0], depth[:0], 400.0, 200.0).shape == (0, 4, 32, 32)
    with pytest.raises(ValueError, match=r"\(N, S, S, 3\)"):
        batch_inputs("rgb", rgb[0], None, 400.0, 200.0)
    with pytest.raises(ValueError, match="differ"):
        batch_inputs("rgbd", rgb[:3], depth[:2], 400.0, 200.0)
    with pytest.raises(ValueError, match=r"one depth patch must be \(S, S\)"):
        network_input("depth", None, depth, 400.0, 200.0)


@pytest.mark.parametrize(("a", "b"), [(0.0, 30.0), (0.0, -70.0), (20.0, 110.0), (-150.0, 170.0)])
def test_turned_masks_are_those_of_the_patch_cut_at_the_other_in_plane(a, b):
    """`turn_masks` of a patch cut at in-plane a is the mask of the patch cut at b, for any frame camera
    (here an off-centre object seen by a Kinect-like camera), up to resampling at the edges."""
    frame = np.zeros((480, 640, 3), np.uint8)
    cv2.rectangle(frame, (300, 200), (360, 230), (255, 255, 255), -1)  # an L of a box and a disc
    cv2.circle(frame, (350, 260), 15, (255, 255, 255), -1)
    K = np.array([[572.0, 0.0, 325.0], [0.0, 573.0, 242.0], [0.0, 0.0, 1.0]])
    spec = PatchSpec()
    pa, _ = crop(frame, None, K, (330, 235), 700.0, spec, inplane=a)
    pb, _ = crop(frame, None, K, (330, 235), 700.0, spec, inplane=b)
    ma, mb = pa[None, ..., 0] > 127, pb[..., 0] > 127

    def iou(x: np.ndarray, y: np.ndarray) -> float:
        return float((x & y).sum() / max((x | y).sum(), 1))

    assert iou(turn_masks(ma, b - a, spec)[0], mb) > 0.9
    assert iou(turn_masks(ma, a - b, spec)[0], mb) < 0.6  # the other way round is another mask
    assert turn_masks(np.zeros((0, 64, 64), bool), 10.0, spec).shape == (0, 64, 64)


def test_crops_at_many_rolls_are_each_rolls_own_cut():
    """`crops` (the geometry once, the rolls as a batch) cuts at each roll what the homography of that
    roll alone gives: frame pixel = K align(ray) roll(θ) Kv⁻¹ patch pixel; depth along the virtual axis."""
    from index.geometry.pose import align_rotation, roll_rotation

    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    depth = rng.uniform(600.0, 800.0, (480, 640)).astype(np.float32)
    K = np.array([[572.0, 0.0, 325.0], [0.0, 573.0, 242.0], [0.0, 0.0, 1.0]])
    spec, centre, dist = PatchSpec(), (402.5, 150.0), 700.0
    rolls = [0.0, 30.0, -95.0, 170.0]
    rgbs, depths = crops(frame, depth, K, centre, dist, spec, rolls)
    assert rgbs is not None and depths is not None and rgbs.shape == (4, 64, 64, 3)
    ray = np.linalg.inv(K) @ np.array([*centre, 1.0])
    for i, r in enumerate(rolls):
        rot = align_rotation(ray) @ roll_rotation(r)
        H = K @ rot @ np.linalg.inv(patch_camera(spec, dist))
        flags = cv2.WARP_INVERSE_MAP
        want = cv2.warpPerspective(
            frame, H / H[2, 2], (64, 64), flags=cv2.INTER_LINEAR | flags, borderMode=cv2.BORDER_REPLICATE
        )
        assert np.abs(rgbs[i].astype(int) - want).max() <= 1
        np.testing.assert_array_equal(crop(frame, depth, K, centre, dist, spec, r)[0], rgbs[i])
        d = cv2.warpPerspective(depth, H / H[2, 2], (64, 64), flags=cv2.INTER_NEAREST | flags)
        u, v = np.meshgrid(np.arange(64.0), np.arange(64.0))
        rz = (
            rot @ np.linalg.inv(patch_camera(spec, dist)) @ np.stack([u.ravel(), v.ravel(), np.ones(64 * 64)])
        )[2]
        np.testing.assert_allclose(depths[i], d / rz.reshape(64, 64), rtol=1e-5)
