"""Batch invariants: every index inside its batch, the paper's triplets, >= 2 templates per object."""

import numpy as np
import pytest

from index.templates.viewpoints import sphere_views
from training.batches import BatchBuilder, bootstrap_triplets
from training.similarity import pose_distances, rotations

TEMPLATE_R = rotations(sphere_views(3))
SYMMETRIES = ["none", "180", "full", "none"]


@pytest.fixture
def batch():
    rng = np.random.default_rng(0)
    n = 12
    objs = rng.integers(0, len(SYMMETRIES), n)
    views = sphere_views(4)
    R = rotations([views[i] for i in rng.integers(0, len(views), n)])
    return BatchBuilder(TEMPLATE_R, SYMMETRIES).make(range(n), objs, R, rng), objs, R


def test_indices_inside_the_batch(batch):
    b, _, _ = batch
    assert b.triplets.min() >= 0 and b.triplets.max() < len(b.items)
    assert b.pairs.min() >= 0 and b.pairs.max() < len(b.items)
    assert len(set(b.items)) == len(b.items)


def test_three_triplets_and_a_pair_per_sample(batch):
    b, objs, R = batch
    assert len(b.triplets) == 3 * len(objs) and len(b.pairs) == len(objs)
    for s, obj, r in zip(b.sample_rows, objs, R, strict=True):
        assert b.items[s][:2] == ("sample", obj)
        mine = b.triplets[b.triplets[:, 0] == s]
        assert len(mine) == 3
        pos = b.items[mine[0, 1]]
        d = pose_distances(r[None], TEMPLATE_R, SYMMETRIES[obj])[0]
        assert pos[:2] == ("template", obj) and d[pos[2]] == pytest.approx(d.min())
        for _, p, n in mine:
            assert p == mine[0, 1]
            neg = b.items[n]
            assert neg[0] == "template"
            if neg[1] == obj:  # a same-object negative has a less similar pose
                assert d[neg[2]] > d[pos[2]]
        assert any(b.items[n][1] != obj for n in mine[:, 2])  # one negative of another object


def test_at_least_two_templates_per_object(batch):
    b, _, _ = batch
    objs = {it[1] for it in b.items if it[0] == "template"}
    for o in objs:
        assert sum(1 for it in b.items if it[0] == "template" and it[1] == o) >= 2


def test_single_object_batch_still_has_another_object():
    rng = np.random.default_rng(1)
    b = BatchBuilder(TEMPLATE_R, SYMMETRIES).make([0], [2], TEMPLATE_R[5:6], rng)
    objs = [it[1] for it in b.items if it[0] == "template"]
    assert len(set(objs)) == 2 and all(objs.count(o) >= 2 for o in set(objs))


def test_bootstrapping_picks_the_hardest_in_batch(batch):
    b, objs, R = batch
    rng = np.random.default_rng(2)
    f = rng.normal(size=(len(b.items), 4))
    extra = bootstrap_triplets(b, f)
    assert extra.max() < len(b.items) and len(extra) >= len(objs)
    for s, p, n in extra:
        assert b.items[s][0] == "sample" and b.items[n][0] == "template"
        dist = np.linalg.norm(f - f[s], axis=1)
        if b.items[n][1] == b.items[s][1]:
            wrong = [r for r, a in b.pose_dist[s].items() if a > b.pose_dist[s][p] + 1e-6]
            assert n in wrong and dist[n] == pytest.approx(dist[wrong].min())
        else:
            others = [r for r, it in enumerate(b.items) if it[0] == "template" and it[1] != b.items[s][1]]
            assert dist[n] == pytest.approx(dist[others].min())
