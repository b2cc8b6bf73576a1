"""`service.detection.mask`: a detection's mask as COCO writes it (compressed RLE), read back by a decoder
written from pycocotools' `rleFrString` (the spec; tests/helpers/coco_rle.py), on masks of every edge case."""

from __future__ import annotations

import numpy as np
import pytest
from coco_rle import decode

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
