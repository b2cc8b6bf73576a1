"""Symmetry transformations (`index.geometry.symmetry.symmetry_transformations`): what BOP's MSSD and MSPD
minimise over, continuous symmetries sampled by BOP's max-distance rule."""

import numpy as np
import pytest

from index.geometry.symmetry import (
    MAX_SYM_DISC_STEP,
    bop_form,
    canonical,
    continuous_steps,
    from_bop,
    symmetry_rotations,
    symmetry_transformations,
    transformations_from_bop,
    turns_over,
)


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_a_full_turn_is_sampled_so_no_point_moves_more_than_the_step():
    n = continuous_steps(0.01)
    assert n == 315
    syms = symmetry_transformations("full")
    assert len(syms) == n
    diameter = 200.0
    x = np.array([diameter / 2, 0.0, 30.0])  # a point as far from the axis as the object allows
    moved = [R @ x for R, _ in syms]
    steps = [np.linalg.norm(moved[i] - moved[(i + 1) % n]) for i in range(n)]
    assert max(steps) <= MAX_SYM_DISC_STEP * diameter
    assert max(steps) > 0.99 * MAX_SYM_DISC_STEP * diameter  # and not needlessly finer
    assert all(np.allclose(t, 0) for _, t in syms)


@pytest.mark.parametrize("symmetry, count", [("none", 1), ("180", 2)])
def test_named_symmetries_are_turns_about_z_identity_first(symmetry, count):
    syms = symmetry_transformations(symmetry)
    assert len(syms) == count
    assert np.allclose(syms[0][0], np.eye(3)) and np.allclose(syms[0][1], 0)
    if count == 2:
        assert np.allclose(syms[1][0], _rot_z(180)) and np.allclose(syms[1][1], 0)


def test_bop_discrete_matrices_keep_their_offsets():
    """BOP's eggbox: a half-turn about z with a sub-millimetre offset, given as 16 numbers or a 4x4."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = _rot_z(180), [0.23, 0.69, -0.08]
    for given in ([m.ravel().tolist()], [m]):
        syms = symmetry_transformations(given)
        assert len(syms) == 2
        assert np.allclose(syms[1][0], _rot_z(180)) and np.allclose(syms[1][1], [0.23, 0.69, -0.08])
    bare = symmetry_transformations([_rot_z(90)])  # 3x3 rotations (symmetry_rotations' form): no offset
    assert np.allclose(bare[1][0], _rot_z(90)) and np.allclose(bare[1][1], 0)


def test_every_transformation_is_a_proper_rotation():
    for symmetry in ("none", "180", "full"):
        for R, t in symmetry_transformations(symmetry):
            assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1)
            assert t.shape == (3,)


def test_bop_continuous_symmetries_turn_about_their_axis_through_its_offset():
    """A can about x through (0, 0, 10), and the top-bottom flip of a can: every transformation keeps the
    axis's points where they are, and the flip doubles the count."""
    info = {"symmetries_continuous": [{"axis": [2, 0, 0], "offset": [0, 0, 10]}]}
    syms = transformations_from_bop(info)
    assert len(syms) == continuous_steps()
    on_axis = np.array([35.0, 0.0, 10.0])
    assert all(np.allclose(R @ on_axis + t, on_axis) for R, t in syms)
    off_axis = np.array([0.0, 0.0, 30.0])  # 20 mm from the axis: turns on a circle about it
    assert all(np.linalg.norm(R @ off_axis + t - [0, 0, 10]) == pytest.approx(20) for R, t in syms)
    flip = np.eye(4)
    flip[:3, :3] = _rot_z(180)
    both = transformations_from_bop({**info, "symmetries_discrete": [flip.ravel().tolist()]})
    assert len(both) == 2 * len(syms)
    assert np.allclose(both[0][0], np.eye(3)) and np.allclose(both[0][1], 0)
    with pytest.raises(ValueError, match="one at most"):
        transformations_from_bop({"symmetries_continuous": [info["symmetries_continuous"][0]] * 2})


def test_bop_discrete_symmetries_of_lmo_map_the_eggbox_onto_itself(lmo):
    """On LM-O's eggbox (10) and glue (11), BOP's own symmetry, offset kept, costs no MSSD; `from_bop`'s
    exact half-turn about z (what the service uses) costs 1.7 mm of it."""
    from index.data.bop import BopDataset
    from index.geometry.pose_error import mssd

    ds = BopDataset(lmo)
    for o in (10, 11):
        pts = np.asarray(ds.mesh(o).vertices)
        syms = transformations_from_bop(ds.models_info[o])
        assert len(syms) == 2
        R_gt, t_gt = np.eye(3), np.array([0.0, 0.0, 800.0])
        S_R, S_t = syms[1]
        assert mssd(S_R, S_t + t_gt, R_gt, t_gt, pts, syms) == pytest.approx(0, abs=1e-9)
        # Without its offset the estimate is off by just the offset (eggbox 0.74 mm).
        assert mssd(S_R, t_gt, R_gt, t_gt, pts, syms) == pytest.approx(np.linalg.norm(S_t), abs=1e-9)
        assert np.linalg.norm(S_t) > 0.1
        coarse = symmetry_transformations(from_bop(ds.models_info[o]))
        assert 1.0 < mssd(S_R, S_t + t_gt, R_gt, t_gt, pts, coarse) < 2.0


def test_names_come_to_their_smallest_form_and_a_wrong_one_is_refused_with_the_names():
    assert canonical("180+flip@90") == "180+flip"  # with a half-turn about z, the flips repeat every 90°
    assert canonical("flip@190") == "flip@10" and canonical("flip@-30") == "flip@150"
    assert canonical("full+flip@33") == "full+flip"  # about z any axis across it is as good
    assert canonical("180+flip@28") == "180+flip@28" and canonical(" 180 ") == "180"
    for wrong in ("box", "180+", "flip@x", "", "none+flip", "full+flip@nan", "180 + flip"):
        with pytest.raises(ValueError, match="use one of none, 180, full, flip, 180[+]flip, full[+]flip"):
            canonical(wrong)


@pytest.mark.parametrize(
    "symmetry, count",
    [("none", 1), ("180", 2), ("flip@40", 2), ("180+flip@28", 4), ("full", 360), ("full+flip", 720)],
)
def test_each_named_symmetry_is_a_group_of_proper_rotations(symmetry, count):
    """Closed under composition (a turn after a turn is a turn that leaves the object alike), identity first."""
    rots = symmetry_rotations(symmetry)
    assert len(rots) == count and np.allclose(rots[0], np.eye(3))
    assert all(np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1) for R in rots)
    sample = rots if count <= 4 else rots[::37]
    stack = np.stack(rots)
    for A in sample:
        for B in sample:
            assert np.abs(stack - A @ B).reshape(len(rots), -1).max(axis=1).min() < 0.02


def test_a_flip_turns_the_object_end_over_end_about_its_centre():
    """A box's flip about x through its centre at z = 40: the centre stays, the top goes to the bottom; as
    BOP states it and back."""
    centre = np.array([0.0, 0.0, 40.0])
    syms = symmetry_transformations("180+flip", centre=centre)
    assert len(syms) == 4 and all(np.allclose(R @ centre + t, centre) for R, t in syms)
    top = np.array([10.0, 20.0, 60.0])
    assert any(np.allclose(R @ top + t, [10.0, -20.0, 20.0]) for R, t in syms)  # about x
    for name in ("180", "flip@40", "180+flip@28", "full", "full+flip", "none", "y:full+flip", "x:full"):
        info = bop_form(name, centre)
        assert from_bop(info) == name
        moved = transformations_from_bop(info)
        assert len(moved) == len(symmetry_transformations(name, centre=centre))
        assert all(np.allclose(R @ centre + t, centre) for R, t in moved)


def test_a_symmetry_about_the_meshs_x_or_y_axis_is_the_same_turned():
    """A pen lying along y: any turn about y, and end over end; named "y:", and read back from BOP's form."""
    assert canonical("z:180") == "180" and canonical("y:full+flip@40") == "y:full+flip"
    assert canonical("x:180") == "flip" and canonical("y:180") == "flip@90"  # the same turns, named about z
    assert canonical("y:180+flip") == "180+flip"
    about_y = symmetry_rotations("y:full")
    y = np.array([0.0, 1.0, 0.0])
    assert len(about_y) == 360 and all(np.allclose(R @ y, y) for R in about_y)
    assert any(np.allclose(R, np.diag([-1.0, 1.0, -1.0]), atol=1e-9) for R in about_y)  # its half-turn
    info = bop_form("y:full+flip", (0.0, 5.0, 0.0))
    assert info["symmetries_continuous"][0]["axis"] == [0.0, 1.0, 0.0] and from_bop(info) == "y:full+flip"
    tilted = {"symmetries_continuous": [{"axis": [1.0, 1.0, 0.0], "offset": [0, 0, 0]}]}
    assert len(from_bop(tilted)) == 359  # none of the mesh's axes: its turns, every degree
    assert turns_over("y:full") and turns_over("flip") and turns_over("x:180")
    assert not turns_over("180") and not turns_over("full") and not turns_over("none")
