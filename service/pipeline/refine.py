"""Refining the best answers by the re-ranking's own score: each of the best few is also compared at the
viewpoints next to its own (the object's other templates within about one viewpoint step) and at its
roll turned by a third of the templates' in-plane step either way, and keeps the pose that fits best.

Templates sit about 8 deg apart on the sphere (level 3; "around": within 1.5 times that) and 30 deg apart in-plane (the shipped model),
so an answer's pose is off by up to half of those; the local features of every upright template are in
memory already (`index.store.Snapshot`), so the other viewpoints cost a comparison each, and a turned
roll one more cut of the query. Measured on validation frames (README, Evaluation)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from index.pose import camera_centre

Key = tuple[int, float, float]  # `index.store.local_key`: object, azimuth, elevation


@dataclass(frozen=True)
class Viewpoints:
    """One object's viewpoints that have local features: keys, unit directions (V, 3), and the typical
    angle between neighbours (deg; the median of each one's nearest other)."""

    keys: list[Key]
    directions: np.ndarray
    step_deg: float

    @classmethod
    def of(cls, keys: list[Key]) -> Viewpoints:
        directions = np.stack([camera_centre(k[1], k[2]) for k in keys])
        cos = directions @ directions.T
        np.fill_diagonal(cos, -1.0)
        step = (
            float(np.degrees(np.median(np.arccos(np.clip(cos.max(axis=1), -1.0, 1.0)))))
            if len(keys) > 1
            else 0.0
        )
        return cls(keys, directions, step)

    def near(self, key: Key, k: int, within: float = 1.5) -> list[Key]:
        """Up to `k` of the other viewpoints within `within` neighbour steps of `key`'s, nearest first."""
        cos = self.directions @ camera_centre(key[1], key[2])
        limit = np.cos(np.radians(within * self.step_deg))
        return [self.keys[i] for i in np.argsort(-cos)[: k + 1] if cos[i] >= limit and self.keys[i] != key][
            :k
        ]


class ViewpointTable:
    """Each object's `Viewpoints`, built once per snapshot's local features (a registration or deletion
    makes a new mapping, and so a new table) and kept for the last few mappings seen."""

    def __init__(self, keep: int = 4):
        self._tables: list[tuple[Mapping[Key, np.ndarray], dict[int, Viewpoints]]] = []
        self._keep = keep

    def of(self, local: Mapping[Key, np.ndarray]) -> dict[int, Viewpoints]:
        for mapping, table in self._tables:
            if mapping is local:
                return table
        by_object: dict[int, list[Key]] = {}
        for key in local:
            by_object.setdefault(key[0], []).append(key)
        table = {oid: Viewpoints.of(keys) for oid, keys in by_object.items()}
        self._tables = [(local, table), *self._tables][: self._keep]
        return table


TABLES = ViewpointTable()
