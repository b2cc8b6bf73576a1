"""The depth refinement: an answer's pose (a template's viewpoint and roll at the query's distance) moved
over all six degrees of freedom so that the mesh's surface lies on the frame's measured depth.

Point-to-plane ICP (Chen & Medioni 1991) of the mesh's surface points to the measured points. Each
iteration takes the model points the camera sees at the current pose (their normals face it, they are in
the image and not behind a measured surface much nearer: an occluder in front is not a pull), pairs each
with its nearest measured point (a k-d tree over the measured points of the start's window, built once),
keeps the pairs within a distance gate that shrinks over the iterations, weighs them with a Huber loss,
and solves the 6 x 6 normal equations for the twist of `index.refine.fit.apply_twist` (rotation about the
object's origin, then translation in the camera's axes). Symmetric objects need nothing: the fit goes to
whichever of the poses that look alike is nearest, and the damping keeps a turn about a symmetry axis
(which the depth cannot see) at zero.

Before the ICP the start may slide along the ray through its origin (`slide_to_surface`): the service's
distance is the surface at the centre plus a template's offset, sometimes further off than a gate can
reach; when the slide is long, the ICP runs from both starts and the better scored wins.

The score of a pose (`score_of`) is the share of the model points the camera sees at it whose pixel holds
a reading within `SCORE_MM` of theirs, less the share the reading sees through; the result is kept
(`moved`) only if it scores above the start and did not flee (turned or slid further than any start error
the service makes).

Constants were chosen on the service's rgbd answers on the validation frames (rendered depth, where most
choices tie: 97.2 % within ADD(-S) < 0.1 d for every gate schedule and Huber threshold tried, 95.4 %
without the slide) and on the real Kinect frame from perturbed truths, where they do not tie (83 % with
gates shrinking by 0.7 to 8 mm, 89 % by 0.85 to 12 mm, 91 % adding self-occlusion: the present constants;
that frame also holds the test's instances): docs/results/fit-depth-*.

Conventions: depth (H, W) float32 mm, 0 = no reading; K (3, 3) OpenCV; poses R_m2c, t_m2c mm (BOP)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from index.draw import DrawMesh
from index.refine.fit import Fit, apply_twist, cross
from index.templates.mesh import diameter

#: surface points of a DepthModel: 1,500 put a point every ~4 mm on a 150 mm object (LM-O's are 100-260
#: mm across), about 300-700 of them facing the camera at ~1 m, enough for six parameters many times over
MODEL_POINTS = 1500
MODEL_SEED = 0
#: the start's window: the projected model's box grown by this share of its size on each side, so a start
#: 30 mm off still has its true surface inside
WINDOW_GROW = 0.25
#: measured pixels of the window taken for the k-d tree: every STRIDE-th row and column (2: ~1-4k points for
#: an LM-O object at ~1 m, a 2 px spacing is ~3.5 mm there, finer than the model's points)
STRIDE = 2
#: measured points further than this (mm) from the start's depth range are dropped before the tree: the
#: table far behind, the wall
DEPTH_RANGE_MM = 80.0
#: the distance gate (mm) at the first iteration, shrinking by GATE_SHRINK each to at least GATE_MIN: wide
#: enough for a start 30 mm off, then narrow enough that the neighbours' surfaces do not pull
GATE_START_MM = 40.0
GATE_SHRINK = 0.85
GATE_MIN_MM = 12.0
#: Huber's threshold (mm) on the point-to-plane residual: Kinect's noise at 1 m is ~2-4 mm
HUBER_MM = 4.0
#: before the ICP, the start slides along the ray through its origin to the depth that best explains the
#: readings at its points (`slide_to_surface`), searched within DEPTH_SEARCH_MM in SLIDE_STEP_MM steps:
#: the service's distance is the surface at the centre plus a template's offset, and was 57 mm short for
#: the driller of the Kinect frame, beyond any gate that still keeps the neighbours out
DEPTH_SEARCH_MM = 100.0
SLIDE_STEP_MM = 2.5
SLIDE_TOL_MM = 6.0
#: a slide shorter than this (mm) is left to the ICP's own gates: no second run
SLIDE_MIN_MM = 15.0
ITERATIONS = 20
#: stop when an update turns less than this (radians) and slides less than STOP_MM
STOP_RAD = 1e-3
STOP_MM = 0.2
MIN_PAIRS = 30  # fewer pairs than this: six parameters from too little, the fit stops (degenerate)
#: Levenberg damping, relative to the normal matrix's mean diagonal: keeps turns the depth cannot see
#: (about a symmetry axis, along a plane) at zero instead of wherever noise takes them
DAMPING = 1e-3
#: `outline_of`: the ring around a pose's silhouette (a share of its larger side) and how near (mm) a reading
#: there must be to the model's nearest seen depth to count as its surface going on
BEYOND_RING = 0.15
BEYOND_MM = 15.0
#: self-occlusion: model points are compared with the nearest model point of their CELL_PX x CELL_PX cell
#: (at ~1 m the points are ~2-3 px apart, so a cell holds some of the front surface; 0: no test) and are
#: hidden when more than SELF_MM behind it
CELL_PX = 4
SELF_MM = 10.0
#: a measured depth within this (mm) of a model point's makes it "explained" for the score
SCORE_MM = 10.0
#: `unexplained_of`: the share of a pose's seen points that must have a reading not in front of them (not
#: hidden by a nearer object, not a hole in the depth) for the share they explain to be theirs alone; below
#: it the share is of this many of the seen points, so a pose hidden behind an occluder does not score by a
#: few points. 0.5: the value tried first; 0.3 and 0.7 were measured beside it leave-one-video-out (YCB-V, the
#: open set's unknowns rejected 49 / 44 / 33 % at 11 / 12 / 9 % of registered ones) and it was kept
#: (docs/experiments.md, "The depth fit in the open set")
SHOWN_LEAST = 0.5
#: the result fled: moved further than any start error the service makes (~20 deg, ~30 mm off) by margins
FLEE_DEG = 45.0
FLEE_SHARE = 0.5  # of the object's diameter


@dataclass(frozen=True)
class DepthModel:
    """An object as the depth refinement takes it: `points` (N, 3) mm on its surface, area-sampled, their
    outward `normals` (N, 3) unit, and its `diameter` mm."""

    points: np.ndarray
    normals: np.ndarray
    diameter: float

    @classmethod
    def of(
        cls, mesh: trimesh.Trimesh | DrawMesh, n: int = MODEL_POINTS, seed: int = MODEL_SEED
    ) -> DepthModel:
        """`n` points drawn on the mesh's faces with probability by area (seeded: the same mesh gives the
        same model), each with its face's normal (the faces' winding says which side is out)."""
        if isinstance(mesh, DrawMesh):
            vertices, faces, size = mesh.vertices, mesh.faces, mesh.diameter
        else:
            vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
            size = diameter(mesh) if len(faces) else 0.0
        tri = np.asarray(vertices, float)[np.asarray(faces, np.int64)]
        doubled = cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # normal times twice the area
        area = np.linalg.norm(doubled, axis=1)
        if len(tri) == 0 or area.sum() <= 0:
            raise ValueError("a depth model needs a mesh with a surface (faces of non-zero area)")
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(tri), size=n, p=area / area.sum())
        a, b = rng.random((2, n))
        flip = a + b > 1  # fold the square's far half onto the triangle: uniform barycentric coordinates
        a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
        t = tri[pick]
        points = t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])
        normals = doubled[pick] / area[pick, None]
        return cls(points.astype(np.float32), normals.astype(np.float32), float(size))

    @property
    def nbytes(self) -> int:
        return int(self.points.nbytes + self.normals.nbytes)


def measured_points(
    depth: np.ndarray, K: np.ndarray, box: tuple[int, int, int, int], stride: int
) -> np.ndarray:
    """The measured points (M, 3) mm of `depth`'s pixels in `box` (x0, y0, x1, y1, exclusive ends), every
    `stride`-th row and column, readings only."""
    x0, y0, x1, y1 = box
    v, u = np.mgrid[y0:y1:stride, x0:x1:stride]
    z = depth[y0:y1:stride, x0:x1:stride].astype(float)
    ok = z > 0
    u, v, z = u[ok], v[ok], z[ok]
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)


def _seen(
    model: DepthModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, depth: np.ndarray, cell_px: int = CELL_PX
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The model at (R, t) as the camera sees it: camera points (N, 3), normals (N, 3), which face the
    camera inside the image (N,) bool, and the measured depth at each one's pixel (N,) (0: none or outside)."""
    p = model.points @ R.T + t
    n = model.normals @ R.T
    z = p[:, 2]
    h, w = depth.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.round(K[0, 0] * p[:, 0] / z + K[0, 2])
        v = np.round(K[1, 1] * p[:, 1] / z + K[1, 2])
    inside = (z > 1.0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    facing = inside & (np.einsum("ij,ij->i", n, p) < 0)
    if cell_px > 0 and facing.any():
        # the object hides parts of itself that face the camera (a handle's inside, a spout's far side):
        # a point further than SELF_MM behind the nearest model point of its cell is not seen
        cu, cv = (u[facing] // cell_px).astype(np.int64), (v[facing] // cell_px).astype(np.int64)
        cell = cv * (w // cell_px + 1) + cu
        nearest = np.full((h // cell_px + 1) * (w // cell_px + 1), np.inf)  # every cell: no np.unique
        np.minimum.at(nearest, cell, z[facing])
        facing[facing] = z[facing] <= nearest[cell] + SELF_MM
    d = np.zeros(len(p))
    d[inside] = depth[v[inside].astype(int), u[inside].astype(int)]
    return p, n, facing, d


def score_of(
    model: DepthModel,
    R: np.ndarray,
    t: np.ndarray,
    K: np.ndarray,
    depth: np.ndarray,
    tol_mm: float = SCORE_MM,
) -> float:
    """How well the depth explains the model at (R, t), in [0, 1]: the share of the model points seen
    (facing the camera, not hidden by the object itself) whose pixel's reading is within `tol_mm` of
    theirs, less the share the reading sees through (the model over `tol_mm` in front of the measured
    surface: impossible, where a point behind a nearer reading may be hidden by an occluder). The second
    share keeps a pose at an occluder's depth, or one slid onto the table, from scoring as a fit."""
    shares = _explained(model, R, t, K, depth, tol_mm)
    return 0.0 if shares is None else shares[0]


def _explained(
    model: DepthModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, depth: np.ndarray, tol_mm: float
) -> tuple[float, float] | None:
    """Of the model points seen at (R, t): the share the depth explains (`score_of`), and the share whose
    pixel has a reading not over `tol_mm` in front of them (`unexplained_of`); None when none is seen."""
    p, _, facing, d = _seen(model, R, t, K, depth)
    if not facing.any():
        return None
    gap = d[facing] - p[facing, 2]
    seen = d[facing] > 0
    agree, through = np.abs(gap) < tol_mm, seen & (gap > tol_mm)
    return float(max(0.0, np.mean(agree) - np.mean(through))), float(np.mean(seen & (gap >= -tol_mm)))


def unexplained_of(
    model: DepthModel,
    R: np.ndarray,
    t: np.ndarray,
    K: np.ndarray,
    depth: np.ndarray,
    tol_mm: float = SCORE_MM,
    least: float = SHOWN_LEAST,
) -> float | None:
    """How much of the model at (R, t) the depth leaves unexplained where it could explain it, in [0, 1]
    (None: the camera sees none of it): 1 less `score_of`'s share taken of the seen points whose pixel has a
    reading not over `tol_mm` in front of them, at least `least` of the seen points. A point behind a nearer
    object, or over a hole in the depth, is no evidence either way: `score_of` counts it as unexplained,
    so an object half hidden at its true pose scores like a wrong one (YCB-V: 0.34-0.46 at the truth,
    docs/experiments.md). The open set's depth term (`service.rejection.Term`)."""
    shares = _explained(model, R, t, K, depth, tol_mm)
    if shares is None:
        return None
    explained, shown = shares
    return 1.0 - explained / max(shown, least)


@dataclass(frozen=True)
class Outline:
    """What the measured depth shows around and over a pose's silhouette (`outline_of`).

    `beyond`: how far the measured surface goes on past the model, in [0, 1]: of the pixels with a reading in a
    ring around its silhouette (`BEYOND_RING` of its larger side wide), the share whose reading is within
    `BEYOND_MM` of the model's nearest seen depth there. An object's own outline is where its surface ends
    (the table behind it, or a nearer occluder), so a right pose scores near 0; a smaller object posed on a
    face of a larger one, whose points the depth explains as well (`score_of`), scores high: the larger
    one's surface goes on around it.

    `explained`: how much of the image the depth explains at the pose, in px: the silhouette's area times the
    share of its seen points whose reading is within `SCORE_MM` of theirs. `score_of` is a share of the
    object's own points, so a small object posed on part of a larger one scores as well as the larger one,
    and a larger one partly hidden scores lower; the area the pose explains tells them apart (the larger
    object explains more of the measured surface)."""

    beyond: float
    explained: float


def outline_of(model: DepthModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, depth: np.ndarray) -> Outline:
    """The `Outline` of the model at (R, t) against `depth`; zeros when it shows fewer than MIN_PAIRS points."""
    p, _, facing, d = _seen(model, R, t, K, depth)
    if facing.sum() < MIN_PAIRS:
        return Outline(0.0, 0.0)
    q = p[facing]
    u = np.round(K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]).astype(int)
    v = np.round(K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]).astype(int)
    side = max(u.max() - u.min(), v.max() - v.min()) + 1
    grow = max(2, int(round(BEYOND_RING * side)))
    h, w = depth.shape
    x0, y0 = max(u.min() - grow - 2, 0), max(v.min() - grow - 2, 0)
    x1, y1 = min(u.max() + grow + 3, w), min(v.max() + grow + 3, h)
    z = np.full((y1 - y0, x1 - x0), np.inf, np.float32)
    np.minimum.at(z, (v - y0, u - x0), q[:, 2].astype(np.float32))
    gap = max(1, int(np.ceil(side / np.sqrt(len(q)))))  # the points' spacing in px: close the silhouette
    close = np.ones((2 * gap + 1,) * 2, np.uint8)
    silhouette = cv2.morphologyEx(np.isfinite(z).astype(np.uint8), cv2.MORPH_CLOSE, close)
    silhouette = cv2.dilate(silhouette, close)  # out to the outline: the outermost points fall short of it
    agree = np.abs(d[facing] - q[:, 2]) < SCORE_MM
    explained = float(silhouette.sum()) * float(np.mean(agree))
    around = (cv2.dilate(silhouette, np.ones((2 * grow + 1,) * 2, np.uint8)) > 0) & (silhouette == 0)
    nearest = cv2.erode(
        np.where(np.isfinite(z), z, 1e9).astype(np.float32), np.ones((2 * grow + 1,) * 2, np.uint8)
    )
    ring = depth[y0:y1, x0:x1].astype(np.float32)
    ring_px = around & (ring > 0) & (nearest < 1e9)
    beyond = float(np.mean(np.abs(ring[ring_px] - nearest[ring_px]) < BEYOND_MM)) if ring_px.any() else 0.0
    return Outline(beyond, explained)


def slide_to_surface(
    model: DepthModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, depth: np.ndarray
) -> np.ndarray:
    """`t` moved along its own ray by the shift s (within +-DEPTH_SEARCH_MM) that best explains the
    measured depth at the facing model points' pixels: most points within SLIDE_TOL_MM of their reading,
    less those the reading sees through (the model more than SLIDE_TOL_MM in front of a measured surface:
    impossible). Points behind a nearer reading cost nothing: an occluder may hide them. So an occluder
    in front does not draw the start to itself (its depth leaves the object's seen points in free space),
    and neither does the table behind. `t` itself when too few facing points have a reading."""
    p, _, facing, d = _seen(model, R, t, K, depth)
    gap = (d - p[:, 2])[facing & (d > 0)]
    if len(gap) < MIN_PAIRS:
        return t
    shifts = np.arange(-DEPTH_SEARCH_MM, DEPTH_SEARCH_MM + SLIDE_STEP_MM / 2, SLIDE_STEP_MM)
    off = gap[None, :] - shifts[:, None]
    merit = (np.abs(off) < SLIDE_TOL_MM).sum(axis=1) - (off > SLIDE_TOL_MM).sum(axis=1)
    best = shifts[int(np.argmax(merit))]
    near = gap[np.abs(gap - best) < SLIDE_TOL_MM]
    shift = float(np.median(near)) if len(near) else float(best)
    return t * (1.0 + shift / t[2])


def _window(model: DepthModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, shape: tuple[int, int]):
    """The start's window (x0, y0, x1, y1) in the image and its depth range (near, far) mm; None when the
    model projects nowhere in the image."""
    p = model.points @ R.T + t
    if (p[:, 2] <= 1.0).any():
        return None
    uv = (p @ K.T)[:, :2] / p[:, 2:3]
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    grow = WINDOW_GROW * (hi - lo) + 4
    h, w = shape
    x0, y0 = np.floor(np.maximum(lo - grow, 0)).astype(int)
    x1, y1 = np.ceil(np.minimum(hi + grow, [w, h])).astype(int)
    if x1 <= x0 or y1 <= y0:
        return None
    return (x0, y0, x1, y1), (p[:, 2].min() - DEPTH_RANGE_MM, p[:, 2].max() + DEPTH_RANGE_MM)


def _icp(
    depth: np.ndarray,
    K: np.ndarray,
    model: DepthModel,
    tree: cKDTree,
    R: np.ndarray,
    t: np.ndarray,
    iterations: int,
    gates: tuple[float, float, float],
    huber_mm: float,
    cell_px: int,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Point-to-plane ICP from (R, t) to the measured points of `tree`: the pose and the iterations run.
    `gates`: the first gate (mm), its shrink factor per iteration, the least gate."""
    q = tree.data
    gate, shrink, least = gates
    done = 0
    for it in range(iterations):
        done = it + 1
        p, n, facing, d = _seen(model, R, t, K, depth, cell_px)
        occluded = (d > 0) & (d < p[:, 2] - gate)  # a reading far nearer: something in front, not a pull
        use = facing & ~occluded
        if use.sum() < MIN_PAIRS:
            break
        pu, nu = p[use], n[use]
        dist, j = tree.query(pu, distance_upper_bound=gate)
        pair = np.isfinite(dist)
        if pair.sum() < MIN_PAIRS:
            break
        pu, nu, qu = pu[pair], nu[pair], q[j[pair]]
        r = np.einsum("ij,ij->i", nu, pu - qu)
        weight = np.minimum(1.0, huber_mm / np.maximum(np.abs(r), 1e-9))
        # d r / d twist: a turn w about the origin t moves p by w x (p - t), a slide by itself
        J = np.hstack([cross(pu - t, nu), nu])
        A = (J * weight[:, None]).T @ J
        b = -(J * weight[:, None]).T @ r
        A += DAMPING * np.trace(A) / 6 * np.eye(6)
        twist = np.linalg.solve(A, b)
        R, t = apply_twist(R, t, twist)
        gate = max(gate * shrink, least)
        if np.linalg.norm(twist[:3]) < STOP_RAD and np.linalg.norm(twist[3:]) < STOP_MM and gate <= least:
            break
    return R, t, done


def fit_depth(
    depth: np.ndarray,
    K: np.ndarray,
    model: DepthModel,
    R0: np.ndarray,
    t0: np.ndarray,
    *,
    mask: np.ndarray | None = None,
    iterations: int = ITERATIONS,
    gate_start_mm: float = GATE_START_MM,
    gate_shrink: float = GATE_SHRINK,
    gate_min_mm: float = GATE_MIN_MM,
    huber_mm: float = HUBER_MM,
    stride: int = STRIDE,
    score_mm: float = SCORE_MM,
    slide_min_mm: float = SLIDE_MIN_MM,
    cell_px: int = CELL_PX,
) -> Fit:
    """The pose (R0, t0) refined against `depth` (H, W) float32 mm (0: no reading) seen with `K` (3, 3):
    ICP from the start, and, when `slide_to_surface` moves the start further than `slide_min_mm` along
    its ray, ICP from there too; the better scored of the two when it scores above the start and did not
    flee, else the start (`moved` False). `mask` (where the caller thinks the object is) is accepted
    and not used: the gates already keep the neighbours out, and a wrong mask would cut the object's own
    surface."""
    del mask
    R0, t0 = np.asarray(R0, float), np.ravel(np.asarray(t0, float))
    K = np.asarray(K, float)
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 2 or t0[2] <= 1.0:
        return Fit(R0, t0, 0.0, 0.0, 0, False)
    start = score_of(model, R0, t0, K, depth, score_mm)
    stay = Fit(R0, t0, start, start, 0, False)
    starts = [t0]
    t_slid = slide_to_surface(model, R0, t0, K, depth)
    if np.linalg.norm(t_slid - t0) > slide_min_mm:
        starts.append(t_slid)
    window = _window(model, R0, t0, K, depth.shape)
    if window is None:
        return stay
    box, (near, far) = window
    q = measured_points(depth, K, box, stride)
    q = q[(q[:, 2] > near - DEPTH_SEARCH_MM) & (q[:, 2] < far + DEPTH_SEARCH_MM)]
    if len(q) < MIN_PAIRS:
        return stay
    tree = cKDTree(q)
    best, runs = stay, 0
    for t_start in starts:
        gates = (gate_start_mm, gate_shrink, gate_min_mm)
        R, t, done = _icp(depth, K, model, tree, R0, t_start, iterations, gates, huber_mm, cell_px)
        runs += done
        turned = np.degrees(np.arccos(np.clip((np.trace(R @ R0.T) - 1) / 2, -1, 1)))
        if turned > FLEE_DEG or np.linalg.norm(t - t0) > FLEE_SHARE * model.diameter:
            continue  # fled: further than any start error the service makes
        final = score_of(model, R, t, K, depth, score_mm)
        if final > best.score:
            best = Fit(R, t, final, start, 0, True)
    return Fit(best.R, best.t, best.score, start, runs, best.moved)
