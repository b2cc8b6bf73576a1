"""Distinct answers on hand-made candidates."""

import numpy as np

from index.store.answers import distinct


def test_one_answer_per_key_at_its_best_best_first():
    obj = np.array([1, 1, 1, 2, 2, 1])
    az = np.array([0.0, 0.0, 10.0, 0.0, 0.0, 10.0])
    scores = np.array([0.5, 0.2, 0.9, 0.3, 0.1, 0.4])
    assert distinct((obj, az), scores, 5).tolist() == [4, 1, 5]
    assert distinct((obj, az), scores, 2).tolist() == [4, 1]
    assert distinct((obj,), scores, 5).tolist() == [4, 1]
    assert distinct((obj[:0],), scores[:0], 5).tolist() == []
