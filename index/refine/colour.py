"""The colour refinement: an answer's pose moved over all six degrees of freedom until the mesh's outline
best splits the frame into the object's colours inside and its surroundings' outside (no depth).

`ColourModel.of(mesh)` is prepared once per object: the mesh's silhouette seen from `VIEWS` directions on
the sphere (orthographic, rasterised on the CPU by the winding of the faces' edges: `_Outline`), and for
each, `POINTS` points of its outer contour with their 3-D coordinates and outward normals (a sparse
viewpoint model, as RBOT and SRT3D keep), a byte per coordinate: ~0.2 s and 295 kB an LM-O object.

`fit_colour` is region-based, after SRT3D: colour histograms of the pixels inside the start's outline and
of a ring outside it give each pixel a probability of showing the object; then, each iteration, the
viewpoint nearest to where the pose puts the camera, its contour points and normals projected at the
pose; along a short line through each point, normal to the outline, the posterior of where the outline
lies (every split of the line into object then surroundings, scored by those probabilities); its mean
is the point's residual and its variance the point's weight, and a damped, robust (Huber)
Gauss-Newton step on the twist (`index.refine.fit.apply_twist`), with a Gaussian prior around the start, moves
all points towards their splits. The lines shrink from coarse (a blurred map, long lines) to fine.
Contour alignment to edges was tried first and lost (val, centre given: under 5 deg 15.5 -> 9.7 %, under
20 deg 82.5 -> 50.5 %, the translation 5 % off): LM-O's clutter and the objects' own texture put the
strongest edge of a line, even one whose direction agrees, elsewhere than the outline too often.

`score`: how well the outline splits the map (the mean object probability just inside it and background
probability just outside, in [0, 1]); the result is kept only when it beats the start's by
`ACCEPT_MARGIN`. Poses are BOP's (R, t model to camera, OpenCV axes, mm)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import trimesh
from scipy.sparse import csr_matrix

from index.draw import DrawMesh
from index.refine.fit import Fit, apply_twist, cross

VIEWS = 600  # viewpoints on the sphere (Fibonacci): ~8 deg apart, the nearest within ~4 deg of any pose
POINTS = 120  # contour points kept per viewpoint
MODEL_FACES = 3000  # faces of the mesh the viewpoints are rasterised from (decimated)
MODEL_PX = 240  # the object's diameter in the viewpoints' rasters, px
TANGENT_PX = 3  # a contour point's tangent runs between the contour pixels this far either side
CODE_MAX = 127  # a point's coordinates are kept as int8 steps
NEAR_MM = 1.0  # a pose whose origin is nearer than this (or behind the camera) is not refined


@dataclass(frozen=True)
class ColourModel:
    """The sparse viewpoint model of one object: `directions` (V, 3) unit vectors from the object's origin
    towards the camera, model axes; for each, `coords` (V, P, 3) of its outer contour's points in the
    view's camera axes (`look_from`: x and y across the view, z along it) in steps of `unit` mm, and
    `angles` (V, P) of their outward normals in the view's image plane, a turn in 256 steps; `diameter`
    mm. A byte each, 4 bytes a point (12 as half floats): the step, 1/127 of the farthest vertex's
    distance from the origin, is about the raster's pixel (1/240 of the diameter) the contour was found
    at; a 1.4 deg step turns a normal's line, the fit's search direction, by a hundredth of its length."""

    directions: np.ndarray
    coords: np.ndarray
    angles: np.ndarray
    unit: float
    diameter: float

    @property
    def nbytes(self) -> int:
        return int(self.directions.nbytes + self.coords.nbytes + self.angles.nbytes)

    @classmethod
    def of(cls, mesh: trimesh.Trimesh | DrawMesh, views: int = VIEWS, points: int = POINTS) -> ColourModel:
        draw = mesh if isinstance(mesh, DrawMesh) else DrawMesh.of(mesh, MODEL_FACES)
        if len(draw.faces) > MODEL_FACES * 2:
            draw = DrawMesh.of(trimesh.Trimesh(draw.vertices, draw.faces, process=False), MODEL_FACES)
        dirs = fibonacci_sphere(views).astype(np.float32)
        outline = _Outline(draw)
        local, normal = outline.contours(dirs.astype(float), points)
        # the farthest vertex and a raster pixel more (the outline runs up to half a pixel beyond it)
        unit = (np.linalg.norm(draw.vertices, axis=1).max() + 1 / outline.scale) / CODE_MAX
        coords = np.clip(np.round(local / unit), -CODE_MAX, CODE_MAX).astype(np.int8)
        turn = np.round(np.arctan2(normal[..., 1], normal[..., 0]) / (2 * np.pi) * 256)
        return cls(dirs, coords, (turn % 256).astype(np.uint8), float(unit), float(draw.diameter))

    def view(self, v: int) -> tuple[np.ndarray, np.ndarray]:
        """The contour points (P, 3) mm and outward normals (P, 3) of view `v`, model axes."""
        R = look_from(self.directions[v].astype(float))
        a = self.angles[v] * (2 * np.pi / 256)
        normal = np.column_stack([np.cos(a), np.sin(a), np.zeros(len(a))])
        return self.coords[v].astype(float) * self.unit @ R, normal @ R

    @property
    def points(self) -> np.ndarray:
        """Every view's contour points (V, P, 3) mm, model axes."""
        return self.coords.astype(float) * self.unit @ look_from(self.directions.astype(float))

    @property
    def normals(self) -> np.ndarray:
        """Every view's contour normals (V, P, 3), model axes."""
        a = self.angles * (2 * np.pi / 256)
        flat = np.stack([np.cos(a), np.sin(a), np.zeros(a.shape)], axis=-1)
        return flat @ look_from(self.directions.astype(float))

    def nearest_view(self, R: np.ndarray, t: np.ndarray) -> int:
        """The viewpoint nearest to where (R, t) puts the camera, seen from the object."""
        c = -np.asarray(R, float).T @ np.ravel(t)
        return int(np.argmax(self.directions @ (c / max(np.linalg.norm(c), 1e-9))))


def fibonacci_sphere(n: int) -> np.ndarray:
    """`n` nearly evenly spread unit vectors (n, 3)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def look_from(direction: np.ndarray) -> np.ndarray:
    """Rotations model -> camera (OpenCV axes) (..., 3, 3) whose cameras look at the origin from
    `direction` (..., 3)."""
    z = -np.asarray(direction, float)
    up = np.where((np.abs(z[..., 2:3]) < 0.9), [0.0, 0.0, 1.0], [0.0, 1.0, 0.0])
    x = cross(up, z)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, cross(z, x), z], axis=-2)


class _Outline:
    """A mesh's silhouettes and outer contours seen from many directions (orthographic), rasterised by the
    nonzero winding rule over the projected faces' edges: each face counted as winding the same way (its
    projected area's sign is its normal's against the direction), an edge two faces facing the same way
    share cancels, so only a view's few hundred fold and border edges are scanned, all views at once
    (one `cv2.fillConvexPoly` per face and view, 1.8 million calls, took 2.4-4 s an object). A pixel is
    on the object when a face covers its centre: the silhouette is the union of all faces, front or back,
    and needs no closed mesh."""

    def __init__(self, mesh: DrawMesh) -> None:
        self.vertices = np.asarray(mesh.vertices, float)
        faces = np.asarray(mesh.faces, np.int64)
        v = self.vertices[faces]
        self.face_normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        ends = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        self.edges, edge_of = np.unique(np.sort(ends, axis=1), axis=0, return_inverse=True)
        # (E, F): +1 where the face runs the edge from its lower vertex to its higher, -1 the other way
        self.incidence = csr_matrix(
            (
                np.where(ends[:, 0] < ends[:, 1], 1.0, -1.0),
                (edge_of.ravel(), np.repeat(np.arange(len(faces)), 3)),
            ),
            shape=(len(self.edges), len(faces)),
        )
        self.scale = MODEL_PX / mesh.diameter

    def contours(self, directions: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """`n` points of the outer contour seen from each of `directions` (V, 3), (V, n, 3) mm in each
        view's camera axes (`look_from`), and their outward normals in its image plane (V, n, 2). A contour
        pixel takes its depth from the nearest end of an edge that can make the outline."""
        R = look_from(directions)
        cam = (R.reshape(-1, 3) @ self.vertices.T).reshape(len(R), 3, -1)
        uv = cam[:, :2] * self.scale  # (V, 2, N) px
        # each view's raster: the box of its vertices and pixels of zeros around, (width, height) from `lo`
        lo = np.floor(uv.min(axis=2)).astype(np.int64) - 1
        shape = np.ceil(uv.max(axis=2)).astype(np.int64) - lo + 3  # a column more: x's rounding
        # an edge's winding in a view: the sum over its faces of the way they run it, times the way they face
        weight = (self.incidence @ np.sign(self.face_normals @ directions.T)).T
        view, edge = np.nonzero(weight)
        at, step, at_view = self._crossings(uv, view, edge, weight[view, edge], lo, shape)
        first = np.searchsorted(view, np.arange(len(R) + 1))
        crossing = np.searchsorted(at_view, np.arange(len(R) + 1))
        ends = self.edges[edge]
        # the nearest end to a pixel in single floats: a hundredth of a pixel matters not
        uv32 = uv.astype(np.float32)
        square = (uv32**2).sum(axis=1)
        outlines: list[np.ndarray] = []
        counts = np.zeros(len(R), np.int64)
        for i in range(len(R)):
            (w, h), span = shape[i], slice(crossing[i], crossing[i + 1])
            # the running sum over the steps is every pixel's winding number
            winding = cv2.integral(np.bincount(at[span], step[span], w * h).reshape(h, w), sdepth=cv2.CV_64F)
            contours, _ = cv2.findContours(
                (winding != 0).view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
            )
            outlines.extend(contours)
            counts[i] = len(contours)
        pixels, tangents = _spread(outlines, counts, n)
        pixels += lo[:, None, :] - 1  # the running sum's first row and column are its zeros
        depth = np.zeros((len(R), n))
        pixels32 = pixels.astype(np.float32)
        for j in np.flatnonzero(counts):
            live = ends[first[j] : first[j + 1]].ravel()
            # the squared distance to each end, less the pixel's own square
            near = np.argmin(square[j, live] - 2 * pixels32[j] @ uv32[j][:, live], axis=1)
            depth[j] = cam[j, 2, live[near]]
        # OpenCV runs outer contours with the object on the right: the outward normal is the tangent turned
        # a quarter to the left
        g = np.stack([-tangents[..., 1], tangents[..., 0]], axis=-1)
        g /= np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
        # a contour pixel's centre is the object's last one: the outline runs half a pixel further out
        xy = (pixels + 0.5 * g) / self.scale
        return np.concatenate([xy, depth[..., None]], axis=-1), g

    def _crossings(
        self,
        uv: np.ndarray,
        view: np.ndarray,
        edge: np.ndarray,
        weight: np.ndarray,
        lo: np.ndarray,
        shape: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where the live edges cross the pixel rows, in their views' order: the flat index in the view's
        raster (`lo`, `shape`), the winding's step (up at the crossing's column, back on the row below:
        each twice) and the view."""
        p, q = uv[view, :, self.edges[edge, 0]], uv[view, :, self.edges[edge, 1]]
        # an edge crosses the rows whose centres lie in [its lower y, its upper y), at x = x0 + y * slope
        top = np.ceil(np.minimum(p[:, 1], q[:, 1])).astype(np.int64)
        rows = np.ceil(np.maximum(p[:, 1], q[:, 1])).astype(np.int64) - top
        crosses = rows > 0
        p, q, rows, top = p[crosses], q[crosses], rows[crosses], top[crosses]
        view, weight = view[crosses], weight[crosses]
        slope = (q[:, 0] - p[:, 0]) / (q[:, 1] - p[:, 1])
        x0 = p[:, 0] - p[:, 1] * slope
        width = shape[view, 0]
        # the flat index of pixel (x, y) in the edge's view's raster is y * width + x + offset
        offset = -lo[view, 1] * width - lo[view, 0]
        y = np.arange(rows.sum()) - np.repeat(np.cumsum(rows) - rows - top, rows)
        x = np.ceil(np.repeat(x0, rows) + y * np.repeat(slope, rows)).astype(np.int64)
        at = y * np.repeat(width, rows) + x + np.repeat(offset, rows)
        step = np.repeat(np.where(q[:, 1] > p[:, 1], weight, -weight), rows)
        at_twice = np.stack([at, at + np.repeat(width, rows)], axis=1)
        return at_twice.ravel(), np.stack([step, -step], axis=1).ravel(), np.repeat(view, 2 * rows)


def _spread(contours: Sequence[np.ndarray], counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`n` points spread evenly over each view's contours (OpenCV's, (L, 1, 2) each, `counts` (V,) of
    them a view, in the views' order): their pixels (V, n, 2) and tangents (V, n, 2), between the pixels
    `TANGENT_PX` either side along their own contour; zeros for a view without any."""
    lengths = np.array([len(k) for k in contours] or [0])
    c = np.concatenate(contours)[:, 0] if contours else np.zeros((1, 2), np.int32)
    ends = np.cumsum(lengths)
    total = np.bincount(np.repeat(np.arange(len(counts)), counts), lengths[: counts.sum()], len(counts))
    total = total.astype(np.int64)
    first = np.cumsum(total) - total
    at = (
        first[:, None]
        + np.round(np.arange(n) / n * total[:, None]).astype(np.int64) % np.maximum(total, 1)[:, None]
    )
    at[total == 0] = 0
    which = np.searchsorted(ends, at, side="right")
    start, length = ends[which] - lengths[which], lengths[which]
    ahead = start + (at - start + TANGENT_PX) % np.maximum(length, 1)
    behind = start + (at - start - TANGENT_PX) % np.maximum(length, 1)
    pixels, tangents = c[at].astype(float), (c[ahead] - c[behind]).astype(float)
    pixels[total == 0] = 0.0
    tangents[total == 0] = 0.0
    return pixels, tangents


# -- the fit -------------------------------------------------------------------------------------------

# Every constant below was chosen on the validation frames' 103 right answers (scripts/fit_colour_eval.py at 36ee81d,
# the figures quoted are their shares under 5 / 20 deg after the fit); most moved those shares by no more
# than two or three answers, so they stay at plain values.

#: the coarse-to-fine schedule: (blur of the foreground map px, half-length of the correspondence lines
#: px, iterations); the start poses are 3-10 deg off, an outline up to ~15 px away on a 150 px object.
#: Longer lines (30, 15, 6) lost 9 points under 5 deg; more iterations (6, 6, 4) gained nothing
STAGES = ((2.0, 20, 4), (1.0, 10, 4), (0.0, 5, 3))
HIST_BINS = 16  # colour bins per channel (4096 in all); 8 lost 3-5 points under 5 deg, 32 was no better
HIST_GAP_PX = 4  # pixels this near the start's outline are left out of both histograms
RING_PX = 20  # the background histogram's ring outside the start's outline, px
P_CLIP = 0.05  # a pixel's foreground probability is kept in [P_CLIP, 1 - P_CLIP] (0.01, 0.15: the same)
#: the line's log-likelihood is scaled by this (neighbouring pixels are not independent); 0.25 and 0.5
#: were 1-4 points worse under 20 deg
TEMPERATURE = 1.0
VAR_MIN = 1.0  # px^2, the smallest variance a line's outline position is given (its weight's cap)
HUBER_PX = 0.35  # Huber's threshold as a share of the line's half-length (0.2: no better overall)
#: Levenberg-Marquardt damping, relative to the normal matrix's diagonal: 1e-3 let the distance wander
#: (3.6 % median after vs 3.6-5.5 % with 0.03-0.1, and 0.1 lost the detection start's distance)
DAMPING = 0.03
#: a Gaussian prior on how far the pose may go from the start: rotation (deg), translation across the
#: ray and along it (shares of the distance). 3 deg: +2-3 points under 5 and 20 deg against no prior;
#: 6 and 12 deg lay between. The translation's sigmas hardly mattered (0.5-2 %, 3-10 %)
PRIOR_DEG, PRIOR_XY, PRIOR_Z = 3.0, 0.02, 0.1
SCORE_BAND_PX = 6  # the score looks this far inside and outside the outline
#: the refined score must beat the start's by this much to be kept: 0.03 kept the fewest bad moves
#: (0.0-0.02 were 2-3 points worse under 5 deg)
ACCEPT_MARGIN = 0.03
MARGIN_PX = 48  # the frame is cut to the outline's box plus this margin


def _outline_mask(uv: np.ndarray, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """The silhouette the projected contour (P, 2), in its order, encloses: uint8 (h, w), 255 inside."""
    mask = np.zeros(shape, np.uint8)
    pts = np.round((uv - np.asarray(origin, float)) * 16).astype(np.int32)
    cv2.fillPoly(mask, [pts], 255, lineType=cv2.LINE_8, shift=4)
    return mask


def _foreground(crop: np.ndarray, silhouette: np.ndarray) -> np.ndarray:
    """Each pixel's probability of showing the object (h, w) float32, from the colour histograms of the
    pixels inside `silhouette` and of a ring around it (a gap left either side of its outline)."""
    q = (crop.astype(np.int32) * HIST_BINS) // 256
    idx = (q[..., 0] * HIST_BINS + q[..., 1]) * HIST_BINS + q[..., 2]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * HIST_GAP_PX + 1,) * 2)
    inside = cv2.erode(silhouette, kernel) > 0
    near = cv2.dilate(silhouette, kernel)
    ring = cv2.dilate(near, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * RING_PX + 1,) * 2))
    outside = (ring > 0) & (near == 0)
    n = HIST_BINS**3
    hf = np.bincount(idx[inside], minlength=n) / max(1, inside.sum())
    hb = np.bincount(idx[outside], minlength=n) / max(1, outside.sum())
    p = (hf + 1e-6) / (hf + hb + 2e-6)
    return np.clip(p[idx], P_CLIP, 1 - P_CLIP).astype(np.float32)


def _project(
    model: ColourModel, R: np.ndarray, t: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The outline at (R, t): pixels (P, 2), unit outward image normals (P, 2), points rotated about the
    origin (P, 3) and camera points (P, 3)."""
    points, normals = model.view(model.nearest_view(R, t))
    q = points @ R.T
    X = q + t
    uv = (X @ K.T)[:, :2] / X[:, 2:3]
    n3 = normals @ R.T
    # the normal's image direction: the projected point moved a little along the 3-D normal
    Y = X + n3
    n2 = (Y @ K.T)[:, :2] / Y[:, 2:3] - uv
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-9)
    return uv, n2, q, X


def _along(
    image: np.ndarray, origin: tuple[int, int], uv: np.ndarray, n2: np.ndarray, s: np.ndarray
) -> np.ndarray:
    """`image` (h, w) float32 sampled at offsets `s` px along each point's outward normal: (P, len(s)),
    0.5 outside the image (no opinion)."""
    mx = (uv[:, 0:1] - origin[0] + s * n2[:, 0:1]).astype(np.float32)
    my = (uv[:, 1:2] - origin[1] + s * n2[:, 1:2]).astype(np.float32)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.5)


def _line_posteriors(p: np.ndarray, temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each line's outline lies, given its pixels' foreground probabilities `p` (P, S) at offsets
    -h..h: the outline between samples k-1 and k (offset k - h - 0.5) leaves the k first inside and the
    rest outside. Returns the posterior mean offset (P,) and variance (P,)."""
    S = p.shape[1]
    inside = np.concatenate([np.zeros((len(p), 1)), np.cumsum(np.log(p), axis=1)], axis=1)
    lb = np.log1p(-p)
    outside = lb.sum(axis=1, keepdims=True) - np.concatenate(
        [np.zeros((len(p), 1)), np.cumsum(lb, axis=1)], axis=1
    )
    ll = temperature * (inside + outside)
    ll -= ll.max(axis=1, keepdims=True)
    w = np.exp(ll)
    w /= w.sum(axis=1, keepdims=True)
    d = np.arange(S + 1) - (S - 1) / 2 - 0.5
    mean = w @ d
    var = w @ (d * d) - mean * mean
    return mean, var


def region_score(p: np.ndarray, origin: tuple[int, int], uv: np.ndarray, n2: np.ndarray, band: int) -> float:
    """How well the outline at `uv` (normals `n2`) splits the frame: the mean foreground probability just
    inside it and background probability just outside it (`band` px each side), in [0, 1]."""
    s = np.concatenate([-np.arange(1, band + 1), np.arange(1, band + 1)]).astype(np.float32)
    v = _along(p, origin, uv, n2, s)
    return float((v[:, :band].mean() + (1.0 - v[:, band:]).mean()) / 2)


def _jacobian(q: np.ndarray, X: np.ndarray, n2: np.ndarray, K: np.ndarray) -> np.ndarray:
    """d(n . uv)/d(twist) of each point (P, 6): rotation about the origin then translation, camera axes."""
    fx, fy = K[0, 0], K[1, 1]
    z = X[:, 2]
    a = np.column_stack(
        [n2[:, 0] * fx / z, n2[:, 1] * fy / z, -(n2[:, 0] * fx * X[:, 0] + n2[:, 1] * fy * X[:, 1]) / z**2]
    )
    return np.hstack([cross(q, a), a])


def _valid_start(rgb: np.ndarray, K: np.ndarray, R0: np.ndarray, t0: np.ndarray) -> bool:
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] < 8 or rgb.shape[1] < 8:
        return False
    if not (np.isfinite(R0).all() and np.isfinite(t0).all() and np.isfinite(K).all()):
        return False
    return float(np.ravel(t0)[2]) > NEAR_MM


def fit_colour(
    rgb: np.ndarray,
    K: np.ndarray,
    model: ColourModel,
    R0: np.ndarray,
    t0: np.ndarray,
    *,
    mask: np.ndarray | None = None,
    stages: tuple[tuple[float, int, int], ...] = STAGES,
    temperature: float = TEMPERATURE,
    huber: float = HUBER_PX,
    damping: float = DAMPING,
    prior: tuple[float, float, float] = (PRIOR_DEG, PRIOR_XY, PRIOR_Z),
    accept_margin: float = ACCEPT_MARGIN,
) -> Fit:
    """(R0, t0) moved to where the model's outline best splits `rgb` (H, W, 3) uint8 (intrinsics `K`)
    into the object's colours inside and its surroundings' outside. `mask` (H, W) in [0, 1] or bool:
    where the service's mask head sees the object, averaged into the colour cue; None for none. A start
    that cannot be refined (behind the camera, its outline off the frame, an empty frame) comes back
    unmoved. `prior`: the start's sigmas (deg, share of the distance across and along the ray); 0 deg
    for none."""
    R0, t0, K = np.asarray(R0, float), np.ravel(np.asarray(t0, float)), np.asarray(K, float)
    rgb = np.asarray(rgb)
    unmoved = Fit(R0, t0, 0.0, 0.0, 0, False)
    if not _valid_start(rgb, K, R0, t0):
        return unmoved
    h, w = rgb.shape[:2]
    if mask is not None and np.shape(mask) != (h, w):
        raise ValueError(f"the mask must be the frame's size {(h, w)}; got {np.shape(mask)}")
    uv0, n0, _, X0 = _project(model, R0, t0, K)
    if not np.isfinite(uv0).all() or (X0[:, 2] <= NEAR_MM).any():
        return unmoved
    lo = np.floor(uv0.min(axis=0)).astype(int) - MARGIN_PX
    hi = np.ceil(uv0.max(axis=0)).astype(int) + MARGIN_PX
    box = (max(0, lo[0]), max(0, lo[1]), min(w, hi[0]), min(h, hi[1]))
    if box[2] - box[0] < 8 or box[3] - box[1] < 8:
        return unmoved
    origin = (int(box[0]), int(box[1]))
    crop = np.ascontiguousarray(rgb[box[1] : box[3], box[0] : box[2]])
    p_fg = _foreground(crop, _outline_mask(uv0, origin, crop.shape[:2]))
    if mask is not None:
        m = np.asarray(mask, np.float32)[box[1] : box[3], box[0] : box[2]]
        p_fg = np.clip(0.5 * p_fg + 0.5 * m, P_CLIP, 1 - P_CLIP).astype(np.float32)
    start_score = region_score(p_fg, origin, uv0, n0, SCORE_BAND_PX)
    P = None
    if prior[0] > 0:
        sigma = np.array([np.radians(prior[0])] * 3 + [prior[1] * t0[2]] * 2 + [prior[2] * t0[2]])
        P = np.diag(1.0 / sigma**2)
    R, t = R0, t0
    iterations = 0
    for blur, half, n_iter in stages:
        p = cv2.GaussianBlur(p_fg, (0, 0), blur) if blur > 0 else p_fg
        s = np.arange(-half, half + 1, dtype=np.float32)
        for _ in range(n_iter):
            iterations += 1
            uv, n2, q, X = _project(model, R, t, K)
            if (X[:, 2] <= NEAR_MM).any():
                return Fit(R0, t0, start_score, start_score, iterations, False)
            r, var = _line_posteriors(_along(p, origin, uv, n2, s), temperature)
            J = _jacobian(q, X, n2, K)
            k = huber * half
            wgt = np.where(np.abs(r) <= k, 1.0, k / np.maximum(np.abs(r), 1e-9)) / np.maximum(var, VAR_MIN)
            A = J.T @ (J * wgt[:, None])
            b = J.T @ (wgt * r)
            A += damping * np.diag(np.diag(A)) + 1e-9 * np.eye(6)
            if P is not None:  # the prior pulls back towards the start by how far the pose has gone
                gone = np.concatenate([cv2.Rodrigues(R @ R0.T)[0].ravel(), t - t0])
                A += P
                b -= P @ gone
            R, t = apply_twist(R, t, np.linalg.solve(A, b))
            if t[2] <= NEAR_MM:
                return Fit(R0, t0, start_score, start_score, iterations, False)
    uv, n2, _, _ = _project(model, R, t, K)
    score = region_score(p_fg, origin, uv, n2, SCORE_BAND_PX)
    if score >= start_score + accept_margin:
        return Fit(R, t, score, start_score, iterations, True)
    return Fit(R0, t0, start_score, start_score, iterations, False)
