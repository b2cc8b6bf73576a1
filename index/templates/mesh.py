"""Loading a user's mesh: any format of `MESH_FORMATS`, in mm, checked, and simplified when too heavy;
refused when too large to load safely (`max_input_faces`, see `index/templates/mesh_limits.py`) or, when asked,
when its units make an object of a size not registered, or are doubtful (`check_size`, see `index/geometry/units.py`)."""

from __future__ import annotations

import io
import json
import logging
import re
import threading
import weakref
from functools import partial
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from index.geometry.units import UNIT_SCALE, UNITS, size_problem
from index.templates import mesh_limits

log = logging.getLogger(__name__)

MESH_FORMATS = ("ply", "obj", "stl", "off", "glb", "gltf")
# The formats as every message, help text and doc names them. An upload is one file: a glTF's buffers and
# images must be inside it (data URIs); GLB always is.
FORMATS_TEXT = "PLY, OBJ, STL, OFF, GLB or glTF (self-contained: buffers and images as data URIs)"
MAX_SIZE_MM = 1e6  # a kilometre: larger is a units mistake, or coordinates that overflow the renderer


class MeshError(ValueError):
    """A mesh that cannot be used; the message says why, in one line."""


class MeshTooLarge(MeshError):
    """A mesh with more triangles (or parts) than the caller accepts."""


def load_mesh(
    source: str | Path | bytes,
    units: str | None = "mm",
    file_type: str | None = None,
    max_faces: int | None = 200_000,
    max_input_faces: int | None = None,
    check_size: bool = False,
) -> trimesh.Trimesh:
    """One triangle mesh in millimetres from a path or bytes (`file_type` needed for bytes).

    Multi-part files (OBJ groups, GLB scenes) are merged with their colours and textures baked to
    vertex colours where the parts differ. A mesh over `max_faces` is simplified to it; one over
    `max_input_faces` (or `mesh_limits.MAX_PARTS`) raises MeshTooLarge, before parsing when it can.
    `units` None: not given, read as mm. With `check_size`, an object whose diameter is not registered,
    or whose units are doubtful, raises MeshError saying which units would make it fit
    (`index.geometry.units.size_problem`)."""
    if units is not None and units not in UNIT_SCALE:
        raise MeshError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise MeshError(f"no such file: {path}")
        file_type = file_type or path.suffix.lstrip(".").lower()
        data = path.read_bytes()
    else:
        data = source
    file_type = (file_type or "").lower()
    if file_type not in MESH_FORMATS:
        raise MeshError(f"unsupported mesh format {file_type!r}; use {FORMATS_TEXT}")
    if file_type == "gltf":
        _self_contained(data)
    if file_type == "ply":
        _whole_ply(data)
    if max_input_faces is not None:
        _refuse(mesh_limits.declared(data, file_type), max_input_faces, "declares")
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=file_type, process=False)
        if max_input_faces is not None:
            _refuse(mesh_limits.parsed(loaded), max_input_faces, "holds")
        mesh = _as_single_mesh(loaded)
        _check(mesh)
        mesh = _renderable(_face_colours_to_corners(mesh))
    except MeshError:
        raise
    except Exception as e:  # trimesh raises anything from KeyError to struct.error on garbage
        raise MeshError(f"not a readable {file_type.upper()} mesh ({type(e).__name__}: {e})") from None
    mesh.apply_scale(UNIT_SCALE[units or "mm"])
    size = float(np.ptp(mesh.vertices, axis=0).max())
    if not size <= MAX_SIZE_MM:
        raise MeshError(f"the mesh is {size:.3g} mm across, over {MAX_SIZE_MM:g}: check its units")
    if max_faces is not None and len(mesh.faces) > max_faces:
        mesh = simplify(mesh, max_faces)
        if len(mesh.faces) == 0:  # e.g. a million copies of one triangle
            raise MeshError(f"simplifying it to {max_faces:,} faces left none: its faces are degenerate")
    if check_size and (problem := size_problem(diameter(mesh), units)):
        raise MeshError(problem)
    return mesh


def _whole_ply(data: bytes) -> None:
    """A PLY cut short, said so before trimesh trips on it (a `KeyError: 'y'` of a header cut between its
    properties, a mesh "with no faces" of an ASCII body cut in half): the header must end (`end_header`),
    and an ASCII body must hold a line for each vertex and face it declares. A binary body's length is
    trimesh's own check ("PLY is unexpected length")."""
    if not data.startswith(b"ply"):
        return  # not a PLY at all: trimesh says what it is not
    end = data.find(b"end_header")
    if end < 0:
        raise MeshError("the PLY is cut short: its header never ends (no end_header); send the whole file")
    header = data[:end].decode("ascii", "replace")
    if "format ascii" not in header:
        return
    counts = [(m.group(1), int(m.group(2))) for m in re.finditer(r"^element\s+(\S+)\s+(\d+)", header, re.M)]
    declared = sum(n for _, n in counts)
    lines = sum(1 for line in data[end:].splitlines()[1:] if line.strip())
    if lines < declared:
        what = ", ".join(f"{name} {n:,}" for name, n in counts)
        raise MeshError(
            f"the PLY is cut short: its header declares {what} ({declared:,} lines), its body holds "
            f"{lines:,}; send the whole file"
        )


def _self_contained(data: bytes) -> None:
    """A glTF upload cannot bring the files its JSON points at: say so, not what trimesh trips on."""
    try:
        doc = json.loads(data)
    except Exception:  # not JSON: trimesh says what is wrong
        return
    if not isinstance(doc, dict):
        return
    for kind in ("buffers", "images"):
        for item in doc.get(kind) or ():
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                raise MeshError(
                    f"the glTF's {kind[:-1]} {uri[:80]!r} is a separate file: send a GLB, or a glTF with "
                    "its buffers and images embedded as data URIs"
                )


def _refuse(size: mesh_limits.Size, max_faces: int, verb: str) -> None:
    if (why := mesh_limits.too_large(size, max_faces, verb)) is not None:
        raise MeshTooLarge(why)


def _as_single_mesh(loaded: object) -> trimesh.Trimesh:
    if isinstance(loaded, trimesh.Scene):
        for g in loaded.geometry.values():  # before dump(), which reads colours through the faces
            if isinstance(g, trimesh.Trimesh):
                _check_indices(g)
        parts = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not parts:
            raise MeshError("the file holds no triangles")
        if len(parts) == 1:
            return parts[0]
        for p in parts:  # mixed textures cannot be merged: bake each part to vertex colours first
            if isinstance(p.visual, trimesh.visual.TextureVisuals):
                p.visual = _baked(p)
        merged = trimesh.util.concatenate(parts)
        assert isinstance(merged, trimesh.Trimesh)  # meshes concatenate to a mesh
        return merged
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"the file holds a {type(loaded).__name__}, not a triangle mesh")
    return loaded


#: the texture images' modes the renderer takes; others are converted (`_renderable`)
TEXTURE_MODES = ("RGB", "RGBA")
#: where trimesh's materials keep their images (a glTF's PBR material, an OBJ's simple one)
TEXTURE_FIELDS = (
    "baseColorTexture",
    "metallicRoughnessTexture",
    "normalTexture",
    "occlusionTexture",
    "emissiveTexture",
    "image",
)


def _placed(visual: trimesh.visual.TextureVisuals, n: int) -> bool:
    """Whether a texture has a finite (u, v) for each of the mesh's `n` vertices: else it cannot be placed."""
    uv = visual.uv
    return uv is not None and np.shape(uv) == (n, 2) and bool(np.isfinite(uv).all())


def _baked(mesh: trimesh.Trimesh) -> trimesh.visual.ColorVisuals:
    """A textured mesh's colours per vertex: its texture's where it can be placed, its material's one colour
    where it cannot (a glTF primitive without texture coordinates: trimesh gives a single colour for the
    whole part, which merged with other parts gave fewer colours than vertices, and a registration's 500)."""
    visual = mesh.visual
    assert isinstance(visual, trimesh.visual.TextureVisuals)
    if _placed(visual, len(mesh.vertices)):
        _convert_images(visual.material)
        return visual.to_color()
    colour = np.asarray(visual.to_color().vertex_colors, np.uint8).reshape(-1, 4)[:1]
    return trimesh.visual.ColorVisuals(mesh, vertex_colors=np.repeat(colour, len(mesh.vertices), axis=0))


def _renderable(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """`mesh` with colours the renderer takes: a texture that cannot be placed baked to its material's colour,
    texture images of other modes (grey with alpha, 1-bit, palette, 16-bit, float) converted to 8-bit RGB(A).
    Unconverted, a grey-and-alpha or 1-bit texture made the renderer raise during a registration (a 500)."""
    if isinstance(mesh.visual, trimesh.visual.TextureVisuals):
        if _placed(mesh.visual, len(mesh.vertices)):
            _convert_images(mesh.visual.material)
        else:
            mesh.visual = _baked(mesh)
    return mesh


def _convert_images(material: object) -> None:
    """Every texture image of `material` as 8-bit RGB, or RGBA where it has transparency, in place."""
    for name in TEXTURE_FIELDS:
        image = getattr(material, name, None)
        if isinstance(image, Image.Image) and image.mode not in TEXTURE_MODES:
            setattr(material, name, _eight_bit(image))


def _eight_bit(image: Image.Image) -> Image.Image:
    """`image` as 8-bit RGB or RGBA: high-bit-depth greys scaled to their range's 0-255, not clipped."""
    if image.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        values = np.asarray(image, np.float64)
        top = 1.0 if image.mode == "F" else 65535.0
        grey = np.clip(np.nan_to_num(values / top) * 255.0, 0, 255).astype(np.uint8)
        return Image.fromarray(grey).convert("RGB")  # 2-D uint8: mode L
    alpha = "A" in image.mode or "a" in image.mode or "transparency" in image.info
    return image.convert("RGBA" if alpha else "RGB")


def _face_colours_to_corners(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A mesh coloured per face (a PLY's face colours, for one) as one coloured per vertex: each vertex split
    into one per colour of the faces that meet there, so every face keeps its own colour and a region of one
    colour stays one surface. The renderer shades by vertex (a mesh with face colours was refused by it, a
    registration's 500), and averaging the faces' colours at shared vertices would blur a box of six coloured
    sides to one grey."""
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.ColorVisuals) or visual.kind != "face":
        return mesh
    colours = np.asarray(visual.face_colors, np.uint8)
    corners = np.column_stack([mesh.faces.reshape(-1), np.repeat(colours, 3, axis=0)])
    kept, faces = np.unique(corners, axis=0, return_inverse=True)
    return trimesh.Trimesh(
        mesh.vertices[kept[:, 0]],
        np.asarray(faces).reshape(-1, 3),
        vertex_colors=kept[:, 1:].astype(np.uint8),
        process=False,
    )


def _check(mesh: trimesh.Trimesh) -> None:
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise MeshError("the mesh is empty: no faces")
    if mesh.vertices.shape[1:] != (3,) or mesh.faces.shape[1:] != (3,):
        raise MeshError(f"vertices {mesh.vertices.shape} and faces {mesh.faces.shape} are not (N, 3)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError("the mesh has NaN or infinite vertex coordinates")
    _check_indices(mesh)
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    if np.sort(extent)[-2] <= 0 or mesh.area <= 0:
        raise MeshError("the mesh is degenerate: it has no area (all points on a line or a point)")


def _check_indices(mesh: trimesh.Trimesh) -> None:
    if len(mesh.faces) and (mesh.faces.max() >= len(mesh.vertices) or mesh.faces.min() < 0):
        raise MeshError("the mesh's faces point at vertices that do not exist")


#: one decimation at a time in the process: the library (fast_simplification, through trimesh) keeps the mesh
#: it works on in process-wide memory, loaded, decimated and read back in separate calls, so that two threads
#: decimating at once (a registration, the pose fit's warm-up, a detection's masks) took each other's
#: meshes: the same frames gave colour detection recall 53-70 % by the threads' timing (docs/experiments.md)
_DECIMATING = threading.Lock()


def simplify(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Quadric decimation to at most `max_faces`, colours carried over from the nearest old vertex."""
    with _DECIMATING:
        simple = mesh.simplify_quadric_decimation(face_count=max_faces)
    visual = mesh.visual
    colors = None
    if isinstance(visual, trimesh.visual.TextureVisuals):
        colors = visual.to_color().vertex_colors
    elif isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        colors = visual.vertex_colors
    if colors is not None:
        _, nearest = cKDTree(mesh.vertices).query(simple.vertices)
        simple.visual = trimesh.visual.ColorVisuals(simple, vertex_colors=colors[nearest])
    log.info("simplified mesh from %d to %d faces", len(mesh.faces), len(simple.faces))
    return simple


_EXACT = 6000  # hull vertices measured pair by pair


#: the diameters measured, by mesh (its id, a weak reference to it and the hash of its data when measured):
#: a service's upload is measured when parsed (its units are checked) and again when registered, 0.1-0.3 s
#: each time for a 20k-face mesh on 2 busy cores
_measured: dict[int, tuple[weakref.ref, int, float]] = {}


def diameter(mesh: trimesh.Trimesh) -> float:
    """Largest distance between two vertices of the convex hull, mm (BOP's `diameter`); measured once per
    mesh while its vertices and faces stay the same (trimesh's hash of them says so).

    Exact over up to `_EXACT` hull vertices, in blocks (|a|^2 + |b|^2 - 2ab, centred, float64; each pair
    once): 0.03 s for a 20k-face mesh's 3,485, where a full difference tensor took 0.1-0.7 s on a
    registration's request path.
    More hull vertices than that are first cut to the extremes along 500 directions: a lower bound, exact
    when the farthest pair is among them (a 40,962-vertex sphere's diameter came out exact)."""
    key, data = id(mesh), hash(mesh)
    seen = _measured.get(key)
    if seen is not None and seen[0]() is mesh and seen[1] == data:
        return seen[2]
    size = _diameter(mesh)
    _measured[key] = (weakref.ref(mesh, partial(_forget, key)), data, size)
    return size


def _forget(key: int, _: weakref.ref) -> None:
    _measured.pop(key, None)


def _diameter(mesh: trimesh.Trimesh) -> float:
    try:
        pts = np.asarray(mesh.convex_hull.vertices, np.float64)
    except Exception:  # qhull fails on flat meshes
        pts = np.asarray(mesh.vertices, np.float64)
    pts = pts - pts.mean(axis=0)
    if len(pts) > _EXACT:
        dirs = np.random.default_rng(0).normal(size=(500, 3))
        proj = pts @ dirs.T
        pts = pts[np.unique(np.concatenate([proj.argmax(0), proj.argmin(0)]))]
    sq = (pts**2).sum(axis=1)
    best = 0.0
    for i in range(0, len(pts), 1024):  # each pair once: a block against itself and what follows it
        d2 = sq[i : i + 1024, None] + sq[None, i:] - 2.0 * (pts[i : i + 1024] @ pts[i:].T)
        best = max(best, float(d2.max()))
    return float(np.sqrt(best))
