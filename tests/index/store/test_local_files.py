"""The embedded store's local features in memory-mapped files, and two models sharing one index
(`index.store.local_files`, `index.store.embedded`): real SQLite, FAISS and files in a temporary data dir,
hand-made templates."""

from __future__ import annotations

import json
import sqlite3

import numpy as np

from index.store import Store, TemplateSet, local_key
from index.store.local_files import LOCAL_DIR

#: rgbd takes rgb's templates (as `index.templates.register.template_twins` gives them); depth has its own
MODELS = {"rgb": (4, "fp-rgb"), "depth": (3, "fp-depth"), "rgbd": (4, "fp-rgbd")}


def templates(centre: float, seed: int = 0, n: int = 6) -> TemplateSet:
    """n templates (azimuth 10 i, upright and turned alternately), local features of the upright ones."""
    rng = np.random.default_rng(seed)
    desc = (np.full((n, 4), centre) + rng.normal(0, 0.01, (n, 4))).astype(np.float32)
    poses = np.stack([np.arange(n) * 10.0, np.full(n, 30.0), np.where(np.arange(n) % 2, 30.0, 0.0)], axis=1)
    rows = np.flatnonzero(poses[:, 2] == 0)
    return TemplateSet(poses, desc, rows, rng.normal(size=(len(rows), 8)).astype(np.float16))


def depth(centre: float, n: int = 6) -> TemplateSet:
    poses = np.stack([np.arange(n) * 10.0, np.full(n, 30.0), np.zeros(n)], axis=1)
    return TemplateSet(poses, np.full((n, 3), centre, np.float32))


def add(store: Store, name: str, centre: float, rgbd: TemplateSet | None = None) -> int:
    ts = templates(centre)
    sets = {"rgb": ts, "depth": depth(centre), "rgbd": ts if rgbd is None else rgbd}
    return store.add_object(name, "none", sets).object_id


def nearest(store: Store, model: str, centre: float) -> str:
    return store.search(model, np.full((1, 4), centre, np.float32), 1)[0][0].name


def test_local_features_are_mapped_from_their_files_and_leave_with_their_object(tmp_path):
    store = Store(tmp_path, MODELS)
    a, b = add(store, "a", 0.0), add(store, "b", 5.0)
    files = sorted((tmp_path / LOCAL_DIR).rglob("*.npy"))
    assert [f.name for f in files] == [f"{a}.npy", f"{b}.npy"]  # rgbd's are rgb's: no files of its own
    store.close()
    again = Store(tmp_path, MODELS)
    local = again.snapshot.models["rgb"].local
    ts = templates(0.0)
    key = local_key(a, *ts.poses[ts.local_rows[1], :2])
    np.testing.assert_array_equal(local[key], ts.local[1])
    assert not local[key].flags.owndata and isinstance(local[key].base.base, np.memmap)  # type: ignore[union-attr]
    assert again.remove_object(a)
    assert not (files[0]).exists() and files[1].exists()
    assert {k[0] for k in again.snapshot.models["rgb"].local} == {b}


def test_a_missing_or_damaged_file_is_made_again_from_sqlite(tmp_path):
    store = Store(tmp_path, MODELS)
    a = add(store, "a", 0.0)
    store.close()
    path = next((tmp_path / LOCAL_DIR).rglob(f"{a}.npy"))
    path.write_bytes(path.read_bytes()[:-2])  # a truncated file
    again = Store(tmp_path, MODELS)
    ts = templates(0.0)
    got = again.snapshot.models["rgb"].local[local_key(a, *ts.poses[0, :2])]
    np.testing.assert_array_equal(got, ts.local[0])
    again.close()
    path.unlink()
    third = Store(tmp_path, MODELS)
    np.testing.assert_array_equal(
        third.snapshot.models["rgbd"].local[local_key(a, *ts.poses[0, :2])], ts.local[0]
    )


def test_files_of_objects_sqlite_does_not_hold_are_swept(tmp_path):
    store = Store(tmp_path, MODELS)
    a = add(store, "a", 0.0)
    store.close()
    folder = next((tmp_path / LOCAL_DIR).rglob(f"{a}.npy")).parent
    (folder / "99.npy").write_bytes((folder / f"{a}.npy").read_bytes())  # a rolled-back registration's
    (tmp_path / LOCAL_DIR / "rgb-fp-old").mkdir()  # the model's earlier fingerprint
    Store(tmp_path, MODELS).close()
    assert not (folder / "99.npy").exists() and (folder / f"{a}.npy").exists()
    assert not (tmp_path / LOCAL_DIR / "rgb-fp-old").exists()


def test_twins_share_one_index_across_restarts(tmp_path):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    add(store, "b", 5.0)
    snap = store.snapshot
    assert snap.models["rgbd"] is snap.models["rgb"] and snap.models["depth"] is not snap.models["rgb"]
    store.close()
    tag = json.loads((tmp_path / "rgbd.faiss.json").read_text())
    assert tag["same_as"] == "rgb" and not (tmp_path / "rgbd.faiss").exists()
    again = Store(tmp_path, MODELS)
    assert again.snapshot.models["rgbd"] is again.snapshot.models["rgb"]
    assert nearest(again, "rgbd", 5.0) == "b" and again.snapshot.objects.keys() == snap.objects.keys()


def test_twins_part_when_their_templates_differ(tmp_path):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    add(store, "b", 5.0, rgbd=templates(9.0, seed=1))  # rgbd's templates of b are not rgb's
    snap = store.snapshot
    assert snap.models["rgbd"] is not snap.models["rgb"]
    assert nearest(store, "rgbd", 9.0) == "b" and nearest(store, "rgb", 9.0) == "b"
    assert nearest(store, "rgbd", 0.0) == "a"
    other = templates(9.0, seed=1)
    key = local_key(2, *other.poses[0, :2])
    np.testing.assert_array_equal(snap.models["rgbd"].local[key], other.local[0])
    store.remove_object(1)  # each its own index now: the removal reaches both
    assert nearest(store, "rgbd", 0.0) == "b" and nearest(store, "rgb", 0.0) == "b"
    store.close()
    again = Store(tmp_path, MODELS)
    assert again.snapshot.models["rgbd"] is not again.snapshot.models["rgb"]
    np.testing.assert_array_equal(again.snapshot.models["rgbd"].local[key], other.local[0])
    np.testing.assert_array_equal(again.snapshot.models["rgb"].local[key], templates(5.0).local[0])


def test_a_store_from_before_sharing_is_shared_when_opened(tmp_path):
    store = Store(tmp_path, {"rgb": MODELS["rgb"], "rgbd": MODELS["rgbd"]})
    add_alone = {"rgb": templates(0.0), "rgbd": templates(0.0)}  # equal, not the same objects
    store.add_object("a", "none", add_alone)
    store.close()
    (tmp_path / "rgbd.faiss.json").unlink()  # as a store written before: no `same_as`
    again = Store(tmp_path, {"rgb": MODELS["rgb"], "rgbd": MODELS["rgbd"]})
    assert again.snapshot.models["rgbd"] is again.snapshot.models["rgb"]
    assert json.loads((tmp_path / "rgbd.faiss.json").read_text())["same_as"] == "rgb"


def test_a_twins_features_are_stored_once_and_outlive_a_change_of_the_other_model(tmp_path):
    store = Store(tmp_path, MODELS)
    a = add(store, "a", 0.0)
    store.close()
    db = sqlite3.connect(tmp_path / "store.sqlite")
    sizes = dict(db.execute("SELECT model, SUM(length(local)) FROM templates GROUP BY model").fetchall())
    db.close()
    ts = templates(0.0)
    assert sizes["rgb"] == ts.local.nbytes and sizes["rgbd"] < 100  # rgbd's rows point to rgb's
    changed = {**MODELS, "rgb": (4, "fp-rgb-2")}  # a new rgb model: its templates are dropped
    again = Store(tmp_path, changed)
    assert again.missing()["rgb"] == [a] and again.missing()["rgbd"] == []
    got = again.snapshot.models["rgbd"].local
    for r, f in zip(ts.local_rows, ts.local, strict=True):
        np.testing.assert_array_equal(got[local_key(a, *ts.poses[r, :2])], f)
    assert nearest(again, "rgbd", 0.0) == "a"
