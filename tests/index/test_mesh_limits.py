"""Mesh files too large to load safely are refused: before parsing from what they declare, right after
parsing from what the parser found; files under the limits load as before."""

from __future__ import annotations

import base64
import json
import struct
import time

import numpy as np
import pytest
import trimesh

from index.mesh import MeshTooLarge, load_mesh
from index.mesh_limits import MAX_PARTS, Size, declared


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


def ply_triangles(n: int) -> bytes:
    """A binary PLY whose header declares n faces; its body holds ten."""
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {n}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return (
        header.encode()
        + struct.pack("<9f", 0, 0, 0, 100, 0, 0, 0, 100, 0)
        + struct.pack("<B3i", 3, 0, 1, 2) * 10
    )


def ply_polygons(n: int, corners: int = 255) -> bytes:
    """n faces of `corners` corners each: n * (corners - 2) triangles once parsed."""
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {n}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face = struct.pack("<B", corners) + np.resize(np.array([0, 1, 2], "<i4"), corners).tobytes()
    return header.encode() + struct.pack("<9f", 0, 0, 0, 100, 0, 0, 0, 100, 0) + face * n


def gltf_placed(n: int) -> bytes:
    """One triangle placed on n nodes."""
    buf = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0]], np.float32).tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data:;base64," + base64.b64encode(buf).decode(), "byteLength": len(buf)}],
        "bufferViews": [{"buffer": 0, "byteLength": len(buf)}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [100, 100, 0],
            }
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "translation": [i, 0, 0]} for i in range(n)],
        "scenes": [{"nodes": list(range(n))}],
        "scene": 0,
    }
    return json.dumps(doc).encode()


OBJ_TRIANGLE = b"v 0 0 0\nv 100 0 0\nv 0 100 0\n"
REFUSED_BEFORE_PARSING = {  # made when the test runs: some are 50 MB
    # 48 MB; trimesh alone takes 6 s and 0.9 GB for it, with the checks 14 s and 2 GB
    "obj with 6 M face lines": (lambda: OBJ_TRIANGLE + b"f 1 2 3\n" * 6_000_000, "obj", "6,000,000 faces"),
    "ply header of 10 M faces": (lambda: ply_triangles(10_000_000), "ply", "10,000,000 faces"),
    "stl of 1 M triangles": (
        lambda: b"\0" * 80 + struct.pack("<I", 10**6) + bytes(50 * 10**6),
        "stl",
        "1,000,000 faces",
    ),
    "obj of 20,000 materials": (  # 0.4 MB that trimesh takes 84 s to parse
        lambda: OBJ_TRIANGLE + b"".join(b"usemtl m%d\nf 1 2 3\n" % i for i in range(20_000)),
        "obj",
        "20,000 parts",
    ),
    "gltf of 20,000 placements": (lambda: gltf_placed(20_000), "gltf", "20,000 parts"),  # 15 s to merge
}


@pytest.mark.parametrize("case", list(REFUSED_BEFORE_PARSING))
def test_files_declaring_too_much_are_refused_before_parsing(case):
    make, fmt, what = REFUSED_BEFORE_PARSING[case]
    data = make()
    t0 = time.perf_counter()
    with pytest.raises(MeshTooLarge, match=f"declares {what}"):
        load_mesh(data, file_type=fmt, max_input_faces=500_000)
    assert time.perf_counter() - t0 < 2.0  # counting, not parsing (parsing takes 6-84 s)


def test_polygons_are_counted_as_the_triangles_they_become():
    data = ply_polygons(100)  # declares 100 faces, holds 25,300 triangles
    assert declared(data, "ply") == Size(100)
    with pytest.raises(MeshTooLarge, match="holds 25,300 faces"):
        load_mesh(data, file_type="ply", max_input_faces=10_000)
    assert len(load_mesh(data, file_type="ply", max_input_faces=30_000, max_faces=None).faces) == 25_300


def test_parts_under_the_limit_load():
    assert declared(gltf_placed(MAX_PARTS), "gltf") == Size(MAX_PARTS, MAX_PARTS)
    assert len(load_mesh(gltf_placed(50), file_type="gltf", max_input_faces=1000).faces) == 50
