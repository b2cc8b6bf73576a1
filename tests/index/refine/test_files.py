"""The colour fit models kept on disk (`index.refine.files.ColourFiles`): read back as made, never for an
object that is not registered or was registered anew under the same id, and swept when their object goes."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import trimesh

from index.draw import DrawMesh
from index.refine import colour
from index.refine.colour import ColourModel
from index.refine.files import FIT_DIR, ColourFiles


@pytest.fixture(scope="module")
def model() -> ColourModel:
    return ColourModel.of(DrawMesh.of(trimesh.creation.box(extents=(60.0, 40.0, 20.0))), views=24, points=40)


def same(a: ColourModel, b: ColourModel) -> bool:
    arrays = all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("directions", "coords", "angles"))
    return arrays and (a.unit, a.diameter) == (b.unit, b.diameter)


def test_a_kept_model_is_read_back_as_it_was_made(tmp_path, model):
    files = ColourFiles(tmp_path, {7: 1700000000.25}.get)
    assert files.read(7) is None  # none kept yet
    files.write(7, model)
    back = files.read(7)
    assert back is not None and same(back, model) and back.coords.dtype == np.int8
    # another process on the same data dir reads it too
    assert same(ColourFiles(tmp_path, {7: 1700000000.25}.get).read(7), model)  # type: ignore[arg-type]


def test_an_object_not_registered_or_registered_anew_is_not_read(tmp_path, model):
    ColourFiles(tmp_path, {7: 1700000000.0}.get).write(7, model)
    assert ColourFiles(tmp_path, {}.get).read(7) is None  # not registered
    assert ColourFiles(tmp_path, {7: 1700000900.0}.get).read(7) is None  # the same id, a store made anew
    ColourFiles(tmp_path, {}.get).write(8, model)  # not registered: not kept
    assert not list(tmp_path.rglob("8-*"))


def test_a_damaged_file_is_made_again_not_read(tmp_path, model):
    files = ColourFiles(tmp_path, {3: 1.0}.get)
    files.write(3, model)
    path = files.path(3)
    assert path is not None
    path.write_bytes(path.read_bytes()[:100])  # cut short
    assert files.read(3) is None
    files.write(3, model)
    assert same(files.read(3), model)  # type: ignore[arg-type]


def test_remove_and_sweep_leave_the_registered_objects_and_newer_ids(tmp_path, model):
    registered = {1: 10.0, 2: 20.0, 5: 50.0, 9: 90.0}
    files = ColourFiles(tmp_path, registered.get)
    for oid in registered:
        files.write(oid, model)
    files.remove(2)
    assert files.read(2) is None and files.read(1) is not None
    dead = files.dir / "9-90.npz.0123.tmp"  # a writer killed before its rename, long ago
    dead.write_bytes(b"half")
    os.utime(dead, (time.time() - 3600, time.time() - 3600))
    live = files.dir / "9-90.npz.4567.tmp"  # one writing now
    live.write_bytes(b"half")
    old = tmp_path / FIT_DIR / "colour-0123456789ab"  # another version's models
    old.mkdir()
    (old / "1-10.npz").write_bytes(b"x")
    # 5 was deleted, 1 registered anew (another time), 9 is another process's newer object
    ColourFiles(tmp_path, {1: 11.0}.get).sweep({1: 11.0, 6: 60.0})
    names = sorted(p.name for p in files.dir.iterdir())
    assert names == ["9-90.npz", "9-90.npz.4567.tmp"] and not old.exists()


def test_a_file_the_disk_will_not_remove_is_logged_not_raised(tmp_path, model, caplog):
    """A DELETE must not fail on a cache (a 500 after the object is gone): what cannot be removed is logged."""
    files = ColourFiles(tmp_path, {4: 40.0}.get)
    stuck = files.dir / "4-40.npz"
    (stuck / "inside").mkdir(parents=True)  # a directory where the file would be: unlink refuses it
    files.remove(4)
    files.sweep({5: 50.0})  # 4 was deleted
    assert stuck.is_dir() and caplog.text.count("cannot be removed") == 2


def test_models_made_by_other_code_are_not_read(tmp_path, model, monkeypatch):
    ColourFiles(tmp_path, {6: 60.0}.get).write(6, model)
    monkeypatch.setattr(colour, "VIEWS", colour.VIEWS + 1)  # the models are made otherwise now
    files = ColourFiles(tmp_path, {6: 60.0}.get)
    assert files.read(6) is None
    files.sweep({6: 60.0})  # and the next start removes them
    assert not any((tmp_path / FIT_DIR).iterdir())
