"""Each answer's pose (`service.poses`) against BOP's ground truth on the real LM-O test frames: a match at
an instance's annotated view (`pose_to_view` of its cam_R_m2c, cam_t_m2c), seen along the ray through
where its origin projects at ‖t‖, gives the annotated R and t back."""

from __future__ import annotations

import numpy as np

from index.data.bop import BopDataset
from index.geometry.pose import pose_to_view
from index.geometry.pose_error import rotation_error
from index.store import Match
from service.poses import match_pose


def so3(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def test_a_match_at_the_annotated_view_gives_the_annotated_pose(lmo):
    insts = list(BopDataset(lmo).instances(2))
    assert len(insts) > 100
    off_axis = []
    for inst in insts:
        view = pose_to_view(inst.R, inst.t)
        match = Match(1, "obj", view.azimuth, view.elevation, view.inplane, distance=0.1)
        u, v = inst.centre_uv
        ray = np.linalg.inv(inst.K) @ np.array([u, v, 1.0])
        R, t = match_pose(match, ray / np.linalg.norm(ray), view.distance)
        assert np.abs(so3(R) - inst.R).max() < 1e-6, (inst.frame_id, inst.obj_id)
        assert np.linalg.norm(t - inst.t) < 1.0, (inst.frame_id, inst.obj_id, t, inst.t)
        # the ray matters: the same view on the optical axis is another rotation
        on_axis, _ = match_pose(match, np.array([0.0, 0.0, 1.0]), view.distance)
        off_axis.append(rotation_error(on_axis, inst.R))
    assert max(off_axis) > 5.0
