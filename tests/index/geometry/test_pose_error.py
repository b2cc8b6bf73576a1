"""The one pose error (`index.geometry.pose_error`): vectorised, symmetry-aware, and "within" strictly below; BOP's
model-based errors on hand-made objects whose answers are known."""

import numpy as np
import pytest

from index.geometry.pose import View, camera_centre, view_to_pose
from index.geometry.pose_error import (
    add,
    add_s_correct,
    adi,
    mspd,
    mssd,
    re,
    rotation_error,
    rotation_errors,
    te,
    view_error,
    view_errors,
    within,
    within_deg_cm,
)
from index.geometry.symmetry import continuous_steps, symmetry_transformations

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])  # LM-O's camera


def R(az: float, el: float, ip: float = 0.0, ray=None) -> np.ndarray:
    return view_to_pose(View(az, el, ip), ray)[0]


def test_rotation_errors_are_every_pair_of_the_one_pair_function():
    rng = np.random.default_rng(1)
    est = np.stack([R(*rng.uniform([0, 0, -180], [360, 90, 180])) for _ in range(5)])
    gt = np.stack([R(*rng.uniform([0, 0, -180], [360, 90, 180])) for _ in range(3)])
    for symmetry in ("none", "180", "full", "180+flip@20", "full+flip", "y:full", "x:180+flip"):
        errors = rotation_errors(est, gt, symmetry)
        assert errors.shape == (5, 3)
        for i in range(5):
            for j in range(3):
                assert errors[i, j] == pytest.approx(rotation_error(est[i], gt[j], symmetry), abs=1e-9)


def test_rotation_error_counts_in_plane_and_forgives_symmetries():
    assert rotation_error(R(10, 30, 25), R(10, 30, -5)) == pytest.approx(30, abs=1e-6)
    assert rotation_error(R(190, 30), R(10, 30), "180") == pytest.approx(0, abs=1e-6)
    assert rotation_error(R(190, 30), R(10, 30)) > 100
    assert rotation_error(R(130, 30), R(10, 30), "full") == pytest.approx(0, abs=1e-5)
    assert rotation_error(R(130, 30, 20), R(10, 30), "full") > 5  # a roll still tilts the z axis


def test_a_flip_is_forgiven_only_where_the_object_has_one():
    """A pose turned end over end (a half-turn about the object's x axis, or about the axis 30° from it)
    counts 0 for a box or a can with both ends alike, and about 180° for an object whose ends differ."""
    gt = R(10, 30, 15)
    about_x = gt @ np.diag([1.0, -1.0, -1.0])
    a = np.array([np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0])
    about_30 = gt @ (2 * np.outer(a, a) - np.eye(3))
    assert rotation_error(about_x, gt, "180+flip") == pytest.approx(0, abs=1e-5)
    assert rotation_error(about_x, gt, "flip") == pytest.approx(0, abs=1e-5)
    assert rotation_error(about_30, gt, "180+flip@30") == pytest.approx(0, abs=1e-5)
    assert rotation_error(about_30, gt, "180+flip") == pytest.approx(60, abs=1e-4)
    assert rotation_error(about_x, gt, "180") == pytest.approx(180, abs=1e-4)
    assert rotation_error(about_x @ _turn_z(77), gt, "full+flip") == pytest.approx(0, abs=1e-5)
    assert rotation_error(about_x, gt, "full") == pytest.approx(180, abs=1e-4)
    # the viewing direction: seen from 30° below a can with both ends alike is seen from 30° above
    assert view_error(10, -30, 100, 30, "full+flip") == pytest.approx(0, abs=1e-5)
    assert view_error(10, -30, 100, 40, "full+flip") == pytest.approx(10, abs=1e-5)
    assert view_error(10, -30, 100, 30, "full") == pytest.approx(60, abs=1e-5)
    # about the mesh's y axis: a turn about y costs nothing, a tilt of y what it tilts
    about_y = np.array([[np.cos(1.0), 0.0, np.sin(1.0)], [0.0, 1.0, 0.0], [-np.sin(1.0), 0.0, np.cos(1.0)]])
    assert rotation_error(gt @ about_y, gt, "y:full") == pytest.approx(0, abs=1e-5)
    assert rotation_error(gt @ about_y, gt, "full") > 50
    assert rotation_error(gt @ _turn_z(25), gt, "y:full") == pytest.approx(25, abs=1e-5)


def _turn_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_view_errors_ignore_in_plane_on_any_ray():
    """Both poses on one off-axis ray (the service's answer along the ray through (u, v)): the error is
    the angle between the two camera centres, whatever the rolls."""
    ray = np.array([0.3, -0.2, 1.0])
    est = np.stack([R(40, 20, 70, ray), R(40, 50, -30, ray)])
    gt = R(40, 20, 0, ray)[None]
    errors = view_errors(est, gt, "none", ray)[:, 0]
    assert errors[0] == pytest.approx(0, abs=1e-5)
    expected = np.degrees(np.arccos(camera_centre(40, 50) @ camera_centre(40, 20)))
    assert errors[1] == pytest.approx(expected, abs=1e-5) and errors[1] == pytest.approx(30, abs=1e-5)
    assert view_error(40, 50, 40, 20) == pytest.approx(30, abs=1e-5)
    assert view_error(100, 50, 280, 50, "180") == pytest.approx(0, abs=1e-5)
    assert view_error(100, 50, 17, 20, "full") == pytest.approx(30, abs=1e-5)  # elevation only


def test_within_is_strictly_below():
    assert within(np.array([19.999, 20.0, 20.001]), 20).tolist() == [True, False, False]


def test_equal_poses_are_zero_not_nan():
    """A rotation's trace may come out a hair above 3 (cosine above 1): clipped before arccos."""
    rng = np.random.default_rng(2)
    for _ in range(50):
        r = R(*rng.uniform([0, 0, -180], [360, 90, 180]))
        for symmetry in ("none", "180", "full"):
            assert rotation_error(r, r, symmetry) == pytest.approx(0, abs=1e-5)
            assert view_errors(r, r, symmetry)[0, 0] == pytest.approx(0, abs=1e-5)


def rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def box_points(extents=(100.0, 60.0, 40.0), n: int = 5, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A grid of n^3 points filling a box: symmetric under half-turns about its three axes."""
    axes = [np.linspace(-e / 2, e / 2, n) for e in extents]
    return np.stack(np.meshgrid(*axes), -1).reshape(-1, 3) + np.asarray(centre)


def cylinder_points(radius: float = 30.0, height: float = 80.0) -> np.ndarray:
    """Rings of points on a cylinder about z, as many per ring as "full" has samples, so that the point
    set itself is unchanged by each sampled turn."""
    n = continuous_steps()
    a = np.radians(np.arange(n) * 360.0 / n)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n)], 1)
    return np.concatenate([ring + [0, 0, z] for z in np.linspace(-height / 2, height / 2, 5)])


POSE = (R(30, 40, 15), np.array([20.0, -10.0, 600.0]))


def test_identical_poses_have_zero_error_everywhere():
    Rg, tg = POSE
    for pts, symmetry in ((box_points(), "none"), (box_points(), "180"), (cylinder_points(), "full")):
        syms = symmetry_transformations(symmetry)
        assert mssd(Rg, tg, Rg, tg, pts, syms) == pytest.approx(0, abs=1e-9)
        assert mspd(Rg, tg, Rg, tg, K, pts, syms) == pytest.approx(0, abs=1e-9)
        assert add(Rg, tg, Rg, tg, pts) == pytest.approx(0, abs=1e-9)
        assert adi(Rg, tg, Rg, tg, pts) == pytest.approx(0, abs=1e-9)
    assert te(tg, tg) == 0 and re(Rg, Rg) == pytest.approx(0, abs=1e-5)
    assert within_deg_cm(Rg, tg, Rg, tg)


def test_a_10_mm_shift_is_10_mm_of_mssd_and_add_and_f_10_over_z_px_of_mspd():
    Rg, tg = POSE
    shift = np.array([10.0, 0.0, 0.0])
    pts = box_points()
    assert mssd(Rg, tg + shift, Rg, tg, pts) == pytest.approx(10, abs=1e-9)
    assert add(Rg, tg + shift, Rg, tg, pts) == pytest.approx(10, abs=1e-9)
    assert te(tg + shift, tg) == pytest.approx(10) and re(Rg, Rg) == pytest.approx(0, abs=1e-5)
    # A sideways shift moves a point at depth z by fx * 10 / z px: the nearest point moves most.
    z_min = (pts @ Rg.T + tg)[:, 2].min()
    assert mspd(Rg, tg + shift, Rg, tg, K, pts) == pytest.approx(K[0, 0] * 10 / z_min, abs=1e-9)
    centre = np.zeros((1, 3))  # one point on the optical axis at 500 mm
    t0 = np.array([0.0, 0.0, 500.0])
    assert mspd(np.eye(3), t0 + shift, np.eye(3), t0, K, centre) == pytest.approx(572.4 * 10 / 500, abs=1e-9)


def test_a_cylinder_turned_about_its_axis_is_not_wrong():
    Rg, tg = POSE
    pts, syms = cylinder_points(), symmetry_transformations("full")
    step = 360.0 / continuous_steps()
    Re = Rg @ rot_z(40 * step)  # one of the sampled turns: exactly a symmetric pose
    assert mssd(Re, tg, Rg, tg, pts, syms) == pytest.approx(0, abs=1e-9)
    assert mspd(Re, tg, Rg, tg, K, pts, syms) == pytest.approx(0, abs=1e-9)
    assert adi(Re, tg, Rg, tg, pts) == pytest.approx(0, abs=1e-9)
    assert add(Re, tg, Rg, tg, pts) > 20
    # Without its symmetry it is wrong: the rim's chord of the turn.
    assert mssd(Re, tg, Rg, tg, pts) == pytest.approx(2 * 30 * np.sin(np.radians(20 * step)), abs=1e-9)
    # Any other turn is at most half a sample away: MSSD within BOP's 1% of the diameter.
    diameter = np.hypot(60.0, 80.0)
    assert 0 < mssd(Rg @ rot_z(37.0), tg, Rg, tg, pts, syms) <= 0.01 * diameter
    assert within_deg_cm(Rg @ rot_z(37.0), tg, Rg, tg, syms)
    assert not within_deg_cm(Rg @ rot_z(37.0), tg, Rg, tg)


def test_a_box_at_its_half_turn_is_not_wrong_but_an_unlisted_symmetry_is():
    Rg, tg = POSE
    pts, syms = box_points(), symmetry_transformations("180")
    Re = Rg @ rot_z(180)
    assert mssd(Re, tg, Rg, tg, pts, syms) == pytest.approx(0, abs=1e-9)
    assert mspd(Re, tg, Rg, tg, K, pts, syms) == pytest.approx(0, abs=1e-9)
    assert adi(Re, tg, Rg, tg, pts) == pytest.approx(0, abs=1e-9)
    assert add(Re, tg, Rg, tg, pts) > 30
    # The box's half-turn about x is a symmetry of its points (ADD-S forgives it) but not listed.
    Rx = Rg @ rot_x(180)
    assert adi(Rx, tg, Rg, tg, pts) == pytest.approx(0, abs=1e-9)
    assert mssd(Rx, tg, Rg, tg, pts, syms) > 30


def test_a_symmetry_with_an_offset_moves_the_translation_too():
    """A box centred at (5, 0, 0) is its own image under x -> Rz(180) x + (10, 0, 0)."""
    Rg, tg = POSE
    pts = box_points(centre=(5.0, 0.0, 0.0))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot_z(180), [10.0, 0.0, 0.0]
    syms = symmetry_transformations([m])
    Re, t_e = Rg @ rot_z(180), Rg @ [10.0, 0.0, 0.0] + tg
    assert mssd(Re, t_e, Rg, tg, pts, syms) == pytest.approx(0, abs=1e-9)
    assert mssd(Re, tg, Rg, tg, pts, syms) == pytest.approx(10, abs=1e-9)  # the offset left out: 10 mm
    assert within_deg_cm(Re, t_e, Rg, tg, syms, max_mm=1.0)
    assert not within_deg_cm(Re, tg, Rg, tg, syms, max_mm=1.0)


def test_five_degrees_five_cm_is_both_strictly():
    Rg, tg = POSE
    x = np.array([1.0, 0.0, 0.0])
    assert within_deg_cm(Rg @ rot_x(4.9), tg + 49.9 * x, Rg, tg)
    assert not within_deg_cm(Rg @ rot_x(5.1), tg, Rg, tg)
    assert not within_deg_cm(Rg, tg + 50.0 * x, Rg, tg)
    assert re(Rg @ rot_x(4.9), Rg) == pytest.approx(4.9, abs=1e-6)


def test_add_s_within_a_tenth_of_the_diameter_and_missing_is_wrong():
    errors = np.array([9.99, 10.0, np.nan, 0.0])
    assert add_s_correct(errors, np.full(4, 100.0)).tolist() == [True, False, False, True]
