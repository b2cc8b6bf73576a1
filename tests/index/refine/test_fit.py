"""The fits' shared algebra (`index.refine.fit`): its cross product is numpy's, to the bit, for every shape the
fits give it (so a fit's every step, and the answers, are those `np.cross` gave)."""

from __future__ import annotations

import numpy as np
import pytest

from index.refine.fit import cross


@pytest.mark.parametrize(
    ("a", "b"),
    [
        ((800, 3), (800, 3)),
        ((3,), (3,)),
        ((5, 3), (3,)),
        ((3,), (4, 3)),
        ((2, 7, 3), (2, 7, 3)),
        ((0, 3), (0, 3)),
    ],
)
def test_the_cross_product_is_numpys_to_the_bit(a, b):
    rng = np.random.default_rng(sum(a) + sum(b))
    x, y = rng.normal(size=a) * 1e3, rng.normal(size=b)
    ours, numpys = cross(x, y), np.cross(x, y)
    assert ours.shape == numpys.shape and ours.dtype == numpys.dtype
    assert np.array_equal(ours.view(np.uint64), numpys.view(np.uint64))


def test_the_cross_product_of_float32_vectors_stays_float32():
    x = np.array([[1.0, 0.0, 0.0]], np.float32)
    y = np.array([[0.0, 1.0, 0.0]], np.float32)
    assert cross(x, y).dtype == np.float32
    assert cross(x, y).tolist() == [[0.0, 0.0, 1.0]]
