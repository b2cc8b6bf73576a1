"""How big a mesh file is, in triangles and parts, before anything costly is done with it.

A hostile file can make the loader use far more memory and time than its size: 48 MB of `f 1 2 3`
lines is six million OBJ faces (2 GB and 14 s through trimesh, the checks and the simplification);
49 MB of PLY 255-gons is twelve million triangles (4.6 GB, 55 s); a 10 MB glTF that places one triangle
on 200,000 nodes takes 120 s to merge, and 100 kB of OBJ switching between 5,000 materials takes trimesh
8 s to parse (it grows with the square). `index.templates.mesh.load_mesh(max_input_faces=...)` refuses such
files: before parsing, from what the file declares (`declared`: PLY and OFF headers, binary STL's size,
ASCII STL's and OBJ's face records and materials, glTF's nodes and accessors), and right after parsing,
before merging, checking or simplifying, from what the parser found (`parsed`: polygons and instances
show only then).
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass

import trimesh

# Parts cost more than linearly: merging 20,000 glTF nodes takes 6 s, parsing 1,000 OBJ materials 0.5 s.
MAX_PARTS = 1000


@dataclass(frozen=True)
class Size:
    faces: int  # triangles
    parts: int = 1  # meshes placed in the scene, instances counted


def declared(data: bytes, file_type: str) -> Size:
    """What the file says it holds, read without parsing it; 0 faces when it does not say, or is not
    what it claims to be (the parser will tell)."""
    head = data[:65536]
    if file_type == "ply":
        m = re.search(rb"^element\s+face\s+(\d+)", head[: head.find(b"end_header")], re.M)
        return Size(int(m.group(1)) if m else 0)
    if file_type == "off":  # "OFF" (or COFF, NOFF...), comments, then "vertices faces edges"
        tokens = re.sub(rb"#[^\n]*", b"", head).split()[:3]
        ok = len(tokens) == 3 and tokens[0].endswith(b"OFF") and tokens[2].isdigit()
        return Size(int(tokens[2]) if ok else 0)
    if file_type == "stl":
        if head.lstrip().startswith(b"solid") and b"facet" in head[:4096]:
            return Size(data.count(b"endfacet"))
        if len(data) < 84:
            return Size(0)
        (n,) = struct.unpack_from("<I", data, 80)
        return Size(min(n, (len(data) - 84) // 50))  # 50 bytes a triangle
    if file_type == "obj":  # every face line is at least one triangle; every material a part
        lines = sum(data.count(b"\n" + start) for start in (b"f ", b"f\t"))
        materials = set(re.findall(rb"^[ \t]*usemtl[ \t]+(\S+)", data, re.M))
        return Size(lines + data.startswith((b"f ", b"f\t")), max(1, len(materials)))
    if file_type in ("glb", "gltf"):
        return _gltf(data, file_type)
    return Size(0)


def _gltf(data: bytes, file_type: str) -> Size:
    try:
        if file_type == "glb":  # 12-byte header, then the JSON chunk: length, type, content
            (length,) = struct.unpack_from("<I", data, 12)
            doc = json.loads(data[20 : 20 + length])
        else:
            doc = json.loads(data)
        accessors = doc.get("accessors", [])

        def triangles(prim: dict) -> int:
            acc = prim["indices"] if "indices" in prim else prim["attributes"]["POSITION"]
            return int(accessors[acc]["count"]) // 3

        meshes = [[triangles(p) for p in m.get("primitives", [])] for m in doc.get("meshes", [])]
        placed = [meshes[n["mesh"]] for n in doc.get("nodes", []) if "mesh" in n]  # a node has one parent
        return Size(sum(map(sum, placed)), sum(map(len, placed)))
    except Exception:  # not JSON, not glTF: trimesh says what is wrong
        return Size(0)


def parsed(loaded: object) -> Size:
    """What the parser found, each placement of a scene's geometry counted."""
    if isinstance(loaded, trimesh.Scene):
        placed = [
            (len(nodes), len(getattr(loaded.geometry.get(name), "faces", ())))
            for name, nodes in loaded.graph.geometry_nodes.items()
        ]
        return Size(sum(n * f for n, f in placed), sum(n for n, _ in placed))
    return Size(len(getattr(loaded, "faces", ())))


def too_large(size: Size, max_faces: int, verb: str) -> str | None:
    """Why a file of this size is refused (`verb`: declares or holds), or None."""
    if size.faces > max_faces:
        return (
            f"the file {verb} {size.faces:,} faces, over the limit of {max_faces:,}; simplify it first "
            "(e.g. quadric edge collapse in MeshLab, Decimate in Blender)"
        )
    if size.parts > MAX_PARTS:
        return f"the file {verb} {size.parts:,} parts, over the limit of {MAX_PARTS:,}; merge them first"
    return None
