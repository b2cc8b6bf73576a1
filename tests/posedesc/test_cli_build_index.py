"""posedesc build-index: a folder of meshes into a data dir the service then serves."""

from __future__ import annotations

import numpy as np

from index.features.embed import load_models, store_keys
from index.store import Store
from posedesc.cli import main


def test_build_index(tmp_path, posedesc_models, l_shape, capsys):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    l_shape.export(meshes / "lshape.ply")
    (meshes / "broken.stl").write_text("not a mesh")
    (meshes / "notes.txt").write_text("ignored")
    data = tmp_path / "data"
    args = ["build-index", "--meshes", str(meshes), "--data-dir", str(data), "--models", str(posedesc_models)]
    assert main([*args, "--level", "1"]) == 1  # one mesh was unusable
    out = capsys.readouterr().out
    assert "skipped broken.stl" in out and "1 objects added" in out
    (meshes / "broken.stl").unlink()
    assert main([*args, "--level", "1"]) == 0  # a second run skips what is there
    assert "0 objects added" in capsys.readouterr().out
    embedders = load_models(posedesc_models)
    store = Store(data, store_keys(embedders))
    (rec,) = store.snapshot.objects.values()
    assert rec.name == "lshape" and rec.templates["rgb"] == len(store.snapshot.models["rgb"].ids) > 10
    assert np.isfinite(store.snapshot.models["depth"].poses).all()


def test_build_index_errors(tmp_path, posedesc_models, capsys):
    assert main(["build-index", "--meshes", str(tmp_path / "nope"), "--data-dir", str(tmp_path)]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["build-index", "--meshes", str(tmp_path), "--data-dir", str(tmp_path / "d")]) == 2
    assert "no meshes" in capsys.readouterr().err
    (tmp_path / "m.ply").write_text("x")
    empty = tmp_path / "no-models"
    empty.mkdir()
    assert (
        main(
            [
                "build-index",
                "--meshes",
                str(tmp_path),
                "--data-dir",
                str(tmp_path / "d"),
                "--models",
                str(empty),
            ]
        )
        == 2
    )
    assert "no models in" in capsys.readouterr().err


def test_a_symmetry_that_is_not_one_is_refused_in_one_line(tmp_path, capsys):
    args = ["build-index", "--meshes", str(tmp_path), "--data-dir", str(tmp_path / "d"), "--symmetry", "box"]
    try:
        code = main(args)
    except SystemExit as e:  # argparse's own refusal
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "unknown symmetry 'box'; use one of none, 180, full, flip, 180+flip, full+flip" in err[-1]


def test_build_index_names_meshes_and_warns_of_a_shape_only_one(tmp_path, posedesc_models, l_shape, capsys):
    import trimesh

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    bare = trimesh.Trimesh(l_shape.vertices, l_shape.faces)  # no colours: shape only
    bare.export(meshes / "obj_000001.ply")
    data = tmp_path / "data"
    base = ["build-index", "--meshes", str(meshes), "--data-dir", str(data), "--models", str(posedesc_models)]
    assert main([*base, "--name", "obj_000002=ape"]) == 2  # names a mesh the folder does not hold
    assert "no mesh 'obj_000002'" in capsys.readouterr().err
    assert main([*base, "--name", "obj_000001"]) == 2
    assert "write FILE=NAME" in capsys.readouterr().err
    assert main([*base, "--level", "1", "--name", "obj_000001.ply=ape"]) == 0
    out = capsys.readouterr().out
    assert "obj_000001.ply: ape," in out and "warning: the mesh has no colours" in out
    (rec,) = Store(data, store_keys(load_models(posedesc_models))).snapshot.objects.values()
    assert rec.name == "ape"
