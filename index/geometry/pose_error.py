"""Pose errors, the one definition the evaluation, the service's tests and training use (the names and
units of bop_toolkit's `pose_error.py`, so our numbers compare with BOP's).

Conventions: `R_est`, `R_gt` are rotations R_m2c (object to camera, OpenCV axes: `index.geometry.pose`), one (3, 3)
or a stack (N, 3, 3); `t_est`, `t_gt` translations in mm; errors are degrees (angles) or mm (distances).
Cosines are clipped to [-1, 1] before `arccos`. Every error respects the object's symmetry
(`index.geometry.symmetry`): the smallest error over the poses that look the same.

- `rotation_errors` / `rotation_error`: the 3-D rotation angle, in-plane included;
- `view_errors` / `view_error`: the angle between viewing directions (the paper's error; in-plane does
  not count);
- `within`: an error counts as within t when it is strictly below t, as BOP counts.

BOP's model-based errors (Hodaň et al., BOP 2018/2019/2020), the model's points `pts` (N, 3) in mm:
- `mssd` (mm), `mspd` (px): the largest distance over the model's points, 3-D or projected, the smallest
  over the object's symmetry transformations (`index.geometry.symmetry.symmetry_transformations`);
- `add`, `adi` (ADD-S) (mm): the mean distance between corresponding / nearest transformed points;
- `te` (mm), `re` (degrees): translation and rotation errors; `within_deg_cm`: the classic "5°, 5 cm";
- `vsd`: the visible surface discrepancy, from depth maps rendered at both poses (`render_depths`);
- `missing_as_inf`: a missing estimate's error (nan) as infinitely wrong, as BOP counts it.

The recall over BOP19's thresholds and the average recall AR, from these errors: `evaluation.bop.recall`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.spatial import cKDTree

from index.geometry.pose import lookat_rotation
from index.geometry.symmetry import Symmetry, continuous, symmetry_rotations

if TYPE_CHECKING:
    import trimesh


class FrameRenderer(Protocol):
    """What `render_depths` needs of a renderer (`index.templates.render.Renderer`): meshes at poses in a
    frame, colour and depth (mm) back."""

    def render_frame(
        self,
        meshes: Sequence[tuple[trimesh.Trimesh, np.ndarray, np.ndarray]],
        K: np.ndarray,
        width: int,
        height: int,
    ) -> tuple[np.ndarray, np.ndarray]: ...


#: Symmetry transformations x -> R x + t of the object frame (`index.geometry.symmetry.symmetry_transformations`).
Transformations = Sequence[tuple[np.ndarray, np.ndarray]]


def _stack(R: np.ndarray) -> np.ndarray:
    return np.asarray(R, dtype=float).reshape(-1, 3, 3)


def _degrees(cos: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_errors(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """3-D rotation error, in-plane included: the smallest angle (degrees) between each R_est and any
    pose R_gt @ S that looks the same (S a symmetry of the object). Under "full" only where the two
    poses put the axis it turns about is observable (with "+flip", that axis either way round).
    Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    if (named := continuous(symmetry)) is not None:
        i = "xyz".index(named.axis)  # where each pose puts the axis it turns about
        cos = R_est[:, :, i] @ R_gt[:, :, i].T
        return _degrees(np.abs(cos) if named.flip_deg is not None else cos)
    # trace(R_est^T R_gt S) is the sum of the element-wise product of R_est and R_gt S.
    trace = np.full((len(R_est), len(R_gt)), -np.inf)
    for S in symmetry_rotations(symmetry):
        trace = np.maximum(trace, np.einsum("nij,mij->nm", R_est, R_gt @ S))
    return _degrees((trace - 1.0) / 2.0)


def rotation_error(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> float:
    """`rotation_errors` of one pair of poses (3, 3), degrees."""
    return float(rotation_errors(R_est, R_gt, symmetry)[0, 0])


def view_errors(
    R_est: np.ndarray,
    R_gt: np.ndarray,
    symmetry: Symmetry = "none",
    ray: np.ndarray | Sequence[float] = (0.0, 0.0, 1.0),
) -> np.ndarray:
    """Viewing-direction error (the paper's pose error): the angle (degrees) between where the two poses
    put the camera as seen from the object, -R^T ray for an object on `ray` (camera frame; both poses on
    it), the smallest over the symmetries; in-plane does not count. Under "full" only elevation (over the
    plane across its axis) is observable (with "+flip", its size only). Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    r = np.asarray(ray, dtype=float) / np.linalg.norm(ray)
    c_est, c_gt = -np.einsum("k,nkj->nj", r, R_est), -np.einsum("k,nkj->nj", r, R_gt)
    if (named := continuous(symmetry)) is not None:
        i = "xyz".index(named.axis)
        el_est, el_gt = np.arcsin(np.clip(c_est[:, i], -1, 1)), np.arcsin(np.clip(c_gt[:, i], -1, 1))
        if named.flip_deg is not None:
            el_est, el_gt = np.abs(el_est), np.abs(el_gt)
        return np.degrees(np.abs(el_est[:, None] - el_gt[None, :]))
    # The pose R_gt @ S puts the camera at S^T c_gt in the object frame.
    return _degrees(np.max([c_est @ (c_gt @ S).T for S in symmetry_rotations(symmetry)], axis=0))


def view_error(
    az_est: float, el_est: float, az_gt: float, el_gt: float, symmetry: Symmetry = "none"
) -> float:
    """`view_errors` of two viewpoints given as azimuth and elevation (degrees, `index.geometry.pose`), degrees."""
    return float(view_errors(lookat_rotation(az_est, el_est), lookat_rotation(az_gt, el_gt), symmetry)[0, 0])


def within(errors: np.ndarray, threshold: float | np.ndarray) -> np.ndarray:
    """Which errors count as within `threshold` (same unit; thresholds broadcast against the errors):
    strictly below it, as BOP counts."""
    return np.asarray(errors) < threshold


# BOP's model-based errors --------------------------------------------------------------------------


def _transform(R: np.ndarray, t: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return np.asarray(pts, float) @ np.asarray(R, float).T + np.ravel(t)


def _symmetric_poses(
    R_gt: np.ndarray, t_gt: np.ndarray, syms: Transformations | None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The poses that look like (R_gt, t_gt): x -> R_gt (S_R x + S_t) + t_gt for every symmetry S."""
    R_gt, t_gt = np.asarray(R_gt, float), np.ravel(t_gt).astype(float)
    if not syms:
        return [(R_gt, t_gt)]
    return [(R_gt @ S_R, R_gt @ np.ravel(S_t) + t_gt) for S_R, S_t in syms]


def _project(K: np.ndarray, pts_cam: np.ndarray) -> np.ndarray:
    uvw = pts_cam @ np.asarray(K, float).T
    return uvw[:, :2] / uvw[:, 2:3]


def mssd(
    R_est: np.ndarray,
    t_est: np.ndarray,
    R_gt: np.ndarray,
    t_gt: np.ndarray,
    pts: np.ndarray,
    syms: Transformations | None = None,
) -> float:
    """Maximum Symmetry-aware Surface Distance (mm): min over symmetries S of max over the model's points x
    of ||(R_est x + t_est) - (R_gt S x + t_gt)||."""
    est = _transform(R_est, t_est, pts)
    return min(
        float(np.linalg.norm(est - _transform(R, t, pts), axis=1).max())
        for R, t in _symmetric_poses(R_gt, t_gt, syms)
    )


def mspd(
    R_est: np.ndarray,
    t_est: np.ndarray,
    R_gt: np.ndarray,
    t_gt: np.ndarray,
    K: np.ndarray,
    pts: np.ndarray,
    syms: Transformations | None = None,
) -> float:
    """Maximum Symmetry-aware Projection Distance (px): as `mssd`, between the points' projections by K."""
    est = _project(K, _transform(R_est, t_est, pts))
    return min(
        float(np.linalg.norm(est - _project(K, _transform(R, t, pts)), axis=1).max())
        for R, t in _symmetric_poses(R_gt, t_gt, syms)
    )


def add(R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray, pts: np.ndarray) -> float:
    """Average Distance of model points (ADD, Hinterstoisser et al. 2012), mm: the mean distance between
    each point under the two poses."""
    return float(np.linalg.norm(_transform(R_est, t_est, pts) - _transform(R_gt, t_gt, pts), axis=1).mean())


def adi(R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray, pts: np.ndarray) -> float:
    """ADD-S (ADI), mm: the mean distance from each point under the true pose to the nearest point under
    the estimate; any symmetry, even one nobody listed, costs nothing."""
    distances, _ = cKDTree(_transform(R_est, t_est, pts)).query(_transform(R_gt, t_gt, pts), k=1)
    return float(np.mean(distances))


def te(t_est: np.ndarray, t_gt: np.ndarray) -> float:
    """Translation error (mm)."""
    return float(np.linalg.norm(np.ravel(t_est) - np.ravel(t_gt)))


def re(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """Rotation error (degrees) as BOP defines it: the angle of R_est R_gt^T, no symmetry forgiven."""
    return rotation_error(R_est, R_gt)


#: The classic criteria: ADD(-S) below a tenth of the diameter (Hinterstoisser et al. 2012), and
#: "5°, 5 cm" (Shotton et al. 2013).
ADD_FRACTION = 0.1
DEG_CM = (5.0, 50.0)


def within_deg_cm(
    R_est: np.ndarray,
    t_est: np.ndarray,
    R_gt: np.ndarray,
    t_gt: np.ndarray,
    syms: Transformations | None = None,
    max_deg: float = DEG_CM[0],
    max_mm: float = DEG_CM[1],
) -> bool:
    """Whether the estimate is within `max_deg` and `max_mm` of one pose that looks like the truth (both at
    once: a symmetry with an offset moves the translation too)."""
    return any(
        re(R_est, R) < max_deg and te(t_est, t) < max_mm for R, t in _symmetric_poses(R_gt, t_gt, syms)
    )


def add_s_correct(errors: np.ndarray, diameters: np.ndarray, fraction: float = ADD_FRACTION) -> np.ndarray:
    """Which ADD (or, for symmetric objects, ADD-S) errors (mm) are within `fraction` of the diameter;
    a missing estimate (nan) is not."""
    return within(missing_as_inf(errors), fraction * np.asarray(diameters, float))


# VSD -------------------------------------------------------------------------------------------------

#: VSD's tolerance for "visible": a rendered surface at most this far behind the measured depth (mm), BOP19.
VSD_DELTA = 15.0


def distance_map(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """A depth map (H, W) turned into distances from the camera centre, as VSD compares (0 stays 0)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    return depth * np.sqrt(x**2 + y**2 + 1.0)


def visibility_mask(depth_test: np.ndarray, depth_model: np.ndarray, delta: float = VSD_DELTA) -> np.ndarray:
    """Where the rendered model would be seen in the test image: it is there, and not more than `delta`
    behind the measured surface; where the sensor measured nothing (0) it counts as seen (BOP19)."""
    return (depth_model > 0) & ((depth_model - depth_test <= delta) | (depth_test == 0))


def vsd(
    depth_est: np.ndarray,
    depth_gt: np.ndarray,
    depth_test: np.ndarray,
    delta: float,
    taus: Sequence[float] | np.ndarray,
    K: np.ndarray | None = None,
) -> np.ndarray:
    """Visible Surface Discrepancy for each misalignment tolerance tau (mm): the fraction of the pixels
    where the object is visible under either pose that are not visible under both within tau of each other.
    depth_est, depth_gt: the model rendered at the two poses; depth_test: the measured depth; all (H, W) mm,
    0 = nothing. With K the depths become distances from the camera centre first, as BOP does.

    The estimate's visible part also takes the truth's visible pixels that the estimate covers, so an
    estimate hidden behind the measured surface where the truth is seen is not punished twice."""
    if K is not None:
        depth_est, depth_gt, depth_test = (distance_map(d, K) for d in (depth_est, depth_gt, depth_test))
    visib_gt = visibility_mask(depth_test, depth_gt, delta)
    visib_est = visibility_mask(depth_test, depth_est, delta) | (visib_gt & (depth_est > 0))
    union = int((visib_gt | visib_est).sum())
    if union == 0:  # nothing of the object visible under either pose: BOP calls that wholly wrong
        return np.ones(len(taus))
    gap = np.abs(depth_est - depth_gt)[visib_gt & visib_est]
    return np.array([1.0 - np.count_nonzero(gap < tau) / union for tau in taus])


def render_depths(
    renderer: FrameRenderer,
    mesh: trimesh.Trimesh,
    K: np.ndarray,
    width: int,
    height: int,
    R_est: np.ndarray,
    t_est: np.ndarray,
    R_gt: np.ndarray,
    t_gt: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The model's depth maps (H, W) mm at the estimated and the true pose, for `vsd`. Call it on the
    renderer's own thread (EGL)."""
    _, depth_est = renderer.render_frame([(mesh, R_est, t_est)], K, width, height)
    _, depth_gt = renderer.render_frame([(mesh, R_gt, t_gt)], K, width, height)
    return depth_est, depth_gt


def missing_as_inf(errors: np.ndarray | Sequence[float]) -> np.ndarray:
    """The errors with a missing estimate's (nan) made infinite: wrong at every threshold, as BOP counts."""
    e = np.asarray(errors, float)
    return np.where(np.isnan(e), np.inf, e)
