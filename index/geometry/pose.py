"""Pose conventions, stated once. Everything else (renderer, patches, API, evaluation) uses these.

Object frame: the mesh's own frame, millimetres.

Viewpoint (azimuth, elevation, distance): the camera centre sits at
    C = distance * (cos(el) cos(az), cos(el) sin(az), sin(el))
in the object frame, azimuth measured around the object's +z axis from +x towards +y, elevation above
the object's xy plane, both in degrees. The camera looks at the object's origin.

In-plane (degrees): the camera's roll about its optical axis, seen in the image. At in-plane 0 the
object's +z axis projects straight up in the image; at in-plane θ the object appears rotated by θ
counter-clockwise (as a person sees the picture). At the pole the "up" direction is the limit for
elevation -> 90° at the given azimuth, i.e. image-up = the elevation tangent
(-sin(el) cos(az), -sin(el) sin(az), cos(el)); for azimuth 0 at the pole that is the object's -x.

Camera axes: OpenCV (x right, y down, z forward), as BOP's `cam_R_m2c`, `cam_t_m2c` (mm):
X_cam = R_m2c @ X_obj + t_m2c. pyrender uses OpenGL axes (y up, z backwards): see `opengl_from_opencv`.

An object off the optical axis is seen along the ray through its origin. A pose is then
R_m2c = R_align(ray) @ R_roll(inplane) @ R_lookat(az, el), t_m2c = distance * ray, where R_align is the
smallest rotation taking the optical axis onto the ray. `pose_to_view` inverts this exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Flips y and z: OpenCV camera axes <-> OpenGL camera axes (its own inverse).
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class View:
    """A viewpoint plus in-plane roll; angles in degrees, distance in mm."""

    azimuth: float
    elevation: float
    inplane: float = 0.0
    distance: float = 400.0


def camera_centre(azimuth: float, elevation: float, distance: float = 1.0) -> np.ndarray:
    """Camera centre in the object frame. Shape: (3,)."""
    az, el = np.radians(azimuth), np.radians(elevation)
    return distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def lookat_rotation(azimuth: float, elevation: float) -> np.ndarray:
    """R_m2c of a camera on the view sphere looking at the origin, in-plane 0. Shape: (3, 3)."""
    az, el = np.radians(azimuth), np.radians(elevation)
    z_cam = -camera_centre(azimuth, elevation)  # forward: towards the origin
    up = np.array([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])  # image up
    y_cam = -up  # OpenCV y points down
    x_cam = np.cross(y_cam, z_cam)
    return np.stack([x_cam, y_cam, z_cam])


def roll_rotation(inplane: float) -> np.ndarray:
    """Rotation about the optical axis that turns the image content by `inplane` degrees counter-clockwise.

    With y pointing down, a visually counter-clockwise turn is a negative turn in (x, y)."""
    c, s = np.cos(np.radians(inplane)), np.sin(np.radians(inplane))
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def align_rotation(ray: np.ndarray) -> np.ndarray:
    """Smallest rotation taking the optical axis (0, 0, 1) onto `ray` (camera frame). Shape: (3, 3)."""
    r = np.asarray(ray, dtype=float)
    r = r / np.linalg.norm(r)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, r), float(z @ r)
    if c < -1 + 1e-12:  # ray straight backwards: any half-turn about an axis in the image plane
        return np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def view_to_pose(view: View, ray: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R_m2c, t_m2c in mm) of a view; `ray` (camera frame) places the object off the optical axis."""
    R = roll_rotation(view.inplane) @ lookat_rotation(view.azimuth, view.elevation)
    if ray is None:
        return R, np.array([0.0, 0.0, view.distance])
    ray = np.asarray(ray, dtype=float) / np.linalg.norm(ray)
    return align_rotation(ray) @ R, view.distance * ray


def pose_to_view(R_m2c: np.ndarray, t_m2c: np.ndarray) -> View:
    """The view of a BOP pose: azimuth/elevation of the camera centre, in-plane about the ray to the object."""
    R, t = np.asarray(R_m2c, dtype=float).reshape(3, 3), np.asarray(t_m2c, dtype=float).reshape(3)
    distance = float(np.linalg.norm(t))
    c = -R.T @ t  # camera centre in the object frame
    azimuth = float(np.degrees(np.arctan2(c[1], c[0])))
    elevation = float(np.degrees(np.arcsin(np.clip(c[2] / distance, -1.0, 1.0))))
    # Undo the off-axis alignment, then what is left of R relative to the look-at frame is the roll.
    R_roll = align_rotation(t).T @ R @ lookat_rotation(azimuth, elevation).T
    inplane = float(np.degrees(np.arctan2(R_roll[0, 1], R_roll[0, 0])))
    return View(azimuth % 360.0, elevation, inplane, distance)


def opengl_camera_pose(R_m2c: np.ndarray, t_m2c: np.ndarray) -> np.ndarray:
    """Camera-to-object 4x4 pose in OpenGL axes, as pyrender wants for its camera node."""
    R_gl = OPENGL_FROM_OPENCV @ R_m2c
    t_gl = OPENGL_FROM_OPENCV @ t_m2c
    pose = np.eye(4)
    pose[:3, :3] = R_gl.T
    pose[:3, 3] = -R_gl.T @ t_gl
    return pose


def wrap_degrees(angle: float | np.ndarray) -> float | np.ndarray:
    """Wraps angles to (-180, 180] (0 comes out as +0)."""
    return -((-np.asarray(angle, dtype=float) + 180.0) % 360.0 - 180.0) + 0.0


def rotation_of(w: np.ndarray) -> np.ndarray:
    """The rotation by the axis-angle vector `w` (3,), radians (Rodrigues)."""
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = np.asarray(w, float) / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * (kx @ kx)
