"""The pose conventions of index/geometry/pose.py, pinned."""

import numpy as np
import pytest

from index.geometry.pose import (
    View,
    camera_centre,
    lookat_rotation,
    pose_to_view,
    view_to_pose,
)
from index.geometry.pose_error import rotation_error


def project_dir(R: np.ndarray, v_obj) -> np.ndarray:
    """Image-plane direction (x right, y down) of an object-frame direction seen at the optical axis."""
    d = R @ np.asarray(v_obj, float)
    return d[:2] / np.linalg.norm(d[:2])


@pytest.mark.parametrize(
    "az,el,ip", [(0, 30, 0), (30, 40, 15), (250, 10, -120), (359, 85, 179), (0, 90, 0), (123, 90, 40)]
)
def test_view_pose_round_trip(az, el, ip):
    R, t = view_to_pose(View(az, el, ip, 650))
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1)
    back = pose_to_view(R, t)
    R2, t2 = view_to_pose(back)
    assert rotation_error(R, R2) < 1e-4 and np.allclose(t, t2)
    assert back.distance == pytest.approx(650)
    if el < 90:  # at the pole azimuth folds into in-plane
        assert back.azimuth == pytest.approx(az % 360, abs=1e-6)
        assert back.inplane == pytest.approx(ip, abs=1e-6)


def test_off_axis_round_trip():
    v = View(77, 33, -25, 900)
    R, t = view_to_pose(v, ray=[0.3, -0.2, 1.0])
    assert np.allclose(t / np.linalg.norm(t), np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0]))
    back = pose_to_view(R, t)
    assert (back.azimuth, back.elevation, back.inplane, back.distance) == pytest.approx((77, 33, -25, 900))


def test_camera_centre_and_axes():
    R, t = view_to_pose(View(90, 0, 0, 400))
    # camera on +y, looking at the origin: the camera centre -R^T t is at (0, 400, 0)
    assert np.allclose(-R.T @ t, [0, 400, 0], atol=1e-9)
    assert np.allclose(camera_centre(90, 0, 400), [0, 400, 0], atol=1e-9)
    # the optical axis points from the camera to the object: object +y is towards the camera
    assert np.allclose(R @ [0, 1, 0], [0, 0, -1], atol=1e-9)


def test_inplane_zero_puts_object_z_up():
    for az, el in [(0, 20), (135, 60), (300, 5)]:
        R = lookat_rotation(az, el)
        assert np.allclose(project_dir(R, [0, 0, 1]), [0, -1], atol=1e-9)  # up in the image


def test_inplane_positive_is_counter_clockwise():
    R, _ = view_to_pose(View(40, 30, 90, 400))
    # object z, up at in-plane 0, turned 90 deg counter-clockwise points left
    assert np.allclose(project_dir(R, [0, 0, 1]), [-1, 0], atol=1e-9)


def test_pole_limit():
    # at the pole, azimuth 0: image up is the object's -x, and it is the limit of el -> 90
    R = lookat_rotation(0, 90)
    assert np.allclose(project_dir(R, [-1, 0, 0]), [0, -1], atol=1e-9)
    assert rotation_error(R, lookat_rotation(0, 89.999)) < 0.01
    assert rotation_error(lookat_rotation(70, 90), lookat_rotation(70, 89.999)) < 0.01
