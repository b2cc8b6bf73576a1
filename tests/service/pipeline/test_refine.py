"""Refinement: the viewpoints around an answer's own, found once per snapshot's local features."""

from __future__ import annotations

import numpy as np

from index.geometry.pose import camera_centre
from index.store import local_key
from index.templates.viewpoints import hemisphere
from service.pipeline.refine import Viewpoints, ViewpointTable


def _keys(oid: int, level: int = 3) -> list:
    return [local_key(oid, az, el) for az, el in hemisphere(level)]


def test_the_viewpoints_around_one_are_its_nearest_within_one_and_a_half_steps():
    v = Viewpoints.of(_keys(1))
    assert 6.0 < v.step_deg < 11.0  # level 3: ~8 deg between neighbours
    key = v.keys[100]
    near = v.near(key, 6)
    assert 4 <= len(near) <= 6 and key not in near
    angles = [
        np.degrees(np.arccos(np.clip(camera_centre(k[1], k[2]) @ camera_centre(key[1], key[2]), -1, 1)))
        for k in near
    ]
    assert angles == sorted(angles) and max(angles) <= 1.5 * v.step_deg + 1e-6
    # every other viewpoint nearer than the farthest one returned is returned
    others = [k for k in v.keys if k != key and k not in near]
    farthest = np.cos(np.radians(max(angles)))
    assert all(camera_centre(k[1], k[2]) @ camera_centre(key[1], key[2]) <= farthest + 1e-9 for k in others)
    assert Viewpoints.of([key]).near(key, 6) == []


def test_tables_are_built_once_per_mapping_of_local_features():
    table = ViewpointTable(keep=2)
    local = {k: np.zeros(4, np.float16) for k in _keys(1, 1) + _keys(2, 1)}
    first = table.of(local)
    assert set(first) == {1, 2} and len(first[1].keys) == 16
    assert table.of(local) is first
    grown = {**local, **{k: np.zeros(4, np.float16) for k in _keys(3, 1)}}  # a registration: a new mapping
    assert set(table.of(grown)) == {1, 2, 3}
    assert table.of(local) is first  # still kept (two mappings)
