"""`service.detection.mask`: a detection's mask as COCO writes it (compressed RLE), read back by a decoder
written from pycocotools' `rleFrString` (the spec; tests/helpers/coco_rle.py), on masks of every edge case."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from coco_rle import decode

from index.draw import MASK_FACES, DrawMesh, silhouette
from index.geometry.pose import View, view_to_pose
from service.detection.mask import rle


@pytest.mark.parametrize("seed", range(5))
def test_a_mask_reads_back_as_it_was(seed):
    rng = np.random.default_rng(seed)
    mask = np.zeros((48, 64), bool)
    for _ in range(4):  # a few blobs, some touching the border
        y, x = rng.integers(0, 48), rng.integers(0, 64)
        mask[max(0, y - 9) : y + 9, max(0, x - 12) : x + 12] = True
    mask ^= rng.random(mask.shape) < 0.02  # and speckle: long and short runs
    out = rle(mask)
    assert out["size"] == [48, 64] and isinstance(out["counts"], str)
    np.testing.assert_array_equal(decode(out), mask)


def test_the_edge_cases():
    for mask in (np.zeros((5, 7), bool), np.ones((5, 7), bool), np.eye(6, dtype=bool)):
        np.testing.assert_array_equal(decode(rle(mask)), mask)
    first = np.zeros((4, 4), bool)
    first[0, 0] = True  # the first run, of background, is empty
    assert decode(rle(first))[0, 0]
    # by hand from pycocotools' rules: a 3 x 2 frame, its second column set: runs [3, 3] (column-major, first
    # of background), each under 16, one character each, 48 + 3
    m = np.array([[False, True], [False, True], [False, True]])
    assert rle(m)["counts"] == "33"


@pytest.mark.parametrize("seed", range(3))
def test_the_coarse_mesh_draws_the_silhouette_of_the_whole(seed):
    """A mask is the silhouette of the mesh cut to `MASK_FACES` faces: on a generated shape of many faces
    the two silhouettes agree to 0.98 IoU at any pose; a mesh with fewer faces is its own coarse mesh."""
    rng = np.random.default_rng(seed)
    shape = trimesh.creation.icosphere(subdivisions=5, radius=60.0)  # 20,480 faces
    shape.vertices *= 1.0 + 0.25 * np.sin(shape.vertices[:, :1] / 15.0)  # bumps: not a sphere any more
    full = DrawMesh.of(shape)
    coarse = full.coarse(MASK_FACES)
    assert len(coarse.faces) <= MASK_FACES < len(full.faces) and full.coarse(10**6) is full
    K = np.array([[570.0, 0, 320.0], [0, 570.0, 240.0], [0, 0, 1]])
    view = View(float(rng.uniform(0, 360)), float(rng.uniform(-80, 80)), float(rng.uniform(-180, 180)), 600.0)
    R, t = view_to_pose(view, np.array([*rng.uniform(-0.2, 0.2, 2), 1.0]))
    a, b = (silhouette(m, R, t, K, (480, 640)) > 0 for m in (full, coarse))
    assert a.sum() > 2000 and (a & b).sum() / (a | b).sum() > 0.98
