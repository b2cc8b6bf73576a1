"""Mesh files too large to load safely are refused: before parsing from what they declare, right after
parsing from what the parser found; files under the limits load as before. How long the count before
parsing takes (milliseconds, where parsing took 6-84 s) is a figure of `posedesc bench --only guards`."""

from __future__ import annotations

import pytest
import trimesh

from benchmarks.serving.hostile import DECLARING, gltf_placed, ply_polygons
from index.templates.mesh import MeshTooLarge, load_mesh
from index.templates.mesh_limits import MAX_PARTS, Size, declared


def as_bytes(data: bytes | str) -> bytes:
    return data.encode() if isinstance(data, str) else data


@pytest.mark.parametrize("fmt", ["ply", "obj", "stl", "stl-ascii", "off", "glb"])
def test_declared_faces_are_the_real_ones(l_shape, fmt):
    if fmt == "stl-ascii":
        data, fmt = as_bytes(trimesh.exchange.stl.export_stl_ascii(l_shape)), "stl"
    else:
        data = as_bytes(l_shape.export(file_type=fmt))
    assert declared(data, fmt) == Size(len(l_shape.faces))
    assert len(load_mesh(data, file_type=fmt, max_input_faces=len(l_shape.faces)).faces) == len(l_shape.faces)


@pytest.mark.parametrize("case", list(DECLARING))
def test_files_declaring_too_much_are_refused_before_parsing(case, monkeypatch):
    make, fmt, what = DECLARING[case]
    parsed: list[str] = []
    load = trimesh.load
    monkeypatch.setattr(trimesh, "load", lambda *a, **kw: parsed.append(fmt) or load(*a, **kw))
    with pytest.raises(MeshTooLarge, match=f"declares {what}"):
        load_mesh(make(), file_type=fmt, max_input_faces=500_000)
    assert parsed == []  # refused from the count: the parser never ran (parsing these takes 6-84 s)


def test_polygons_are_counted_as_the_triangles_they_become():
    data = ply_polygons(100)  # declares 100 faces, holds 25,300 triangles
    assert declared(data, "ply") == Size(100)
    with pytest.raises(MeshTooLarge, match="holds 25,300 faces"):
        load_mesh(data, file_type="ply", max_input_faces=10_000)
    assert len(load_mesh(data, file_type="ply", max_input_faces=30_000, max_faces=None).faces) == 25_300


def test_parts_under_the_limit_load():
    assert declared(gltf_placed(MAX_PARTS), "gltf") == Size(MAX_PARTS, MAX_PARTS)
    assert len(load_mesh(gltf_placed(50), file_type="gltf", max_input_faces=1000).faces) == 50
