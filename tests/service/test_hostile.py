"""Hostile uploads against `posedesc serve` on a loopback port: images that claim or decompress to huge
sizes, meshes that expand to millions of faces or thousands of parts, NaN and infinite vertices, broken
GLB. Each is refused with a 4xx and a one-line JSON message, quickly, and the server's memory stays
bounded: its peak resident memory (VmHWM, reset before each upload) grows by far less than the
unguarded code took (2-4.6 GB for the meshes below)."""

from __future__ import annotations

import base64
import io
import json
import struct
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import pytest
import trimesh
from PIL import Image
from service_helpers import Server, depth_png, png


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
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return header.encode() + struct.pack("<9f", 0, 0, 0, 100, 0, 0, 0, 100, 0) + body


def ply_255_gons(n: int) -> bytes:
    """n faces of 255 corners: 49 MB for 48,000 of them, 12 million triangles once parsed."""
    return ply(n, (struct.pack("<B", 255) + np.resize(np.array([0, 1, 2], "<i4"), 255).tobytes()) * n)


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


def glb_index_outside() -> bytes:
    """The box's first face index set to 257 of 8 vertices (a 500 before: trimesh's colours read it)."""
    data, doc, _ = glb_of_a_box()
    (length,) = struct.unpack_from("<I", data, 12)
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
        "min": [0] * 3,
        "max": [100] * 3,
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

# name: (endpoint field, file name, make the bytes, form fields, status, words of the message, seconds, MB)
# The seconds and MB are generous bounds (a busy shared machine), far below what the unguarded code took.
Case = tuple[str, str, Callable[[], bytes], dict[str, str], int, str, float, float]
CASES: dict[str, Case] = {
    "png claiming 50000 x 50000": ("rgb", "a.png", lambda: png_claiming(50_000, 50_000), {}, 413, "over the limit", 2, 50),
    "png bomb: 24 kB of 5000 x 5000": ("rgb", "a.png", lambda: png_of(5000, 5000), {}, 413, "over the limit", 2, 50),
    "jpeg claiming 65000 x 65000": ("rgb", "a.jpg", lambda: jpeg_claiming(65_000, 65_000), {}, 413, "over the limit", 2, 50),
    "png text chunk of 200 MB": ("rgb", "a.png", text_bomb, {}, 422, "not an image", 2, 50),
    "png truncated 4000 x 4000": ("rgb", "a.png", lambda: png_of(4000, 4000)[:5000], {}, 422, "truncated", 2, 100),
    "16-bit 4096 x 4096 zeros": ("depth", "d.png", lambda: png_of(4096, 4096, "I;16"), {}, 422, "all zero", 5, 400),
    "image body of 26 MB": ("rgb", "a.png", lambda: b"\0" * 26_000_000, {}, 413, "body over the limit", 3, 150),
    "ply declaring 10 M faces": ("mesh", "m.ply", lambda: ply(10_000_000, b"\0" * 130), {}, 413, "10,000,000 faces", 2, 50),
    "binary stl of 49 MB": ("mesh", "m.stl", lambda: stl_binary(980_000), {}, 413, "980,000 faces", 3, 300),
    "obj of 6 M faces in 48 MB": (
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"f 1 2 3\n" * 6_000_000, {}, 413, "6,000,000 faces", 3, 300,
    ),
    "ply of 255-gons: 12 M triangles": ("mesh", "m.ply", lambda: ply_255_gons(48_000), {}, 413, "12,144,000 faces", 15, 1500),
    "obj of 20,000 materials": (
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"".join(b"usemtl m%d\nf 1 2 3\n" % i for i in range(20_000)),
        {}, 413, "20,000 parts", 2, 50,
    ),
    "gltf placing 20,000 triangles": ("mesh", "m.gltf", lambda: gltf_placed(20_000), {}, 413, "20,000 parts", 2, 100),
    "obj of 300,000 copies of a triangle": (  # simplified to nothing: was a 500
        "mesh", "m.obj", lambda: OBJ_TRIANGLE + b"f 1 2 3\n" * 300_000, {}, 422, "left none", 5, 300,
    ),
    "mesh body of 51 MB": ("mesh", "m.stl", lambda: b"\0" * 51_000_000, {}, 413, "body over the limit", 3, 200),
    "ply with a NaN vertex": ("mesh", "m.ply", lambda: NAN_PLY, {}, 422, "NaN or infinite", 2, 50),
    "obj with an infinite vertex": ("mesh", "m.obj", lambda: OBJ_TRIANGLE + b"v 0 inf 0\nf 1 2 3\nf 2 3 4\n", {}, 422, "NaN or infinite", 2, 50),
    "stl with a NaN vertex": ("mesh", "m.stl", lambda: stl_binary(100, np.nan), {}, 422, "NaN or infinite", 2, 50),
    "obj 1e300 mm across": (
        "mesh", "m.obj", lambda: b"v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
        {}, 422, "across", 2, 50,
    ),
    "glb whose json chunk claims 2 GB": ("mesh", "m.glb", glb_chunk_length_lie, {}, 422, "not a readable GLB", 2, 50),
    "glb whose faces point past its vertices": ("mesh", "m.glb", glb_index_outside, {}, 422, "do not exist", 2, 50),
    "glb whose accessors claim 2e9 items": ("mesh", "m.glb", glb_accessor_lie, {}, 413, "666,666,666 faces", 2, 50),
}  # fmt: skip


@pytest.fixture(scope="module")
def server(tmp_path_factory, posedesc_models):
    data_dir = tmp_path_factory.mktemp("hostile") / "data"
    with Server(data_dir, posedesc_models, env={"POSEDESC_LEVEL": "1"}) as s:
        s.wait_ready()
        with httpx.Client(base_url=s.url, timeout=120) as c:  # warm up: sessions, first allocations
            assert c.post(
                "/recognize", files={"rgb": ("p.png", png(np.zeros((64, 64, 3), np.uint8)))}
            ).is_success
        yield s
        assert "Traceback" not in s.log.read_text()


def reset_peak(server: Server) -> float:
    """Resets the server's peak resident memory to its current one (Linux: clear_refs 5); returns it."""
    Path(f"/proc/{server.proc.pid}/clear_refs").write_text("5")
    return server.memory_mb()[1]


def send(url: str, field: str, filename: str, content: bytes, data: dict[str, str]) -> httpx.Response:
    endpoint = "/objects" if field == "mesh" else "/recognize"
    data = {"name": "hostile", **data} if field == "mesh" else data
    with httpx.Client(base_url=url, timeout=120) as c:
        return c.post(endpoint, files={field: (filename, content)}, data=data)


@pytest.mark.parametrize("case", list(CASES))
def test_hostile_upload_is_refused_quickly_in_bounded_memory(server, case):
    field, filename, make, data, status, words, seconds, megabytes = CASES[case]
    content = make()
    before = reset_peak(server)
    t0 = time.perf_counter()
    r = send(server.url, field, filename, content, data)
    took = time.perf_counter() - t0
    grew = server.memory_mb()[1] - before
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == "application/json"
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and words in detail, detail
    assert took < seconds, f"{took:.1f} s"
    assert grew < megabytes, f"peak memory grew by {grew:.0f} MB"
    assert server.proc.poll() is None


def test_concurrent_bombs_are_parsed_one_at_a_time(server):
    """Three 12 M-triangle PLYs and six 4096 x 4096 depth images at once: meshes are parsed one at a
    time (each ~1.1 GB, freed before the next) and images decoded two at a time (~0.2 GB each), so the
    peak is about one parse and two decodes, not the sum of all of them (4.5 GB)."""
    bomb, big_depth = ply_255_gons(48_000), depth_png(np.zeros((4096, 4096)))
    uploads = [("mesh", "m.ply", bomb)] * 3 + [("depth", "d.png", big_depth)] * 6
    statuses: list[int] = []
    before = reset_peak(server)
    threads = [
        threading.Thread(target=lambda u=u: statuses.append(send(server.url, *u, {}).status_code))
        for u in uploads
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    grew = server.memory_mb()[1] - before
    assert sorted(statuses) == [413] * 3 + [422] * 6
    assert grew < 2000, f"peak memory grew by {grew:.0f} MB"
    with httpx.Client(base_url=server.url, timeout=60) as c:  # and the service still serves
        assert c.get("/readyz").status_code == 200
