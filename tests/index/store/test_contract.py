"""What every template store backend does, run against each: the embedded one (real FAISS and SQLite in a
temporary data dir) and Milvus (the real server of the session, `milvus` fixture; each test its own
collection prefix). Hand-made descriptors."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable, Mapping

import numpy as np
import pytest

from index.store import EmbeddedStore, NameTaken, TemplateSet, TemplateStore, local_key

MODELS = {"rgb": (4, "fp-rgb"), "depth": (4, "fp-depth")}
Opener = Callable[[Mapping[str, tuple[int, str]]], TemplateStore]


@pytest.fixture(
    params=["embedded", pytest.param("milvus", marks=[pytest.mark.slow, pytest.mark.xdist_group("services")])]
)  # starts a Milvus
def open_store(request, tmp_path) -> Opener:
    """Opens the backend's store on the same data (again after a close: a restart)."""
    opened: list[TemplateStore] = []
    if request.param == "embedded":

        def opener(models):
            opened.append(EmbeddedStore(tmp_path, models))
            return opened[-1]
    else:
        from index.store.milvus import MilvusStore

        server = request.getfixturevalue("milvus")
        prefix = f"c{uuid.uuid4().hex[:10]}"

        def opener(models):
            opened.append(MilvusStore(server.uri, tmp_path, models, prefix=prefix))
            return opened[-1]

    yield opener
    for s in opened:
        s.close()
    if request.param == "milvus":  # a restart of the session's Milvus reloads every collection left loaded
        from pymilvus import MilvusClient

        client = MilvusClient(server.uri)
        for c in client.list_collections():
            if c.startswith(prefix):
                client.drop_collection(c)
        client.close()


def templates(centre: float, n: int = 5, dim: int = 4) -> TemplateSet:
    """n descriptors along a line near (centre, ..., centre); pose azimuth = 10 * i."""
    desc = np.full((n, dim), centre, np.float32)
    desc[:, 0] += np.arange(n) * 0.1
    poses = np.stack([np.arange(n) * 10.0, np.full(n, 30.0), np.zeros(n)], axis=1)
    return TemplateSet(poses, desc)


def add(store: TemplateStore, name: str, centre: float) -> int:
    return store.add_object(name, "none", {m: templates(centre) for m in MODELS}).object_id


def test_add_search_remove(open_store):
    store = open_store(MODELS)
    a, b = add(store, "a", 0.0), add(store, "b", 5.0)
    q = np.array([[5.2, 5.0, 5.0, 5.0]], np.float32)
    (matches,) = store.search("rgb", q, 3)
    assert [m.name for m in matches] == ["b", "b", "b"]
    assert matches[0].azimuth == 20.0 and matches[0].elevation == 30.0
    assert matches[0].distance == pytest.approx(0.0, abs=1e-3)
    assert matches[1].distance == pytest.approx(0.1, abs=1e-3)  # L2, not squared
    assert store.snapshot.objects[a].templates == {"rgb": 5, "depth": 5}
    assert store.snapshot.models["rgb"].size == 10
    assert store.remove_object(b) is True
    assert store.remove_object(b) is False
    (matches,) = store.search("depth", q, 10)
    assert {m.object_id for m in matches} == {a} and len(matches) == 5  # k larger than the store


def test_reopen_keeps_state(open_store, tmp_path):
    store = open_store(MODELS)
    a = add(store, "a", 0.0)
    store.remove_object(add(store, "b", 5.0))
    mesh = b"glTF-pretend"
    c = store.add_object("c", "180", {m: templates(9.0) for m in MODELS}, faces=12, mesh=mesh, extra={"k": 1})
    store.close()
    again = open_store(MODELS)
    assert sorted(r.name for r in again.snapshot.objects.values()) == ["a", "c"]
    rec = again.snapshot.objects[c.object_id]
    assert (rec.symmetry, rec.faces, dict(rec.extra)) == ("180", 12, {"k": 1})
    assert again.mesh_bytes(c.object_id) == mesh and again.mesh_bytes(a) is None
    assert {m.name for m in again.search("rgb", np.zeros((1, 4), np.float32), 10)[0]} == {"a", "c"}


def test_changed_model_drops_its_templates(open_store):
    store = open_store(MODELS)
    a = add(store, "a", 0.0)
    store.close()
    again = open_store({"rgb": (4, "fp-rgb"), "depth": (4, "retrained"), "rgbd": (8, "new")})
    assert again.missing() == {"rgb": [], "depth": [a], "rgbd": [a]}
    assert again.snapshot.models["depth"].size == 0
    assert again.search("depth", np.zeros((1, 4), np.float32), 5) == [[]]
    again.add_templates(a, "depth", templates(0.0))
    assert again.missing()["depth"] == []
    assert again.snapshot.objects[a].templates == {"rgb": 5, "depth": 5}
    (matches,) = again.search("depth", np.zeros((1, 4), np.float32), 1)
    assert matches[0].object_id == a
    with pytest.raises(KeyError):
        again.add_templates(a + 100, "depth", templates(0.0))


def test_bad_inputs_leave_nothing(open_store):
    store = open_store(MODELS)
    with pytest.raises(ValueError, match=r"expected \(N, 4\)"):
        store.add_object("x", "none", {"rgb": templates(0.0, dim=3)})
    with pytest.raises(KeyError):
        store.add_object("x", "none", {"rgbd": templates(0.0)})
    bad = templates(0.0)
    bad.descriptors[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        store.add_object("x", "none", {"rgb": bad})
    assert store.snapshot.objects == {} and not store.has_held_objects()


def test_answers_are_distinct_viewpoints_at_their_best(open_store):
    """Three in-plane variants of each of four viewpoints: k answers are k viewpoints, each at its nearest
    variant; a turn of the query adds its offset to the template's in-plane angle (wrapped)."""
    store = open_store({"rgb": (2, "fp")})
    poses = np.array([(az, 30.0, ip) for az in (0.0, 90.0, 180.0, 270.0) for ip in (-120.0, 0.0, 120.0)])
    desc = np.array([[az / 90.0, ip / 1000.0] for az, _, ip in poses], np.float32)
    store.add_object("a", "none", {"rgb": TemplateSet(poses, desc)})
    snap = store.snapshot
    q = np.array([[1.0, 0.121]], np.float32)  # nearest: azimuth 90, in-plane 120
    answers = snap.answers("rgb", q, 3, variants=3)
    assert [(m.azimuth, m.inplane) for m in answers] == [(90.0, 120.0), (0.0, 120.0), (180.0, 120.0)]
    assert [m.distance for m in answers] == sorted(m.distance for m in answers)
    assert len(snap.answers("rgb", q, 10, variants=1)) == 4  # searches further for distinct ones
    turned = snap.answers("rgb", np.array([[5.0, 0.0], [1.0, 0.12]], np.float32), 1, np.array([0.0, 90.0]))
    assert (turned[0].azimuth, turned[0].inplane) == (90.0, -150.0)  # 120 + 90, wrapped


def test_weights_choose_the_answers_and_leave_their_distances(open_store):
    """An object weighed 2 (a shape-only one in colour) gives its place to another's farther templates; the
    distances returned are still the descriptors'."""
    store = open_store({"rgb": (2, "fp")})
    poses = np.array([(az, 30.0, 0.0) for az in (0.0, 90.0)])
    grey = store.add_object(
        "grey", "none", {"rgb": TemplateSet(poses, np.array([[0, 0], [0, 1]], np.float32))}
    )
    seen = store.add_object(
        "seen", "none", {"rgb": TemplateSet(poses, np.array([[3, 0], [3, 1]], np.float32))}
    )
    snap, q = store.snapshot, np.array([[1.0, 0.0]], np.float32)
    assert [m.object_id for m in snap.answers("rgb", q, 2)] == [grey.object_id] * 2
    weighed = snap.answers("rgb", q, 2, weights={grey.object_id: 2.5})
    assert [m.object_id for m in weighed] == [seen.object_id] * 2
    assert weighed[0].distance == pytest.approx(2.0)  # the descriptors' distance, not 2.0 weighed
    lighter = snap.answers("rgb", q, 2, weights={grey.object_id: 1.5})  # 1.5 and 2.1 against 2 and 2.2
    assert [m.object_id for m in lighter] == [grey.object_id, seen.object_id]


def test_local_features_persist_and_leave_with_their_object(open_store):
    ts = templates(1.0, n=4)
    rows = np.array([0, 2])
    local = np.random.default_rng(0).normal(size=(2, 6)).astype(np.float16)
    with_local = TemplateSet(ts.poses, ts.descriptors, rows, local)
    store = open_store(MODELS)
    oid = store.add_object("a", "none", {"rgb": with_local, "depth": ts}).object_id
    plain = add(store, "b", 5.0)
    keys = {local_key(oid, *ts.poses[r, :2]) for r in rows}
    assert set(store.snapshot.models["rgb"].local) == keys
    assert not store.snapshot.models["depth"].local
    store.close()
    again = open_store(MODELS)
    got = again.snapshot.models["rgb"].local
    assert set(got) == keys
    np.testing.assert_array_equal(got[local_key(oid, *ts.poses[2, :2])], local[1])
    assert again.remove_object(oid)
    assert not again.snapshot.models["rgb"].local and plain in again.snapshot.objects


def test_a_name_is_stored_once(open_store):
    store = open_store(MODELS)
    a = add(store, "a", 0.0)
    with pytest.raises(NameTaken) as taken:
        add(store, "a", 5.0)
    assert taken.value.object_id == a and f"object_id {a}" in str(taken.value)
    assert [r.name for r in store.snapshot.objects.values()] == ["a"]
    assert store.snapshot.named("a").object_id == a and store.snapshot.named("b") is None
    store.remove_object(a)
    assert add(store, "a", 5.0) != a  # a removed object's name is free again; its id is not reused


def test_has_held_objects_outlives_the_objects(open_store):
    store = open_store(MODELS)
    assert not store.has_held_objects()
    store.remove_object(add(store, "a", 0.0))
    assert store.snapshot.objects == {}
    assert store.get_meta("flag") is None
    store.set_meta("flag", "1")
    store.close()
    again = open_store(MODELS)
    assert again.has_held_objects() and again.get_meta("flag") == "1"


def test_readers_never_see_half_an_object(open_store):
    store = open_store(MODELS)
    stop = threading.Event()
    errors: list[str] = []

    def reader():
        q = np.zeros((1, 4), np.float32)
        while not stop.is_set():
            snap = store.snapshot
            for m, mi in snap.models.items():
                if mi.size != sum(r.templates[m] for r in snap.objects.values()):
                    errors.append(f"{m}: {mi.size} templates for objects of another count")
            for match in snap.search("rgb", q, 50)[0]:
                if match.object_id not in snap.objects:
                    errors.append(f"match of unknown object {match.object_id}")

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    ids = []
    for i in range(12):
        ids.append(add(store, f"o{i}", float(i % 3)))
        if i % 3 == 2:
            store.remove_object(ids.pop(0))
    stop.set()
    for t in threads:
        t.join()
    assert errors == []
    assert len(store.snapshot.objects) == 8


def test_a_snapshot_within_some_objects_searches_theirs_only(open_store):
    """A window class's search (`Snapshot.within`): the nearest templates of those objects, however near
    the others' are, and only their records; the whole snapshot is unchanged."""
    store = open_store(MODELS)
    near, far, farther = add(store, "near", 1.0), add(store, "far", 5.0), add(store, "farther", 9.0)
    snap = store.snapshot
    q = np.full((1, 4), 1.0, np.float32)
    within = snap.within(frozenset({far, farther}))
    assert set(within.objects) == {far, farther} and within.size("rgb") == 10
    found = within.answers("rgb", q, 10)
    assert {m.object_id for m in found} == {far, farther} and found[0].object_id == far
    assert len(found) == 10  # every viewpoint of the two, none of the nearest object's
    assert snap.answers("rgb", q, 1)[0].object_id == near and snap.size("rgb") == 15


def test_threads_search_one_snapshot_within_some_objects_at_once(open_store):
    """Two places of a frame are verified at once against one window class (`Snapshot.within`): the
    searches answer as one at a time does. FAISS swaps the selector in a search's parameters while it
    searches, so one parameters object shared by two threads crashed the process."""
    store = open_store(MODELS)
    sets = {m: templates(1.0, n=3000) for m in MODELS}
    a = store.add_object("a", "none", sets).object_id
    add(store, "b", 1.05)
    within = store.snapshot.within(frozenset({a}))
    q = np.full((4, 4), 1.0, np.float32) + np.arange(4, dtype=np.float32)[:, None] * 0.01
    alone = within.knn("rgb", q, 20)
    errors: list[str] = []

    def search() -> None:
        for _ in range(300):
            d, oids, poses = within.knn("rgb", q, 20)
            if not (np.array_equal(oids, alone[1]) and np.allclose(d, alone[0])):
                errors.append("another answer")

    threads = [threading.Thread(target=search) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and set(alone[1].ravel().tolist()) == {a}
