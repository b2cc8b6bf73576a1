"""Local similarity: cells of a trunk map, weighted by where the query's object is."""

import numpy as np

from index.local import cell_weights, cells, l2, masked_cosine


def _maps(rng, n=2, c=5, g=4):
    return rng.normal(size=(n, c, g, g)).astype(np.float32)


def test_cells_are_unit_vectors_of_each_grid_position():
    rng = np.random.default_rng(0)
    m = _maps(rng)
    out = cells(m.reshape(2, -1), 4)
    assert out.shape == (2, 16, 5)
    np.testing.assert_allclose(np.linalg.norm(out, axis=2), 1.0, atol=1e-5)
    v = m[1, :, 2, 3]  # channels first, row-major grid: cell 2 * 4 + 3
    np.testing.assert_allclose(out[1, 11], v / np.linalg.norm(v), atol=1e-5)


def test_cell_weights_are_the_share_of_each_cell_the_mask_covers():
    mask = np.zeros((1, 8, 8), bool)
    mask[0, :, :4] = True  # the left half
    mask[0, 0, 4] = True  # one pixel of the cell (0, 2)
    w = cell_weights(mask, 4).reshape(4, 4)
    np.testing.assert_allclose(w[:, :2], 1.0)
    assert w[0, 2] == 0.25 and w[1:, 2:].sum() == 0 and w[0, 3] == 0


def test_clutter_outside_the_mask_does_not_count_but_inside_it_does():
    rng = np.random.default_rng(1)
    template = _maps(rng, n=1)
    query = template.copy()
    mask = np.zeros((1, 4, 4), bool)
    mask[0, 1:3, 1:3] = True  # the object: the four centre cells
    w = cell_weights(mask, 4)
    t = cells(template.reshape(1, -1), 4)
    assert masked_cosine(cells(query.reshape(1, -1), 4), t, w)[0] < 1e-5
    query[0, :, 0, :] = rng.normal(size=(5, 4))  # clutter along the top row
    cluttered = cells(query.reshape(1, -1), 4)
    assert masked_cosine(cluttered, t, w)[0] < 1e-5
    assert l2(query.reshape(1, -1), template.reshape(1, -1))[0] > 0.1  # the whole map sees it
    query[0, :, 1, 1] = -template[0, :, 1, 1]  # one object cell opposite: 1 - cos = 2, a quarter of it
    assert abs(masked_cosine(cells(query.reshape(1, -1), 4), t, w)[0] - 0.5) < 1e-5
    # a query whose mask found nothing weighs every cell alike
    assert masked_cosine(cluttered, t, np.zeros_like(w))[0] > 0.0
