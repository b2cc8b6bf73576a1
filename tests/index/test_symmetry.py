"""Symmetry transformations (`index.symmetry.symmetry_transformations`): what BOP's MSSD and MSPD
minimise over, continuous symmetries sampled by BOP's max-distance rule."""

import numpy as np
import pytest

from index.symmetry import MAX_SYM_DISC_STEP, continuous_steps, symmetry_transformations


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
