"""What a pose refinement returns (`Fit`) and the small rigid-motion algebra the refinements share: a pose
moved by a twist (`apply_twist`: 3 rotation then 3 translation parameters, applied on the camera's side,
so the translation part moves the object in the camera's axes, mm), and the cross product of 3-vectors
their inner loops take (`cross`).

Two refinements start from an answer's pose (a template's viewpoint and roll at the distance the query was
cut at) and move it over all six degrees of freedom: with colour, the mesh's outline against the frame
(`index.refine.colour`); with depth, the mesh's points against the measured surface (`index.refine.depth`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from index.geometry.pose import rotation_of


@dataclass(frozen=True)
class Fit:
    """A refined pose: `R` (3, 3) model to camera and `t` (3,) mm (BOP's cam_R_m2c, cam_t_m2c; OpenCV
    camera axes). `score`: how well the pose fits what was measured, in [0, 1] (the refinement's own
    measure, higher is better; comparable between poses of one object in one frame, not across methods);
    `start_score` the same at the starting pose; `iterations` run; `moved`: the refinement kept its result
    (False: it found nothing better than the start, and `R`, `t` are the start's); `failed`: the fit raised
    (`failed_at`): nothing was measured, and what is judged by its fit is rejected, never let through."""

    R: np.ndarray
    t: np.ndarray
    score: float
    start_score: float
    iterations: int
    moved: bool
    failed: bool = False


def failed_at(R: np.ndarray, t: np.ndarray) -> Fit:
    """The `Fit` of a fit that raised: the start's pose, score 0, `failed`."""
    return Fit(np.asarray(R, float), np.asarray(t, float), 0.0, 0.0, 0, False, failed=True)


def apply_twist(R: np.ndarray, t: np.ndarray, twist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) moved by `twist` (6,): rotation (axis-angle, radians, about the object's origin as the camera
    sees it) then translation (mm, camera axes). Rotating about the object's origin, not the camera's,
    keeps a rotation step from also sliding the object across the image."""
    dR = rotation_of(np.asarray(twist[:3], float))
    return dR @ np.asarray(R, float), np.asarray(t, float) + np.asarray(twist[3:], float)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`np.cross` of 3-vectors along the last axis (broadcast), the same products and differences in the same
    order, so the same bits, without its checks and axis moves: an ICP step's Jacobian (800 rows) took 44 us
    with `np.cross` and 13 with this, and the depth fit takes one every iteration (docs/experiments.md,
    "The cross product in the fits")."""
    a, b = np.asarray(a), np.asarray(b)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), np.result_type(a, b))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    np.multiply(a1, b2, out=out[..., 0])
    out[..., 0] -= a2 * b1
    np.multiply(a2, b0, out=out[..., 1])
    out[..., 1] -= a0 * b2
    np.multiply(a0, b1, out=out[..., 2])
    out[..., 2] -= a1 * b0
    return out
