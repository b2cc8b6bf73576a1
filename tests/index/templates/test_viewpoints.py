"""`index.templates.viewpoints`, the paper's viewpoint sets on the half-sphere: template and training sets,
and the in-plane steps."""

import numpy as np

from index.geometry.pose import camera_centre
from index.templates.viewpoints import hemisphere, icosphere, inplane_steps, sphere_views, viewpoints


def test_paper_template_and_training_sets():
    assert len(icosphere(3)) == 642 and len(icosphere(4)) == 2562
    t, tr = hemisphere(3), hemisphere(4)
    assert len(t) == 301 and len(tr) == 1241
    assert abs(t[:, 1].min() - 6.74) < 0.01
    assert (t[:, 1] > 89.999).sum() == 1  # one at the pole
    assert np.allclose(np.linalg.norm(icosphere(3), axis=1), 1)


def test_training_set_contains_template_set():
    t, tr = hemisphere(3), hemisphere(4)
    d = np.abs(t[:, None, :] - tr[None, :, :]).sum(-1).min(1)
    assert d.max() < 1e-6


def test_inplane_steps_and_views():
    assert list(inplane_steps(0)) == [0]
    assert list(inplane_steps(15, 45)) == [-45, -30, -15, 0, 15, 30, 45]
    views = sphere_views(3, inplane_steps(20, 40), distance=500)
    assert len(views) == 301 * 5
    assert [v.inplane for v in views[:5]] == [-40, -20, 0, 20, 40]  # viewpoint-major
    assert views[5].azimuth != views[0].azimuth or views[5].elevation != views[0].elevation
    assert {v.distance for v in views} == {500}


def test_the_whole_sphere_is_the_upper_half_then_the_rest():
    """An object that may lie on any face is seen from below its xy plane too: every icosphere vertex, the
    upper half's first and unchanged, each camera direction once."""
    whole, upper = viewpoints(3, whole=True), hemisphere(3)
    assert len(whole) == 642 and np.array_equal(whole[:301], upper)
    assert (whole[301:, 1] <= 1e-6).all() and (whole[:, 1] < -89.999).sum() == 1  # the lower pole, once
    directions = [camera_centre(az, el) for az, el in whole]
    assert len({tuple(np.round(d, 6)) for d in directions}) == 642
    # the lower half mirrors the upper: every viewpoint below has its twin above
    assert sorted(np.round(-whole[whole[:, 1] < -1e-6, 1], 4)) == sorted(np.round(upper[:, 1], 4))
    views = sphere_views(3, inplane_steps(30, 360), whole=True)
    assert len(views) == 642 * 12
