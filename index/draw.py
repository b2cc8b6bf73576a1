"""Answers drawn over the image they answer: each object's silhouette at its pose, tinted and outlined, its
axes and a label (name and confidence). Pure numpy and OpenCV, no GL: the renderer's one thread belongs to
registration (`index.templates.render.RenderWorker`), and a drawing must never wait behind a registration.

The silhouette is every projected triangle filled on a mask (no z-buffer: a silhouette is the union of all
faces, front or back), cut to `MAX_DRAW_FACES` faces first. Poses are BOP's (`R`, `t` model to camera,
OpenCV axes, mm) with OpenCV intrinsics `K`: pixel (i, j) is centred on the integer coordinates, as
`index.templates.render.Renderer.render_frame` renders."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

import cv2
import numpy as np
import trimesh

from index.features.patches import PatchSpec, patch_camera
from index.templates.mesh import diameter, load_mesh, simplify

#: faces projected per object: a 20k-face silhouette is filled in ~0.1 s on one core and shows the outline
#: of a 640 x 480 frame's object as the full mesh does (LM-O's meshes hold 5k-40k faces)
MAX_DRAW_FACES = 20_000
#: faces of the mesh a whole-frame detection's mask is the silhouette of (`service.detection.mask`): LM-O's
#: meshes cut to 3,000 give 0.99 IoU or more with their drawing meshes' silhouettes, 4-6 times sooner
MASK_FACES = 3_000
#: vertices nearer than this (mm, in front of the camera) are not projected: a face reaching behind the
#: camera has no image, and near 0 its projection leaves any integer range
NEAR_MM = 1.0
#: projected coordinates beyond this (px) are dropped: OpenCV draws in fixed point (int32 after the shift)
FAR_PX = 1e6
SHIFT = 4  # sub-pixel bits of the filled triangles: vertices at 1/16 px
TINT_ALPHA = 0.4  # how much of the answer's colour covers the image on its silhouette
#: answers' colours (RGB), in their order: the best first
PALETTE = ((255, 190, 0), (0, 200, 255), (255, 60, 200), (120, 255, 60), (255, 120, 40), (160, 120, 255))
REJECTED_RGB = (170, 170, 170)  # an answer the open-set verdict refused: grey, dashed, "unknown?"
AXIS_RGB = ((255, 0, 0), (0, 255, 0), (0, 80, 255))  # x red, y green, z blue
DASH_PX = 8  # dashes (and gaps) of a rejected answer's outline, in contour pixels
PATCH_DRAW_PX = 256  # a patch (64 px) is drawn on this many pixels: its labels need the room


@dataclass(frozen=True)
class DrawMesh:
    """A mesh as the drawing takes it: `vertices` (N, 3) mm, `faces` (F, 3), `diameter` mm."""

    vertices: np.ndarray
    faces: np.ndarray
    diameter: float

    @classmethod
    def of(cls, mesh: trimesh.Trimesh, max_faces: int = MAX_DRAW_FACES) -> DrawMesh:
        if len(mesh.faces) > max_faces:
            mesh = simplify(mesh, max_faces)
        return cls(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), diameter(mesh))

    def coarse(self, max_faces: int) -> DrawMesh:
        """This mesh cut to at most `max_faces` faces (itself when it has no more)."""
        if len(self.faces) <= max_faces:
            return self
        return DrawMesh.of(trimesh.Trimesh(self.vertices, self.faces, process=False), max_faces)

    @classmethod
    def from_glb(cls, glb: bytes | None) -> DrawMesh | None:
        """From a stored mesh (GLB, mm, as registration keeps it: `index.templates.register`); None for none."""
        return None if glb is None else cls.of(load_mesh(glb, file_type="glb", max_faces=None))

    @classmethod
    def as_stored(cls, mesh: trimesh.Trimesh) -> DrawMesh:
        """What `from_glb` makes of the GLB a registration stores of `mesh`, without writing and reading it
        (0.2 s of a 20k-face mesh's 0.6 s): GLB keeps its vertices as float32, its faces as they are."""
        vertices = np.asarray(mesh.vertices, np.float32).astype(np.float64)
        return cls.of(trimesh.Trimesh(vertices, np.asarray(mesh.faces), process=False))


@dataclass(frozen=True)
class Drawn:
    """One answer to draw: its object's name, `confidence` (None: not calibrated), pose `R` (3, 3) and
    `t` (3,) mm in the image's camera; `rejected`: the open-set verdict refused it (drawn as "unknown?")."""

    name: str
    confidence: float | None
    R: np.ndarray
    t: np.ndarray
    rejected: bool = False

    @property
    def label(self) -> str:
        conf = "" if self.confidence is None else f"  conf {self.confidence:.2f}"
        return f"unknown? {self.name}{conf}" if self.rejected else f"{self.name}{conf}"


def project(points: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of model points (N, 3) at pose (R, t) and their depths (N,) mm (≤ 0: behind)."""
    cam = points @ np.asarray(R, float).T + np.ravel(t)
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam @ np.asarray(K, float).T)[:, :2] / z[:, None]
    return uv, z


def silhouette(
    mesh: DrawMesh, R: np.ndarray, t: np.ndarray, K: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """The mesh's silhouette at (R, t) in an image of `shape` (H, W): uint8 mask, 255 on the object.
    Faces reaching behind the camera are left out; the rest are clipped to the image."""
    mask = np.zeros(shape, np.uint8)
    uv, z = project(mesh.vertices, R, t, K)
    tri, depth = uv[mesh.faces], z[mesh.faces]
    keep = (depth > NEAR_MM).all(axis=1) & (np.abs(tri) < FAR_PX).all(axis=(1, 2))
    h, w = shape
    tri = tri[keep]
    # only faces touching the image: those wholly to one side of it cannot show
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    tri = tri[(hi[:, 0] >= -1) & (lo[:, 0] <= w) & (hi[:, 1] >= -1) & (lo[:, 1] <= h)]
    fixed = np.round(tri * (1 << SHIFT)).astype(np.int32)
    # one call per face: fillPoly given many polygons fills by parity, so overlapping faces would cancel
    for face in fixed:
        cv2.fillConvexPoly(mask, face, 255, lineType=cv2.LINE_8, shift=SHIFT)
    return mask


def draw_answers(image: np.ndarray, answers: Sequence[tuple[DrawMesh, Drawn]], K: np.ndarray) -> np.ndarray:
    """`image` (H, W, 3) uint8 RGB with each answer drawn at its pose in `PALETTE`'s colours, the first on
    top (drawn last), then the labels, the first placed first, each moved down past those placed; an
    answer behind the camera is skipped. Returns a new image."""
    out = np.ascontiguousarray(image, np.uint8).copy()
    colours = [REJECTED_RGB if a.rejected else PALETTE[i % len(PALETTE)] for i, (_, a) in enumerate(answers)]
    anchors = [
        draw_answer(out, mesh, a, K, colours[i]) for i, (mesh, a) in reversed(list(enumerate(answers)))
    ]
    taken: list[tuple[int, int, int, int]] = []
    for (_, a), colour, anchor in zip(answers, colours, reversed(anchors), strict=True):
        if anchor is not None:
            taken.append(draw_label(out, a.label, anchor, colour, taken))
    return out


def draw_answer(
    image: np.ndarray, mesh: DrawMesh, a: Drawn, K: np.ndarray, colour: tuple[int, int, int]
) -> tuple[int, int] | None:
    """One answer's silhouette and axes, drawn into `image` (H, W, 3) uint8 in place; returns where its
    label goes (the silhouette's top left; None: nothing drawn, its origin behind the camera)."""
    if float(np.ravel(a.t)[2]) <= NEAR_MM:
        return None
    mask = silhouette(mesh, a.R, a.t, K, image.shape[:2])
    on = mask > 0
    tint = np.array(colour, np.float32)
    image[on] = np.round(image[on] * (1 - TINT_ALPHA) + tint * TINT_ALPHA).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if a.rejected:
        for c in contours:
            for start in range(0, len(c), 2 * DASH_PX):
                cv2.polylines(image, [c[start : start + DASH_PX]], False, colour, 2, cv2.LINE_AA)
    else:
        cv2.drawContours(image, contours, -1, colour, 2, cv2.LINE_AA)
    origin = draw_axes(image, a.R, a.t, K, mesh.diameter / 2)
    ys, xs = np.nonzero(mask)
    return (int(xs.min()), int(ys.min())) if xs.size else origin


def draw_axes(
    image: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, length_mm: float
) -> tuple[int, int] | None:
    """The object's x, y, z axes (red, green, blue) from its origin, `length_mm` long; returns the
    origin's pixel (None when it projects nowhere drawable). An axis whose end is behind the camera is
    left out."""
    ends = np.vstack([np.zeros(3), np.eye(3) * length_mm])
    uv, z = project(ends, R, t, K)
    if z[0] <= NEAR_MM or not (np.abs(uv[0]) < FAR_PX).all():
        return None
    o = (int(round(uv[0, 0])), int(round(uv[0, 1])))
    # z last: it is the axis most often pointing at the camera, so drawn over the others
    for i in (1, 2, 3):
        if z[i] > NEAR_MM and (np.abs(uv[i]) < FAR_PX).all():
            end = (int(round(uv[i, 0])), int(round(uv[i, 1])))
            cv2.line(image, o, end, AXIS_RGB[i - 1], 2, cv2.LINE_AA)
    cv2.circle(image, o, 3, (255, 255, 255), -1, cv2.LINE_AA)
    return o


def draw_label(
    image: np.ndarray,
    text: str,
    anchor: tuple[int, int],
    colour: tuple[int, int, int],
    taken: Sequence[tuple[int, int, int, int]] = (),
) -> tuple[int, int, int, int]:
    """`text` on a dark box just above `anchor` (x, y), kept inside the image and moved down past the
    boxes in `taken` (x0, y0, x1, y1) it would cover; returns its own box."""
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1
    (tw, th), base = cv2.getTextSize(text, font, scale, thick)
    h, w = image.shape[:2]
    x = int(np.clip(anchor[0], 0, max(0, w - tw - 4)))
    y = int(np.clip(anchor[1] - 6, th + 4, max(th + 4, h - base - 2)))
    for _ in range(len(taken)):  # each move clears one box at least
        hit = [b for b in taken if b[0] < x + tw + 4 and x < b[2] and b[1] < y + base and y - th - 4 < b[3]]
        if not hit:
            break
        y = min(max(b[3] for b in hit) + th + 5, max(th + 4, h - base - 2))
    box = (x, y - th - 4, x + tw + 4, y + base)
    cv2.rectangle(image, box[:2], box[2:], (20, 20, 20), -1)
    cv2.putText(image, text, (x + 2, y - 2), font, scale, colour, thick, cv2.LINE_AA)
    return box


def patch_view(patch: np.ndarray, spec: PatchSpec, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """A patch (square, any size) upscaled to `PATCH_DRAW_PX` and the intrinsics its answers are drawn
    with: the patch camera (`index.features.patches.patch_camera`, the answers' camera) at the same scale."""
    s = PATCH_DRAW_PX
    big = cv2.resize(patch, (s, s), interpolation=cv2.INTER_LINEAR if patch.shape[0] < s else cv2.INTER_AREA)
    scale = s / spec.size
    K = patch_camera(spec, distance_mm).copy()
    K[:2, :2] *= scale
    K[:2, 2] = (K[:2, 2] + 0.5) * scale - 0.5  # pixel centres: i of the patch is (i + 0.5) * scale - 0.5
    return big, K


def grey_to_rgb(image: np.ndarray) -> np.ndarray:
    """A depth image (H, W) mm as a grey RGB picture to draw on: near bright, far dark, none black."""
    valid = image > 0
    out = np.zeros(image.shape, np.uint8)
    if valid.any():
        lo, hi = np.percentile(image[valid], [1, 99])
        out[valid] = np.clip(255 - (image[valid] - lo) / max(hi - lo, 1e-6) * 200, 40, 255).astype(np.uint8)
    return np.repeat(out[..., None], 3, axis=2)


T = TypeVar("T")


class MeshCache(Generic[T]):
    """Drawing meshes by object id (or what is made of them: the pose fit's models, `service.pipeline.fit`),
    loaded once (`load`: the id's, or None when it has none) and kept for the `capacity` most recently used
    (a 20k-face drawing mesh holds ~0.7 MB). `prune` forgets the ids
    no longer registered: ids are never reused (the stores count them up), so a deleted object's mesh is
    never drawn for another. Safe across threads; two threads missing the same id both load it."""

    def __init__(self, load: Callable[[int], T | None], capacity: int = 32):
        self._load, self._capacity = load, capacity
        self._meshes: OrderedDict[int, T | None] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, object_id: int) -> T | None:
        with self._lock:
            if object_id in self._meshes:
                self._meshes.move_to_end(object_id)
                return self._meshes[object_id]
        mesh = self._load(object_id)  # outside the lock: the other thread's drawing need not wait for it
        self.put(object_id, mesh)
        return mesh

    def put(self, object_id: int, mesh: T | None) -> None:
        """Keeps `mesh` as the id's (made by the caller: `load` would make the same)."""
        with self._lock:
            self._meshes[object_id] = mesh
            self._meshes.move_to_end(object_id)
            while len(self._meshes) > self._capacity:
                self._meshes.popitem(last=False)

    def prune(self, registered: Collection[int]) -> None:
        with self._lock:
            for oid in [o for o in self._meshes if o not in registered]:
                del self._meshes[oid]

    def __contains__(self, object_id: int) -> bool:
        with self._lock:
            return object_id in self._meshes
