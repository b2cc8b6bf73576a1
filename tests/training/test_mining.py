"""Mining hard templates from the whole bank: the right ones are chosen and join the batch as candidates."""

import numpy as np
import torch

from index.templates.viewpoints import sphere_views
from training.batches import BatchBuilder, bootstrap_triplets, with_templates
from training.mining import TemplateBank, mine
from training.similarity import rotations

TEMPLATE_R = rotations(sphere_views(3))


def bank_of(f: np.ndarray) -> TemplateBank:
    bank = TemplateBank(np.zeros((*f.shape[:2], 1, 2, 2), np.float16), f.shape[2])
    bank.f = f.astype(np.float32)
    return bank


def test_hard_templates_by_hand():
    # 3 objects x 4 templates in 2-D; the sample (object 0) sits at the origin.
    f = np.array(
        [
            [[0.1, 0], [5, 5], [0.3, 0], [9, 9]],  # object 0: templates 0 and 2 are near it
            [[4, 0], [0.5, 0.5], [7, 7], [8, 8]],  # object 1: template 1 is the nearest other-object one
            [[0.9, 0], [6, 6], [7, 0], [8, 1]],  # object 2: template 0 next
        ]
    )
    # pose distances of the sample to object 0's templates: 0 and 1 are within 20 deg, 2 and 3 beyond
    pd = np.array([3.0, 12.0, 35.0, 90.0])
    hard = bank_of(f).hard(np.zeros((1, 2)), np.array([0]), [pd], n_other=2, min_angle=20.0)
    assert sorted(hard[:2]) == [(1, 1), (2, 0)]
    assert hard[2] == (0, 2)  # nearest far-off view of its own object, not template 0 (same pose)


def test_mined_templates_join_the_batch_and_bootstrapping_uses_them():
    rng = np.random.default_rng(0)
    symmetries = ["none"] * 5
    R = TEMPLATE_R[[3, 40]]
    batch = BatchBuilder(TEMPLATE_R, symmetries, extra_templates=0).make([0, 1], [0, 1], R, rng)
    n = len(batch.items)
    bank = bank_of(rng.normal(size=(5, len(TEMPLATE_R), 4)) + 10)  # all far from the samples...
    bank.f[4, 17] = 0.0  # ...but one template of object 4, which is not in the batch
    net = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(4, 4, bias=False))
    with torch.no_grad():
        net[1].weight.zero_()  # every input -> descriptor 0
    x = torch.zeros(len(batch.sample_rows), 1, 2, 2)  # the samples' inputs
    grown = mine(bank, net, batch, x)
    assert ("template", 4, 17) in grown.items and len(grown.items) > n
    assert grown.items[:n] == batch.items and (grown.triplets == batch.triplets).all()
    f = np.full((len(grown.items), 4), 5.0)
    f[grown.sample_rows] = 0.0
    f[grown.items.index(("template", 4, 17))] = 0.1
    hard = bootstrap_triplets(grown, f)
    assert any(grown.items[k] == ("template", 4, 17) for _, _, k in hard)


def test_with_templates_skips_what_is_there():
    rng = np.random.default_rng(1)
    batch = BatchBuilder(TEMPLATE_R, ["none", "none"]).make([0], [0], TEMPLATE_R[5:6], rng)
    there = next(it for it in batch.items if it[0] == "template")
    grown, new = with_templates(batch, [(there[1], there[2]), (1, 7), (1, 7)])
    assert new == [("template", 1, 7)] and len(grown.items) == len(batch.items) + 1
    s = int(grown.sample_rows[0])
    assert set(grown.pose_dist[s]) == {r for r, it in enumerate(grown.items) if it[:2] == ("template", 0)}
