"""Pose errors, the one definition the evaluation, the service's tests and training use (the names and
units of bop_toolkit's `pose_error.py`, so our numbers compare with BOP's).

Conventions: `R_est`, `R_gt` are rotations R_m2c (object to camera, OpenCV axes: `index.pose`), one (3, 3)
or a stack (N, 3, 3); `t_est`, `t_gt` translations in mm; errors are degrees (angles) or mm (distances).
Cosines are clipped to [-1, 1] before `arccos`. Every error respects the object's symmetry
(`index.symmetry`): the smallest error over the poses that look the same.

- `rotation_errors` / `rotation_error`: the 3-D rotation angle, in-plane included;
- `view_errors` / `view_error`: the angle between viewing directions (the paper's error; in-plane does
  not count);
- `within`: an error counts as within t when it is strictly below t, as BOP counts.

BOP's model-based errors (Hodaň et al., BOP 2018/2019/2020), the model's points `pts` (N, 3) in mm:
- `mssd` (mm), `mspd` (px): the largest distance over the model's points, 3-D or projected, the smallest
  over the object's symmetry transformations (`index.symmetry.symmetry_transformations`);
- `add`, `adi` (ADD-S) (mm): the mean distance between corresponding / nearest transformed points;
- `te` (mm), `re` (degrees): translation and rotation errors; `within_deg_cm`: the classic "5°, 5 cm";
- `vsd`: the visible surface discrepancy, from depth maps rendered at both poses (`render_depths`);
- `bop_recall`: the recall over BOP19's thresholds and the average recall AR, as the challenge scores, from
  one error per target; `bop_matches`: BOP's matching of several scored estimates to an image's instances."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from index.pose import lookat_rotation
from index.symmetry import Symmetry, symmetry_rotations

if TYPE_CHECKING:  # pyrender is heavy and needs EGL: only `render_depths` takes a renderer
    import trimesh

    from index.render import Renderer

#: Symmetry transformations x -> R x + t of the object frame (`index.symmetry.symmetry_transformations`).
Transformations = Sequence[tuple[np.ndarray, np.ndarray]]


def _stack(R: np.ndarray) -> np.ndarray:
    return np.asarray(R, dtype=float).reshape(-1, 3, 3)


def _degrees(cos: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _is_full(symmetry: Symmetry) -> bool:
    return isinstance(symmetry, str) and symmetry == "full"


def rotation_errors(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """3-D rotation error, in-plane included: the smallest angle (degrees) between each R_est and any
    pose R_gt @ S that looks the same (S a symmetry of the object). Under "full" only where the two
    poses put the object's z axis is observable. Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    if _is_full(symmetry):
        return _degrees(R_est[:, :, 2] @ R_gt[:, :, 2].T)
    # trace(R_est^T R_gt S) is the sum of the element-wise product of R_est and R_gt S.
    trace = np.max([np.einsum("nij,mij->nm", R_est, R_gt @ S) for S in symmetry_rotations(symmetry)], axis=0)
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
    it), the smallest over the symmetries; in-plane does not count. Under "full" only elevation is
    observable. Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    r = np.asarray(ray, dtype=float) / np.linalg.norm(ray)
    c_est, c_gt = -np.einsum("k,nkj->nj", r, R_est), -np.einsum("k,nkj->nj", r, R_gt)
    if _is_full(symmetry):
        el_est, el_gt = np.arcsin(np.clip(c_est[:, 2], -1, 1)), np.arcsin(np.clip(c_gt[:, 2], -1, 1))
        return np.degrees(np.abs(el_est[:, None] - el_gt[None, :]))
    # The pose R_gt @ S puts the camera at S^T c_gt in the object frame.
    return _degrees(np.max([c_est @ (c_gt @ S).T for S in symmetry_rotations(symmetry)], axis=0))


def view_error(
    az_est: float, el_est: float, az_gt: float, el_gt: float, symmetry: Symmetry = "none"
) -> float:
    """`view_errors` of two viewpoints given as azimuth and elevation (degrees, `index.pose`), degrees."""
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
    return within(_missing_as_inf(errors), fraction * np.asarray(diameters, float))


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
    renderer: Renderer,
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


# Recall and AR, as BOP19 scores -------------------------------------------------------------------

_STEPS = np.round(np.arange(1, 11) * 0.05, 2)  # 0.05, 0.10, ..., 0.50
#: BOP19's thresholds: MSSD's are fractions of the object's diameter; MSPD's are pixels in a 640 px wide
#: image (scaled by width / 640); VSD's taus are fractions of the diameter, its thresholds on the error.
MSSD_THRESHOLDS = _STEPS
MSPD_THRESHOLDS = np.arange(5.0, 51.0, 5.0)
MSPD_REFERENCE_WIDTH = 640.0
VSD_TAUS = _STEPS
VSD_THRESHOLDS = _STEPS


def _missing_as_inf(errors: np.ndarray | Sequence[float]) -> np.ndarray:
    e = np.asarray(errors, float)
    return np.where(np.isnan(e), np.inf, e)


def recall(errors: np.ndarray | Sequence[float], thresholds: np.ndarray) -> np.ndarray:
    """The fraction of targets whose error is strictly below each threshold; a target without an estimate
    (nan or inf) is wrong at every threshold. errors (N,), thresholds (T,) or per target (N, T) -> (T,)."""
    e = _missing_as_inf(errors)
    if e.ndim != 1 or len(e) == 0:
        raise ValueError(f"recall needs one error per target, at least one target; got shape {e.shape}")
    th = np.asarray(thresholds, float)
    return within(e[:, None], th if th.ndim == 2 else th[None, :]).mean(axis=0)


@dataclass(frozen=True)
class BopRecall:
    """Recall per BOP19 threshold: mssd (10,), mspd (10,), vsd (taus 10, thresholds 10) or None."""

    mssd: np.ndarray
    mspd: np.ndarray
    vsd: np.ndarray | None = None

    @property
    def ar_mssd(self) -> float:
        return float(self.mssd.mean())

    @property
    def ar_mspd(self) -> float:
        return float(self.mspd.mean())

    @property
    def ar_vsd(self) -> float | None:
        return None if self.vsd is None else float(self.vsd.mean())

    @property
    def ar(self) -> float:
        """The average recall: the mean of AR_VSD, AR_MSSD and AR_MSPD (the latter two without depth)."""
        parts = [self.ar_mssd, self.ar_mspd] + ([] if self.ar_vsd is None else [self.ar_vsd])
        return float(np.mean(parts))


def bop_recall(
    mssd_errors: np.ndarray | Sequence[float],
    mspd_errors: np.ndarray | Sequence[float],
    diameters: np.ndarray | Sequence[float],
    image_width: float,
    vsd_errors: np.ndarray | None = None,
) -> BopRecall:
    """BOP19's recalls over all targets pooled (not per object), one error per target (nan: no estimate):
    mssd_errors (N,) mm, mspd_errors (N,) px, diameters (N,) mm, vsd_errors (N, len(VSD_TAUS)) at the taus
    `VSD_TAUS * diameter`. Matching estimates to targets (BOP keeps the best-scored) is the caller's."""
    d = np.asarray(diameters, float)
    mssd_r = recall(mssd_errors, d[:, None] * MSSD_THRESHOLDS[None, :])
    mspd_r = recall(mspd_errors, MSPD_THRESHOLDS * image_width / MSPD_REFERENCE_WIDTH)
    if vsd_errors is None:
        return BopRecall(mssd_r, mspd_r)
    v = np.asarray(vsd_errors, float)
    if v.shape != (len(d), len(VSD_TAUS)):
        raise ValueError(f"vsd_errors must be (targets, {len(VSD_TAUS)} taus); got {v.shape}")
    return BopRecall(mssd_r, mspd_r, np.stack([recall(v[:, i], VSD_THRESHOLDS) for i in range(v.shape[1])]))


def bop_matches(
    scores: np.ndarray | Sequence[float], errors: np.ndarray, thresholds: np.ndarray | Sequence[float]
) -> np.ndarray:
    """BOP's matching of one image's estimates of one object to its G annotated instances, at each
    threshold: only the G best-scored estimates count; in descending score, each takes the still
    unmatched instance it fits best, when that error is below the threshold. scores (E,), errors (E, G)
    (nan: not computed, never matches), thresholds (T,) -> found (T, G) bool. The count of found targets
    over all images, divided by the count of targets, is `recall`'s figure with several estimates."""
    e = _missing_as_inf(errors)
    if e.ndim != 2 or len(e) != len(scores):
        raise ValueError(f"errors must be (estimates {len(scores)}, instances); got shape {e.shape}")
    n_gt = e.shape[1]
    order = np.argsort(-np.asarray(scores, float), kind="stable")[:n_gt]
    found = np.zeros((len(thresholds), n_gt), bool)
    for k, th in enumerate(thresholds):
        for i in order:
            free = np.where(found[k], np.inf, e[i])
            j = int(np.argmin(free))
            if free[j] < th:
                found[k, j] = True
    return found
