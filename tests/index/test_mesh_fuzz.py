"""Fuzzing the mesh loader: valid files of every format, then bytes flipped, cut, repeated, numbers made
absurd. `load_mesh` either returns a usable mesh or raises MeshError (a 422 in the service), never any
other exception (a 500), and never takes long. (schemathesis cannot reach this: it names uploads after
their content's signature, and mesh formats have none it knows.)"""

from __future__ import annotations

import json
import re
import struct
import time

import numpy as np
import trimesh
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from index.mesh import MESH_FORMATS, MeshError, load_mesh

FORMATS = [f for f in MESH_FORMATS if f != "gltf"]  # glTF's JSON points at buffers: as GLB, in one file


def _valid(fmt: str) -> bytes:
    box = trimesh.creation.box(extents=[80, 60, 40])
    box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=np.tile([200, 40, 40, 255], (8, 1)))
    data = box.export(file_type=fmt)
    return data.encode() if isinstance(data, str) else data


VALID = {fmt: _valid(fmt) for fmt in FORMATS}


def _glb_pointing_outside() -> bytes:
    """The box as GLB, its first face index set to 257 (of 8 vertices): trimesh loads it, then its
    colour code indexes with it (an IndexError, a 500 in the service, before this was a MeshError)."""
    glb = bytearray(VALID["glb"])
    (length,) = struct.unpack_from("<I", glb, 12)
    doc = json.loads(glb[20 : 20 + length])
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]
    view = doc["bufferViews"][acc["bufferView"]]
    at = 20 + length + 8 + view.get("byteOffset", 0) + acc.get("byteOffset", 0)  # JSON chunk, BIN header
    struct.pack_into({5125: "<I", 5123: "<H"}[acc["componentType"]], glb, at, 257)
    return bytes(glb)


# what a number in a text format becomes
ABSURD = [
    b"nan",
    b"inf",
    b"-inf",
    b"1e309",
    b"1e300",
    b"-0",
    b"99999999999",
    b"-1",
    b"",
    b"0x10",
    b"4294967296",
]


@st.composite
def damaged(draw: st.DrawFn) -> tuple[str, bytes]:
    fmt = draw(st.sampled_from(FORMATS))
    data = bytearray(VALID[fmt])
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "cut", "repeat", "insert", "number"]))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if kind == "flip" and data:
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "cut":
            del data[at : at + draw(st.integers(1, 64))]
        elif kind == "repeat":
            data[at:at] = data[at : at + draw(st.integers(1, 64))] * draw(st.integers(2, 50))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        else:  # text formats: one number replaced by something absurd
            numbers = list(re.finditer(rb"-?\d+(\.\d+)?(e-?\d+)?", bytes(data)))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data[m.start() : m.end()] = draw(st.sampled_from(ABSURD))
    return fmt, bytes(data)


@given(damaged())
@example(("glb", _glb_pointing_outside()))  # found by this test
@example(("obj", b"v 1\nv 2\nv 3\nf 1 2 3\n"))  # vertices of one coordinate: found by this test
@settings(max_examples=300, deadline=None, database=None, suppress_health_check=list(HealthCheck))
def test_a_damaged_mesh_loads_or_is_refused_with_mesh_error(case):
    fmt, data = case
    t0 = time.perf_counter()
    try:
        mesh = load_mesh(data, file_type=fmt, max_faces=200_000, max_input_faces=500_000)
    except MeshError as e:
        assert "\n" not in str(e)
    else:
        assert len(mesh.faces) > 0 and np.isfinite(mesh.vertices).all()
        assert mesh.faces.max() < len(mesh.vertices)
    assert time.perf_counter() - t0 < 5.0
