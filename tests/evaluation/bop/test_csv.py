"""BOP19 results files (`evaluation.bop.csv`): the exact format, and a round trip that loses nothing."""

import numpy as np
import pytest

from evaluation.bop.csv import Estimate, read_bop_csv, write_bop_csv
from index.geometry.pose import View, view_to_pose


def test_round_trip_keeps_every_number(tmp_path):
    rng = np.random.default_rng(3)
    estimates = []
    for i in range(3):
        R, _ = view_to_pose(View(*rng.uniform([0, 0, -180], [360, 90, 180])))
        t = rng.uniform([-100, -100, 300], [100, 100, 1200])
        estimates.append(Estimate(2, 10 + i, 5 + i, float(rng.uniform()), R, t, 0.25 if i else -1.0))
    path = tmp_path / "posedesc_lmo-test.csv"
    assert write_bop_csv(path, estimates) == 3
    back = read_bop_csv(path)
    assert len(back) == 3
    for a, b in zip(estimates, back, strict=True):
        assert (a.scene_id, a.im_id, a.obj_id, a.score, a.time) == (
            b.scene_id,
            b.im_id,
            b.obj_id,
            b.score,
            b.time,
        )
        assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)


def test_the_format_is_bops(tmp_path):
    path = tmp_path / "r.csv"
    write_bop_csv(path, [Estimate(1, 3, 8, 0.5, np.eye(3), np.array([1.0, 2.0, 500.0]))])
    lines = path.read_text().splitlines()
    assert lines[0] == "scene_id,im_id,obj_id,score,R,t,time"
    assert lines[1] == "1,3,8,0.5,1.0 0.0 0.0 0.0 1.0 0.0 0.0 0.0 1.0,1.0 2.0 500.0,-1.0"


def test_a_malformed_file_names_its_line(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,3,8,0.5,1 0 0 0 1 0 0 0,1 2 3,-1\n")
    with pytest.raises(ValueError, match=r"bad.csv:2: .*R has 8 numbers"):
        read_bop_csv(path)
    path.write_text("scene,im,obj\n")
    with pytest.raises(ValueError, match="header"):
        read_bop_csv(path)
    with pytest.raises(ValueError, match="9 and 3|R of 9"):
        write_bop_csv(path, [Estimate(1, 3, 8, 0.5, np.eye(2), np.zeros(3))])
