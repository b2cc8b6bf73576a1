"""Hostile inputs, made here once for the tests that check how they are refused (tests/promises/test_hostile_uploads_refused.py,
tests/index/templates/test_mesh_limits.py, tests/index/templates/test_mesh_fuzz.py) and for the bench's "guards" section, which
times the refusals (`benchmarks/serving/guards.py`): what a test asserts is the answer, what the bench prints is how
long it took.

- `UPLOADS`: images that claim or decompress to huge sizes, meshes that expand to millions of faces or
  thousands of parts, NaN and infinite vertices, broken GLB, each with the answer the service gives;
- `DECLARING`: mesh files whose headers or lines declare too much (refused before parsing);
- `damage`: a valid mesh file with bytes flipped, cut, repeated, inserted, numbers made absurd."""

from __future__ import annotations

import base64
import io
import json
import re
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from PIL import Image


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_claiming(w: int, h: int, extra: bytes = b"") -> bytes:
    """A PNG header of w x h grey pixels followed by a few bytes of pixels."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    idat = _chunk(b"IDAT", zlib.compress(b"\0" * 100))
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + extra + idat + _chunk(b"IEND", b"")


def jpeg_claiming(w: int, h: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, h, w, 1) + b"\x01\x11\x00"
    sos = b"\xff\xda" + struct.pack(">HB", 8, 1) + b"\x01\x00\x00\x3f\x00"
    return b"\xff\xd8" + sof + sos + b"\0" * 16 + b"\xff\xd9"


def png_of(w: int, h: int, mode: str = "L") -> bytes:
    """A real all-zero PNG: 5000 x 5000 is 24 kB that decode to 25 MB."""
    buf = io.BytesIO()
    Image.new(mode, (w, h)).save(buf, format="PNG")
    return buf.getvalue()


def text_bomb() -> bytes:
    """A valid 64 x 64 PNG with a zTXt chunk that inflates to 200 MB."""
    z = _chunk(b"zTXt", b"comment\0\0" + zlib.compress(b"\0" * 200_000_000, 9))
    return png_claiming(64, 64, z)


def ply(faces: int, body: bytes) -> bytes:
    """A binary PLY of three vertices whose header declares `faces` faces; `body` holds the faces."""
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return header.encode() + struct.pack("<9f", 0, 0, 0, 100, 0, 0, 0, 100, 0) + body


def ply_triangles(n: int) -> bytes:
    """A binary PLY whose header declares n faces; its body holds ten."""
    return ply(n, struct.pack("<B3i", 3, 0, 1, 2) * 10)


def ply_polygons(n: int, corners: int = 255) -> bytes:
    """n faces of `corners` corners each: n * (corners - 2) triangles once parsed; 49 MB for 48,000
    255-gons, 12 million triangles."""
    return ply(n, (struct.pack("<B", corners) + np.resize(np.array([0, 1, 2], "<i4"), corners).tobytes()) * n)


def stl_binary(n: int, corrupt: float | None = None) -> bytes:
    tris = np.zeros(n, dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    tris["v"] = np.random.default_rng(0).uniform(0, 100, (n, 3, 3))
    if corrupt is not None:
        tris["v"][-1, 0, 0] = corrupt
    return b"\0" * 80 + struct.pack("<I", n) + tris.tobytes()


def glb_of_a_box() -> tuple[bytearray, dict, bytes]:
    data = bytearray(trimesh.creation.box(extents=[50, 50, 50]).export(file_type="glb"))
    (length,) = struct.unpack_from("<I", data, 12)
    return data, json.loads(data[20 : 20 + length]), bytes(data[20 + length :])


def glb_chunk_length_lie() -> bytes:
    data, _, _ = glb_of_a_box()
    struct.pack_into("<I", data, 12, 0x7FFFFFF0)  # the JSON chunk claims 2 GB
    return bytes(data)


def glb_accessor_lie() -> bytes:
    _, doc, rest = glb_of_a_box()
    for accessor in doc["accessors"]:
        accessor["count"] = 2_000_000_000
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    return (
        b"glTF"
        + struct.pack("<II", 2, 20 + len(js) + len(rest))
        + struct.pack("<I", len(js))
        + b"JSON"
        + js
        + rest
    )


def glb_index_outside(glb: bytes | None = None) -> bytes:
    """A GLB (a box unless given) whose first face index is set to 257 of its 8 vertices: trimesh loads
    it, then its colour code indexes with it (an IndexError, a 500 in the service before it was refused)."""
    data = bytearray(glb if glb is not None else glb_of_a_box()[0])
    (length,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20 : 20 + length])
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]
    view = doc["bufferViews"][acc["bufferView"]]
    at = 20 + length + 8 + view.get("byteOffset", 0) + acc.get("byteOffset", 0)  # JSON chunk, BIN header
    struct.pack_into({5125: "<I", 5123: "<H"}[acc["componentType"]], data, at, 257)
    return bytes(data)


def gltf_placed(n: int) -> bytes:
    """One triangle placed on n nodes: 1 MB for 20,000, which took trimesh 15 s to merge."""
    buf = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0]], np.float32).tobytes()
    acc = {
        "bufferView": 0,
        "componentType": 5126,
        "count": 3,
        "type": "VEC3",
        "min": [0, 0, 0],
        "max": [100, 100, 0],
    }
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data:;base64," + base64.b64encode(buf).decode(), "byteLength": len(buf)}],
        "bufferViews": [{"buffer": 0, "byteLength": len(buf)}],
        "accessors": [acc],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "translation": [i, 0, 0]} for i in range(n)],
        "scenes": [{"nodes": list(range(n))}],
        "scene": 0,
    }
    return json.dumps(doc).encode()


OBJ_TRIANGLE = b"v 0 0 0\nv 100 0 0\nv 0 100 0\n"
NAN_PLY = (
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    b"element face 1\nproperty list uchar int vertex_indices\nend_header\nnan 0 0\n100 0 0\n0 100 0\n3 0 1 2\n"
)


@dataclass(frozen=True)
class Upload:
    """A hostile upload and the service's answer: the status and words of its one-line message. `megabytes`:
    a generous bound on how much the server's peak memory may grow for it, far below what the unguarded
    code took (2-4.6 GB for the large meshes). `small`: cheap to make and send (the bench's quick mode)."""

    field: str  # "rgb", "depth" (POST /recognize) or "mesh" (POST /objects)
    filename: str
    make: Callable[[], bytes]
    status: int
    words: str
    megabytes: float
    small: bool = True


UPLOADS: dict[str, Upload] = {
    "png claiming 50000 x 50000": Upload("rgb", "a.png", lambda: png_claiming(50_000, 50_000), 413, "over the limit", 50),
    "png bomb: 24 kB of 5000 x 5000": Upload("rgb", "a.png", lambda: png_of(5000, 5000), 413, "over the limit", 50),
    "jpeg claiming 65000 x 65000": Upload("rgb", "a.jpg", lambda: jpeg_claiming(65_000, 65_000), 413, "over the limit", 50),
    "png text chunk of 200 MB": Upload("rgb", "a.png", text_bomb, 422, "not an image", 50, small=False),
    "png truncated 4000 x 4000": Upload("rgb", "a.png", lambda: png_of(4000, 4000, "RGB")[:5000], 422, "truncated", 100),
    "16-bit 4096 x 4096 zeros": Upload("depth", "d.png", lambda: png_of(4096, 4096, "I;16"), 422, "all zero", 400, small=False),
    "image body of 26 MB": Upload("rgb", "a.png", lambda: b"\0" * 26_000_000, 413, "body over the limit", 150, small=False),
    "ply declaring 10 M faces": Upload("mesh", "m.ply", lambda: ply(10_000_000, b"\0" * 130), 413, "10,000,000 faces", 50),
    "binary stl of 49 MB": Upload("mesh", "m.stl", lambda: stl_binary(980_000), 413, "980,000 faces", 300, small=False),
    "obj of 6 M faces in 48 MB": Upload(
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"f 1 2 3\n" * 6_000_000, 413, "6,000,000 faces", 300, small=False
    ),
    "ply of 255-gons: 12 M triangles": Upload(
        "mesh", "m.ply", lambda: ply_polygons(48_000), 413, "12,144,000 faces", 1500, small=False
    ),
    "obj of 20,000 materials": Upload(
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"".join(b"usemtl m%d\nf 1 2 3\n" % i for i in range(20_000)),
        413, "20,000 parts", 50,
    ),
    "gltf placing 20,000 triangles": Upload("mesh", "m.gltf", lambda: gltf_placed(20_000), 413, "20,000 parts", 100),
    "obj of 300,000 copies of a triangle": Upload(  # simplified to nothing: was a 500
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"f 1 2 3\n" * 300_000, 422, "left none", 300, small=False
    ),
    "mesh body of 51 MB": Upload("mesh", "m.stl", lambda: b"\0" * 51_000_000, 413, "body over the limit", 200, small=False),
    "ply with a NaN vertex": Upload("mesh", "m.ply", lambda: NAN_PLY, 422, "NaN or infinite", 50),
    "obj with an infinite vertex": Upload(
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"v 0 inf 0\nf 1 2 3\nf 2 3 4\n", 422, "NaN or infinite", 50
    ),
    "stl with a NaN vertex": Upload("mesh", "m.stl", lambda: stl_binary(100, np.nan), 422, "NaN or infinite", 50),
    "obj 1e300 mm across": Upload(
        "mesh", "m.obj", lambda: b"v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
        422, "across", 50,
    ),
    "glb whose json chunk claims 2 GB": Upload("mesh", "m.glb", glb_chunk_length_lie, 422, "not a readable GLB", 50),
    "glb whose faces point past its vertices": Upload("mesh", "m.glb", glb_index_outside, 422, "do not exist", 50),
    "glb whose accessors claim 2e9 items": Upload("mesh", "m.glb", glb_accessor_lie, 413, "666,666,666 faces", 50),
}  # fmt: skip

#: mesh files that declare too much, refused before parsing: (make, format, what the message says it declares)
DECLARING: dict[str, tuple[Callable[[], bytes], str, str]] = {
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

# -- damaged meshes (fuzzing the loader) --------------------------------------------------------------

DAMAGE_KINDS = ("flip", "cut", "repeat", "insert", "number")
ABSURD = [  # what a number in a text format becomes
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
_NUMBER = re.compile(rb"-?\d+(\.\d+)?(e-?\d+)?")


def valid_mesh(fmt: str) -> bytes:
    """A coloured 80 x 60 x 40 mm box as a file of `fmt`."""
    box = trimesh.creation.box(extents=[80, 60, 40])
    box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=np.tile([200, 40, 40, 255], (8, 1)))
    data = box.export(file_type=fmt)
    return data.encode() if isinstance(data, str) else data


@dataclass(frozen=True)
class Damage:
    """One change to a file: `kind` at byte `at` (taken modulo the file's length), `size` bytes or
    repetitions, `value` the byte to xor, the bytes to insert, or the number to put in."""

    kind: str
    at: int
    size: int = 1
    times: int = 2
    value: bytes = b"\x01"


def damage(data: bytes, changes: Sequence[Damage]) -> bytes:
    """`data` with `changes` applied one after the other."""
    out = bytearray(data)
    for c in changes:
        at = c.at % max(1, len(out))
        if c.kind == "flip" and out:
            out[at] ^= c.value[0] if c.value and c.value[0] else 1
        elif c.kind == "cut":
            del out[at : at + c.size]
        elif c.kind == "repeat":
            out[at:at] = out[at : at + c.size] * c.times
        elif c.kind == "insert":
            out[at:at] = c.value or b"\0"
        elif c.kind == "number":  # text formats: one number replaced by something absurd
            numbers = list(_NUMBER.finditer(bytes(out)))
            if numbers:
                m = numbers[c.at % len(numbers)]
                out[m.start() : m.end()] = c.value
    return bytes(out)


def random_damage(rng: np.random.Generator) -> list[Damage]:
    """One to four changes, as the fuzz test draws them (the bench's cases)."""
    out = []
    for _ in range(int(rng.integers(1, 5))):
        kind = str(rng.choice(DAMAGE_KINDS))
        value = (
            ABSURD[int(rng.integers(len(ABSURD)))]
            if kind == "number"
            else rng.bytes(int(rng.integers(1, 17)))
        )
        out.append(
            Damage(
                kind, int(rng.integers(0, 1 << 20)), int(rng.integers(1, 65)), int(rng.integers(2, 51)), value
            )
        )
    return out
