"""The paper's mini-batches and in-batch bootstrapping, on indices only (the images come from
`training/data.py`), so the invariants can be tested without a picture.

A batch holds training samples (renders through the sensor model, or real patches) and templates (clean
renders at the template viewpoints). For every sample: its template with the closest pose (the positive
and the pair), a template of the same object with a less similar pose among the closest few, a random
template of the same object, and the closest template of another sample's object; three triplets with
the sample as anchor. Every object present has at least two templates in the batch. Bootstrapping adds,
for every sample, the template of its object nearest in descriptor space among those of a wrong pose,
and the nearest template of another object, both from inside the batch."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from training.similarity import Symmetry, pose_distances


@dataclass
class Batch:
    """items[i] is ("sample", object, sample_id) or ("template", object, template_index); triplets (T, 3) and
    pairs (P, 2) are row indices into items. `sample_rows` lists the rows of the samples."""

    items: list[tuple]
    triplets: np.ndarray
    pairs: np.ndarray
    sample_rows: np.ndarray
    objects: np.ndarray  # object of every row
    #: for each sample row: pose distance (deg) to every template of its object, by template index (T,)
    sample_dists: dict[int, np.ndarray] = field(default_factory=dict)
    #: for each sample row: pose distance (deg) to every template row of its object, by row
    pose_dist: dict[int, dict[int, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.pose_dist:
            self.pose_dist = _row_dists(self.items, self.sample_dists)


def _row_dists(items: list[tuple], sample_dists: dict[int, np.ndarray]) -> dict[int, dict[int, float]]:
    return {
        s: {r: float(d[it[2]]) for r, it in enumerate(items) if it[0] == "template" and it[1] == items[s][1]}
        for s, d in sample_dists.items()
    }


def with_templates(batch: Batch, extra: Sequence[tuple[int, int]]) -> tuple[Batch, list[tuple]]:
    """The batch with more templates ((object, template index) each) appended as rows, for bootstrapping
    to choose from; templates already in it are not repeated. Returns the batch and the new items."""
    have = set(batch.items)
    new: list[tuple] = []
    for o, t in extra:
        it = ("template", int(o), int(t))
        if it not in have:
            have.add(it)
            new.append(it)
    if not new:
        return batch, []
    items = batch.items + new
    objects = np.concatenate([batch.objects, np.array([it[1] for it in new], np.int64)])
    return (
        Batch(items, batch.triplets, batch.pairs, batch.sample_rows, objects, batch.sample_dists),
        new,
    )


class BatchBuilder:
    """Makes batches for objects that share one set of template rotations (template_R, (N, 3, 3))."""

    def __init__(
        self,
        template_R: np.ndarray,
        symmetries: Sequence[Symmetry],
        near: int = 8,
        extra_templates: int = 2,
    ):
        self.template_R = np.asarray(template_R, float)
        self.symmetries = list(symmetries)
        self.near = near  # the "less similar" template is one of the `near` closest after the closest
        self.extra = extra_templates  # more random templates per sample: candidates for bootstrapping

    def make(
        self,
        sample_ids: Sequence[int],
        sample_objects: Sequence[int] | np.ndarray,
        sample_R: np.ndarray,
        rng: np.random.Generator,
    ) -> Batch:
        """A batch for these samples (id, object, pose R_m2c (S, 3, 3))."""
        items: list[tuple] = []
        rows: dict[tuple, int] = {}

        def row(item: tuple) -> int:
            if item not in rows:
                rows[item] = len(items)
                items.append(item)
            return rows[item]

        n_t = len(self.template_R)
        sample_rows, closest, dists = [], [], []
        for sid, obj, R in zip(sample_ids, sample_objects, sample_R, strict=True):
            d = pose_distances(R[None], self.template_R, self.symmetries[obj])[0]
            sample_rows.append(row(("sample", int(obj), int(sid))))
            closest.append(int(np.argmin(d)))
            dists.append(d)
        triplets, pairs = [], []
        objs = [int(o) for o in sample_objects]
        for s, obj, c, d in zip(sample_rows, objs, closest, dists, strict=True):
            pos = row(("template", obj, c))
            pairs.append((s, pos))
            farther = np.flatnonzero(d > d[c] + 1e-6)
            order = farther[np.argsort(d[farther])]
            less = int(order[rng.integers(min(self.near, len(order)))])
            rand = int(rng.choice(farther))
            triplets.append((s, pos, row(("template", obj, less))))
            triplets.append((s, pos, row(("template", obj, rand))))
            others = [(o, cc) for o, cc in zip(objs, closest, strict=True) if o != obj]
            if others:
                o, cc = others[rng.integers(len(others))]
            else:  # a batch of one object: any other object's template
                o = int((obj + 1 + rng.integers(len(self.symmetries) - 1)) % len(self.symmetries))
                cc = int(rng.integers(n_t))
            triplets.append((s, pos, row(("template", o, cc))))
            for t in rng.choice(farther, size=min(self.extra, len(farther)), replace=False):
                row(("template", obj, int(t)))
        n_templates: dict[int, int] = {}
        for it in list(items):
            if it[0] == "template":
                n_templates[it[1]] = n_templates.get(it[1], 0) + 1
        for o, n in n_templates.items():  # an object seen only as another's negative: a second template
            if n < 2:
                t = next(it[2] for it in items if it[0] == "template" and it[1] == o)
                row(("template", o, int((t + n_t // 2) % n_t)))
        objects = np.array([it[1] for it in items])
        return Batch(
            items,
            np.array(triplets, np.int64).reshape(-1, 3),
            np.array(pairs, np.int64).reshape(-1, 2),
            np.array(sample_rows, np.int64),
            objects.astype(np.int64),
            dict(zip(sample_rows, dists, strict=True)),
        )


def bootstrap_triplets(batch: Batch, f: np.ndarray) -> np.ndarray:
    """Hard triplets from the current descriptors f (rows of the batch, (B, D)): for each sample, its
    closest-pose template as positive against (a) the nearest template of its object whose pose is
    farther than that, (b) the nearest template of another object. Shape: (T, 3)."""
    out = []
    is_template = np.array([it[0] == "template" for it in batch.items])
    pos_of = {int(s): int(p) for s, p in batch.pairs}
    for s in batch.sample_rows:
        s = int(s)
        dist = np.linalg.norm(f - f[s], axis=1)
        pos = pos_of[s]
        pd = batch.pose_dist[s]
        wrong = [r for r, a in pd.items() if a > pd[pos] + 1e-6]
        if wrong:
            out.append((s, pos, wrong[int(np.argmin(dist[wrong]))]))
        other = np.flatnonzero(is_template & (batch.objects != batch.objects[s]))
        if other.size:
            out.append((s, pos, int(other[np.argmin(dist[other])])))
    return np.array(out, np.int64).reshape(-1, 3)
