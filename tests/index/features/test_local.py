"""Local similarity: cells of a trunk map, weighted by where the query's object is."""

import numpy as np
import pytest

from index.features.local import (
    cell_cosines,
    cell_cosines_across,
    cell_weights,
    l2,
    masked_cosine,
    masked_distance,
)


def _maps(rng, n=2, c=5, g=4):
    return rng.normal(size=(n, c, g, g)).astype(np.float32)


def test_cell_cosines_compare_each_grid_position_over_its_channels():
    rng = np.random.default_rng(0)
    q, t = _maps(rng), _maps(rng)
    cos = cell_cosines(q.reshape(2, -1), t.reshape(2, -1).astype(np.float16), 4)
    assert cos.shape == (2, 16)
    a, b = q[1, :, 2, 3], t[1, :, 2, 3].astype(np.float16).astype(np.float32)  # channels first: cell 11
    np.testing.assert_allclose(cos[1, 11], a @ b / np.linalg.norm(a) / np.linalg.norm(b), atol=1e-5)
    # a cell's scale does not matter, only its direction
    q2 = q.copy()
    q2[1, :, 2, 3] *= 7.0
    np.testing.assert_allclose(
        cell_cosines(q2.reshape(2, -1), t.reshape(2, -1), 4)[1, 11], cos[1, 11], atol=1e-3
    )


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
    t = template.reshape(1, -1)

    def distance(q: np.ndarray, weights: np.ndarray) -> float:
        return float(masked_cosine(cell_cosines(q.reshape(1, -1), t, 4), weights)[0])

    assert distance(query, w) < 1e-5
    query[0, :, 0, :] = rng.normal(size=(5, 4))  # clutter along the top row
    assert distance(query, w) < 1e-5
    assert l2(query.reshape(1, -1), t)[0] > 0.1  # the whole map sees it
    # a query whose mask found nothing weighs every cell alike
    assert distance(query, np.zeros_like(w)) > 0.0
    query[0, :, 1, 1] = -template[0, :, 1, 1]  # one object cell opposite: 1 - cos = 2, a quarter of it
    assert abs(distance(query, w) - 0.5) < 1e-5


def test_coverage_charges_the_query_mask_a_silhouette_leaves_out():
    """`uncovered`: the share of the query's mask outside the template's silhouette (an occluder cutting
    the query's mask costs nothing); `masked_distance` adds it times `coverage`, and only with a mask."""
    from index.features.local import masked_distance, uncovered

    q = np.array([[1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    sil = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(uncovered(q, sil), [0.0, 0.5, 0.0])
    cos = np.full((3, 4), 0.5)
    base = masked_distance(cos, sil, q)
    np.testing.assert_allclose(masked_distance(cos, sil, q, 0.3), base + 0.3 * np.array([0.0, 0.5, 0.0]))
    np.testing.assert_allclose(masked_distance(cos, sil, None, 0.3), masked_distance(cos, sil))


def test_cosines_across_rolls_are_the_pairwise_ones():
    """`cell_cosines_across` (every template against every query row, float16 as stored) equals
    `cell_cosines` of each pair, a zero cell included."""
    rng = np.random.default_rng(5)
    c, g = 24, 4
    queries = rng.normal(size=(3, c * g * g)).astype(np.float32)
    templates = rng.normal(size=(5, c * g * g)).astype(np.float16)
    templates[2, : g * g] = 0.0  # channel 0 zero everywhere in template 2: still a cosine of the rest
    templates[1].reshape(c, g * g)[:, 3] = 0.0  # cell 3 of template 1 all zero: cosine 0
    across = cell_cosines_across(queries, templates, g)
    assert across.shape == (5, 3, g * g)
    for r in range(3):
        pairwise = cell_cosines(queries[r : r + 1], templates, g)
        np.testing.assert_allclose(across[:, r], pairwise, atol=1e-5)
    assert np.all(across[1, :, 3] == 0.0)


def test_distances_across_rolls_are_the_pairwise_ones():
    """`masked_distance` of every template against every query row (broadcast: silhouettes (N, 1, G * G),
    query masks (1, R, G * G)) equals that of each (template, query row) pair, with the coverage term, an
    empty silhouette and an empty query mask included."""
    rng = np.random.default_rng(6)
    n, r, g2 = 4, 3, 16
    cos = rng.uniform(-1, 1, size=(n, r, g2)).astype(np.float32)
    sil = (rng.random((n, g2)) * (rng.random((n, g2)) > 0.5)).astype(np.float32)
    sil[1] = 0.0
    qm = (rng.random((r, g2)) > 0.4).astype(np.float32)
    qm[2] = 0.0
    for mask in (qm, None):
        across = masked_distance(cos, sil[:, None], None if mask is None else mask[None], coverage=0.3)
        assert across.shape == (n, r)
        for j in range(r):
            pairwise = masked_distance(
                cos[:, j], sil, None if mask is None else np.repeat(mask[j][None], n, 0), 0.3
            )
            np.testing.assert_allclose(across[:, j], pairwise, atol=1e-6)


def test_relief_is_each_cells_depth_from_the_distance_over_the_pixels_with_depth():
    """`relief`: cell means of depth - distance in windows, over pixels with depth (and inside `keep`), and
    the share of each cell's pixels that have one."""
    from index.features.local import relief

    depth = np.zeros((1, 8, 8), np.float32)
    depth[0, :4, :4] = 1010.0  # cell (0, 0) of a 2 x 2 grid: 10 mm behind the distance
    depth[0, :4, 4:] = 990.0
    depth[0, 0, 4:] = 0.0  # a row of cell (0, 1) without depth: not in its mean, out of its share
    depth[0, 4:, :4] = 1100.0  # cell (1, 0), hidden by `keep` below
    keep = np.ones((1, 8, 8), bool)
    keep[0, 4:, :4] = False
    values, shares = relief(depth, np.array([1000.0]), 2, 200.0, keep)
    np.testing.assert_allclose(values[0], [0.05, -0.05, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(shares[0], [1.0, 0.75, 0.0, 0.0])


def test_relief_distance_ignores_the_offset_and_clips_an_occluded_cell():
    """Two reliefs of one shape at different distances are 0 apart; a cell 30 mm off (an occluder) adds at
    most the clip; a shape tilted the other way is far; fewer than `RELIEF_MIN_CELLS` shared cells: 0."""
    from index.features.local import RELIEF_MIN_CELLS, relief_distance

    g2 = 16
    shape = np.linspace(-0.1, 0.1, g2, dtype=np.float32)  # a slope, in windows
    sil = np.ones(g2, np.float32)
    shares = np.ones(g2, np.float32)
    occluded = shape + 0.3
    occluded[5] -= 0.15  # one cell 30 mm nearer than the rest of the surface
    queries = np.stack([shape + 0.3, occluded, -shape])
    d = relief_distance(queries, np.stack([shares] * 3), np.stack([shape] * 3), np.stack([sil] * 3), 0.1)
    assert d[0] == pytest.approx(0.0, abs=1e-6)
    assert 0.0 < d[1] <= 0.1 / np.sqrt(g2) + 0.01  # the clipped cell's share of the rms, the mean's shift
    assert d[2] > 0.05
    few = np.zeros(g2, np.float32)
    few[: RELIEF_MIN_CELLS - 1] = 1.0
    assert relief_distance(queries[2:], few[None], shape[None], sil[None], 0.1)[0] == 0.0
    # every template against every query row (broadcast): the pairwise distances
    templates = np.stack([shape, -shape])
    across = relief_distance(
        queries[None], np.stack([shares] * 3)[None], templates[:, None], np.stack([sil, sil])[:, None], 0.1
    )
    assert across.shape == (2, 3)
    for j in range(3):
        pairwise = relief_distance(
            np.stack([queries[j]] * 2), np.stack([shares] * 2), templates, np.stack([sil, sil]), 0.1
        )
        np.testing.assert_allclose(across[:, j], pairwise, atol=1e-6)


def test_a_stored_row_splits_by_its_width():
    """`StoredLocal.of`: features alone, with silhouettes, with silhouettes and relief; any other width is
    refused."""
    from index.features.local import StoredLocal

    f, g = 6, 2
    row = np.arange(f + 2 * g * g, dtype=np.float32)[None]
    full = StoredLocal.of(row, f, g)
    assert full.features.shape == (1, f) and full.silhouettes is not None and full.relief is not None
    assert full.silhouettes[0, 0] == f and full.relief[0, 0] == f + g * g
    older = StoredLocal.of(row[:, : f + g * g], f, g)
    assert older.silhouettes is not None and older.relief is None
    oldest = StoredLocal.of(row[:, :f], f, g)
    assert (oldest.silhouettes, oldest.relief) == (None, None)
    with pytest.raises(ValueError, match="fit neither"):
        StoredLocal.of(row[:, : f + 1], f, g)


def test_leading_float32_converts_the_first_values_of_each_row_exactly():
    """`leading_float32` (onnxruntime's Cast, written into the given array): the first `width` values of
    float16 rows as float32, exactly as numpy converts them; an empty batch is no call."""
    from index.features.local import leading_float32

    rows = np.random.default_rng(3).normal(size=(7, 40)).astype(np.float16)
    out = np.full((9, 30), np.nan, np.float32)
    got = leading_float32(rows, 30, out[1:8])
    np.testing.assert_array_equal(out[1:8], rows[:, :30].astype(np.float32))
    assert np.shares_memory(got, out) and np.isnan(out[0]).all() and np.isnan(out[8]).all()
    np.testing.assert_array_equal(leading_float32(rows, 40), rows.astype(np.float32))
    assert leading_float32(rows[:0], 30).shape == (0, 30)
