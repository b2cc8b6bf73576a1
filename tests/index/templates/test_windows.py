"""Window classes: which window each object size gets, and how a store's objects group by it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from index.geometry.units import LARGEST_MM, SMALLEST_MM
from index.store.records import ObjectRecord
from index.templates.windows import (
    DIAMETER_KEY,
    FILL_HIGH,
    FILL_LOW,
    STEP,
    WINDOW_KEY,
    object_window,
    size_classes,
    window_class,
    window_classes,
)

# LM-O's diameters (models_info.json), mm: the objects the shipped models were trained through 200 mm on
LMO = {1: 102.1, 5: 201.4, 6: 154.5, 8: 261.5, 10: 164.6, 11: 175.9, 12: 145.5}


def test_the_lmo_objects_keep_the_models_window(lmo):
    assert {o: window_class(d, 200.0) for o, d in LMO.items()} == {o: 200.0 for o in LMO}
    assert window_class(300.0, 200.0) == round(200.0 * STEP, 2)  # past the driller: a class up
    read = json.loads((lmo / "models" / "models_info.json").read_text())  # the numbers above are the data's
    assert {int(o): round(v["diameter"], 1) for o, v in read.items()} == LMO


@pytest.mark.parametrize("diameter", np.geomspace(SMALLEST_MM, LARGEST_MM, 60))
def test_every_size_registered_fills_its_window_within_the_band(diameter):
    w = window_class(float(diameter), 200.0)
    assert FILL_LOW - 1e-9 <= diameter / w <= FILL_HIGH + 1e-9
    k = round(2 * np.log2(w / 200.0))
    assert w == pytest.approx(200.0 * STEP**k, abs=0.01)  # a step of the ladder
    # the class nearest the model's: one step nearer would not hold it
    nearer = 200.0 * STEP ** (k - np.sign(k))
    assert k == 0 or not FILL_LOW <= diameter / nearer <= FILL_HIGH


def test_the_ends_of_the_range():
    assert window_class(2000.0, 200.0) == 1600.0 and window_class(1500.0, 200.0) == pytest.approx(1131.37)
    assert window_class(20.0, 200.0) == pytest.approx(35.36) and window_class(25.0, 200.0) == 50.0


def record(oid: int, extra: dict) -> ObjectRecord:
    return ObjectRecord(oid, f"o{oid}", "none", 10, 0.0, {"rgb": 1}, extra)


def test_objects_group_by_size_each_group_within_the_ratio_and_old_objects_left_out():
    objects = {oid: record(oid, {DIAMETER_KEY: d}) for oid, d in LMO.items()} | {99: record(99, {})}
    classes = size_classes(objects, 1.25)
    assert sorted(set().union(*classes.values())) == sorted(LMO)  # 99 has no diameter: in none
    for mm, ids in classes.items():
        ds = [LMO[i] for i in ids]
        assert max(ds) <= 1.25 * min(ds) and min(ds) <= mm <= max(ds)
    assert list(classes) == sorted(classes) and classes[list(classes)[0]] == {1}  # the ape alone
    assert size_classes({}) == {}


def test_objects_group_by_window_the_models_first_and_old_objects_keep_it():
    objects = {
        1: record(1, {}),  # registered before windows were kept
        2: record(2, {WINDOW_KEY: 282.84}),
        3: record(3, {WINDOW_KEY: 200.0}),
        4: record(4, {WINDOW_KEY: 50.0}),
        5: record(5, {WINDOW_KEY: 1600.0}),
    }
    assert object_window(objects[1].extra, 200.0) == 200.0
    classes = window_classes(objects, 200.0)
    assert list(classes) == [200.0, 282.84, 50.0, 1600.0]  # nearest the model's window first
    assert classes[200.0] == {1, 3} and classes[50.0] == {4}
    assert window_classes({}, 200.0) == {}
