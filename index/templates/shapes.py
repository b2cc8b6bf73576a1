"""Procedural objects: random compositions of primitives with coloured, textured parts, in mm.

Training mixes many of these with the real meshes so that the network learns to tell views of objects
in general, not of the few it was trained on (the service registers meshes it never saw). They are
sized like LineMOD objects (diameter 80-300 mm), centred on their bounding box, and carry vertex
colours: a colour per part, some parts with a procedural texture (stripes, checks, blotches) baked in.
`demo_shapes` gives a few fixed ones for the service's built-in demo objects and for tests.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh

from index.templates.mesh import diameter

PRIMITIVES = ("box", "cylinder", "sphere", "capsule", "cone", "torus")
TEXTURES = ("plain", "stripes", "checks", "blotches", "gradient")


def _primitive(kind: str, rng: np.random.Generator, scale: float, thinnest: float = 0.35) -> trimesh.Trimesh:
    """One primitive about `scale` mm across (each side `thinnest` to 1 of it), fine enough for a texture
    baked to its vertices."""
    s = scale * rng.uniform(thinnest, 1.0, 3)
    if kind == "box":
        m = trimesh.creation.box(extents=s)
        m = m.subdivide().subdivide().subdivide()  # vertices for the texture
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=s[0] / 2, height=s[2], sections=24)
        m = m.subdivide().subdivide()
    elif kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=s[0] / 2)
        m.apply_scale([1.0, s[1] / s[0], s[2] / s[0]])  # an ellipsoid
    elif kind == "capsule":
        m = trimesh.creation.capsule(height=s[2], radius=s[0] / 3, count=[16, 16])
    elif kind == "cone":
        m = trimesh.creation.cone(radius=s[0] / 2, height=s[2], sections=24)
        m = m.subdivide().subdivide()
    elif kind == "torus":
        major = s[0] / 2
        m = trimesh.creation.torus(major_radius=major, minor_radius=major * rng.uniform(0.15, 0.4))
    else:
        raise ValueError(f"unknown primitive {kind!r}; use one of {PRIMITIVES}")
    return m


def _paint(mesh: trimesh.Trimesh, rng: np.random.Generator, texture: str) -> trimesh.Trimesh:
    """Bakes a colour or a two-colour procedural texture (in the part's own coordinates) to vertices."""
    base, other = rng.uniform(20, 235, 3), rng.uniform(20, 235, 3)
    v = mesh.vertices
    period = rng.uniform(8.0, 30.0)  # mm
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    if texture == "plain":
        t = np.zeros(len(v))
    elif texture == "stripes":
        t = (np.floor(v @ axis / period) % 2).astype(float)
    elif texture == "checks":
        t = (np.floor(v / period).sum(axis=1) % 2).astype(float)
    elif texture == "blotches":
        k = rng.normal(size=(3, 3)) / period
        phase = rng.uniform(0, 2 * np.pi, 3)
        t = (np.sin(v @ k + phase).sum(axis=1) > 0).astype(float)
    elif texture == "gradient":
        p = v @ axis
        t = (p - p.min()) / (np.ptp(p) + 1e-9)
    else:
        raise ValueError(f"unknown texture {texture!r}; use one of {TEXTURES}")
    rgb = base[None] * (1 - t[:, None]) + other[None] * t[:, None]
    colours = np.concatenate([rgb, np.full((len(v), 1), 255.0)], axis=1).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    return mesh


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    T = trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q))
    return T


def _normalise(mesh: trimesh.Trimesh, diameter_mm: float) -> trimesh.Trimesh:
    """Centres on the bounding box and scales to BOP's `diameter` of `diameter_mm`."""
    mesh.apply_translation(-mesh.bounding_box.centroid)
    mesh.apply_scale(diameter_mm / diameter(mesh))
    return mesh


def random_shape(
    rng: np.random.Generator, diameter_mm: tuple[float, float] = (80.0, 300.0), n_parts: int | None = None
) -> trimesh.Trimesh:
    """A random composition of 2-5 primitives (`n_parts` of them when given), each randomly placed, turned,
    coloured and textured. One part is a single solid (a box, a cylinder, an ellipsoid, a capsule) of random
    proportions: what most household objects are, and what a composition of several never is."""
    n = int(rng.integers(2, 6)) if n_parts is None else n_parts
    parts: list[trimesh.Trimesh] = []
    for i in range(n):
        kind = str(rng.choice(PRIMITIVES[:4] if i == 0 else PRIMITIVES))  # a solid body first
        # a single solid as thin as a marker (a sixth of its length) or as flat as a box of tea
        part = _primitive(kind, rng, 100.0 if i == 0 else 70.0, thinnest=0.15 if n == 1 else 0.35)
        part.apply_transform(_random_rotation(rng))
        if parts:  # centred on a point of the surface so far: one connected object
            anchor = trimesh.sample.sample_surface(parts[int(rng.integers(len(parts)))], 1, seed=rng)[0][0]
            part.apply_translation(anchor)
        texture = str(rng.choice(TEXTURES, p=[0.4, 0.15, 0.15, 0.15, 0.15]))
        parts.append(_paint(part, rng, texture))
    mesh = trimesh.util.concatenate(parts)
    assert isinstance(mesh, trimesh.Trimesh)  # meshes concatenate to a mesh
    return _normalise(mesh, float(rng.uniform(*diameter_mm)))


def _fixed(
    build: Callable[[], list[tuple[trimesh.Trimesh, tuple[int, int, int]]]], diameter: float
) -> trimesh.Trimesh:
    parts = []
    for mesh, rgb in build():
        mesh.visual = trimesh.visual.ColorVisuals(
            mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)).astype(np.uint8)
        )
        parts.append(mesh)
    merged = trimesh.util.concatenate(parts)
    assert isinstance(merged, trimesh.Trimesh)
    return _normalise(merged, diameter)


def _mug() -> list[tuple[trimesh.Trimesh, tuple[int, int, int]]]:
    body = trimesh.creation.cylinder(radius=40, height=95, sections=32)
    handle = trimesh.creation.torus(major_radius=28, minor_radius=7)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([45, 0, 0])
    return [(body, (200, 60, 40)), (handle, (235, 220, 200))]


def _lamp() -> list[tuple[trimesh.Trimesh, tuple[int, int, int]]]:
    base = trimesh.creation.box(extents=[110, 70, 20])
    arm = trimesh.creation.capsule(height=120, radius=8)
    arm.apply_transform(trimesh.transformations.rotation_matrix(np.radians(25), [0, 1, 0]))
    arm.apply_translation([15, 0, 75])
    shade = trimesh.creation.cone(radius=38, height=50, sections=32)
    shade.apply_transform(trimesh.transformations.rotation_matrix(np.radians(160), [0, 1, 0]))
    shade.apply_translation([45, 0, 150])
    return [(base, (50, 50, 60)), (arm, (190, 190, 200)), (shade, (240, 200, 40))]


def _robot() -> list[tuple[trimesh.Trimesh, tuple[int, int, int]]]:
    torso = trimesh.creation.box(extents=[70, 45, 90])
    head = trimesh.creation.icosphere(subdivisions=3, radius=24)
    head.apply_translation([0, 0, 70])
    arm = trimesh.creation.cylinder(radius=9, height=80, sections=16)
    arm.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    arm.apply_translation([70, 0, 25])
    eye = trimesh.creation.box(extents=[30, 8, 8])
    eye.apply_translation([0, -24, 74])
    return [(torso, (40, 110, 200)), (head, (220, 220, 220)), (arm, (230, 120, 30)), (eye, (20, 200, 60))]


def _duck() -> list[tuple[trimesh.Trimesh, tuple[int, int, int]]]:
    body = trimesh.creation.icosphere(subdivisions=3, radius=50)
    body.apply_scale([1.3, 0.9, 0.8])
    head = trimesh.creation.icosphere(subdivisions=3, radius=28)
    head.apply_translation([45, 0, 55])
    beak = trimesh.creation.cone(radius=10, height=30, sections=16)
    beak.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    beak.apply_translation([68, 0, 55])
    return [(body, (245, 215, 40)), (head, (245, 215, 40)), (beak, (240, 110, 20))]


def demo_shapes() -> dict[str, trimesh.Trimesh]:
    """Four fixed, asymmetric, multi-coloured demo objects, 140-220 mm in diameter (same every call)."""
    return {
        "mug": _fixed(_mug, 140.0),
        "lamp": _fixed(_lamp, 220.0),
        "robot": _fixed(_robot, 180.0),
        "duck": _fixed(_duck, 150.0),
    }
