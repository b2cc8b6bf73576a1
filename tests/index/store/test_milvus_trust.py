"""`index.store.milvus_trust` without a server: which of a record's files a replica's directory lacks, and
what the replica says then (the checks against a real Milvus: tests/promises/test_replicas_share_one_store.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from index.store.milvus_trust import FILES_KEY, MilvusTrust, counts_with_files, files_written, missing_files
from index.store.shared_files import SharedFiles

COLLECTIONS = {"rgb": "p_t_rgb_aa", "depth": "p_t_depth_bb"}


def test_the_files_a_record_lists_are_looked_for_in_the_directory(tmp_path: Path) -> None:
    files = SharedFiles(tmp_path)
    counts = json.loads(
        counts_with_files({"p_t_rgb_aa": 16}, files_written(True, ["p_t_rgb_aa", "p_t_old_cc"]))
    )
    assert counts["p_t_rgb_aa"] == 16 and counts[FILES_KEY] == {
        "mesh": True,
        "local": ["p_t_old_cc", "p_t_rgb_aa"],
    }
    # the collection of a model this replica does not load is not looked for
    assert missing_files(files, 7, counts, COLLECTIONS) == ["meshes/7.glb", "local/p_t_rgb_aa/7.npz"]
    files.write("meshes/7.glb", b"glb")
    assert missing_files(files, 7, counts, COLLECTIONS) == ["local/p_t_rgb_aa/7.npz"]
    files.write_arrays("local/p_t_rgb_aa/7.npz", local=np.zeros((1, 2)))
    assert missing_files(files, 7, counts, COLLECTIONS) == []


def test_a_record_from_before_the_lists_asks_for_nothing(tmp_path: Path) -> None:
    assert missing_files(SharedFiles(tmp_path), 3, {"p_t_rgb_aa": 16}, COLLECTIONS) == []
    assert (
        missing_files(
            SharedFiles(tmp_path), 3, json.loads(counts_with_files({}, files_written(False, []))), COLLECTIONS
        )
        == []
    )


class _Replica(MilvusTrust):
    def __init__(self, root: Path, store_id: str | None):
        self.files, self.store_id, self.uri = SharedFiles(root), store_id, "http://127.0.0.1:1"


def test_a_directory_without_the_stores_id_is_named_with_what_to_do(tmp_path: Path) -> None:
    r = _Replica(tmp_path, "abc")
    said = r._directory_problem()
    assert (
        said is not None and str(tmp_path) in said and "it has no meta/store-id" in said and "mount" in said
    )
    r.files.write("meta/store-id", b"other\n")
    assert "its store id is other" in (r._directory_problem() or "")
    r.files.write("meta/store-id", b"abc\n")
    assert r._directory_problem() is None
    assert _Replica(tmp_path / "new", None)._directory_problem() is None  # before the store has an id


def test_missing_files_are_named_a_few_objects_at_most() -> None:
    assert MilvusTrust._files_problem({}, "/data") is None
    said = MilvusTrust._files_problem({i: [f"meshes/{i}.glb"] for i in range(5)}, "/data")
    assert said is not None and "object 0: meshes/0.glb" in said and "and 2 more objects" in said
    assert "object 4" not in said and "answers nothing until they are there" in said
