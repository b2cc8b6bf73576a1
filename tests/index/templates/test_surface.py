"""`index.templates.surface`: how far the origin lies behind the surface at a template's centre, per viewpoint."""

from __future__ import annotations

import pytest
import trimesh

from index.geometry.pose import View
from index.templates.surface import SURFACE_KEY, offset_of, template_offsets


def test_a_box_s_origin_lies_half_its_depth_behind_the_face_seen(renderer):
    box = trimesh.creation.box(extents=[60.0, 100.0, 140.0])  # origin at its centre
    views = [
        View(0.0, 90.0, 0.0, 400.0),  # from above: the top face, 70 mm in front of the origin
        View(0.0, 0.0, 0.0, 400.0),  # from +x: 30 mm
        View(90.0, 0.0, 0.0, 400.0),  # from +y: 50 mm
        View(90.0, 0.0, 30.0, 400.0),  # an in-plane variant: not a viewpoint of its own
    ]
    t = renderer.render(box, views)
    rows = template_offsets(t.depth, t.views, t.window_mm)
    assert rows.shape == (3, 3)
    assert rows[:, 2] == pytest.approx([70.0, 30.0, 50.0], abs=1.5)


def test_the_nearest_stored_viewpoint_gives_the_offset():
    extra = {SURFACE_KEY: [[0.0, 90.0, 70.0], [0.0, 0.0, 30.0], [90.0, 0.0, 50.0]]}
    assert offset_of(extra, 359.0, 1.0) == 30.0  # across azimuth 0/360
    assert offset_of(extra, 180.0, 88.0) == 70.0  # near the pole, whatever the azimuth
    assert offset_of(extra, 85.0, 5.0) == 50.0
    assert offset_of({}, 0.0, 0.0) is None  # registered before offsets were kept
