"""The LineMOD baseline's template index: indices continue across calls to `add` (the benchmark adds one
object at a time)."""

from __future__ import annotations

import numpy as np

from evaluation.baselines.linemod import LineModIndex, top_k
from index.geometry.pose import View


def test_indices_continue_across_adds(renderer, l_shape):
    views = [View(30.0, 40.0, 0.0, 400.0), View(210.0, 70.0, 0.0, 400.0), View(120.0, 15.0, 0.0, 400.0)]
    t = renderer.render(l_shape, views)
    index = LineModIndex("rgb", renderer.window_mm)
    index.add(np.array([7]), t.rgb[:1], None, t.depth[:1] > 0, 400.0)
    index.add(np.array([8, 9]), t.rgb[1:], None, t.depth[1:] > 0, 400.0)
    for i in range(3):
        idx, sim = top_k(index.similarities(t.rgb[i], None, 400.0), 3)
        assert idx[0] == i and sim[0] > 90.0, (i, idx, sim)


def test_templates_tied_with_another_of_their_object_are_kept(renderer, l_shape):
    """OpenCV's `Detector.match` drops a match that equals another of its class in position and score;
    two identical templates of one object must both come back, equally similar."""
    views = [View(30.0, 40.0, 0.0, 400.0), View(30.0, 40.0, 0.0, 400.0), View(210.0, 70.0, 0.0, 400.0)]
    t = renderer.render(l_shape, views)
    index = LineModIndex("depth", renderer.window_mm)
    index.add(np.array([7, 7, 7]), None, t.depth, t.depth > 0, 400.0)
    sims = index.similarities(None, t.depth[0], 400.0)
    assert 0 in sims and 1 in sims and sims[0] == sims[1], sims


def test_templates_are_scored_in_their_own_place(renderer, l_shape):
    """Test patches are cut at the object's centre, as templates are: a template is scored where it sits
    in its own image, not wherever in the patch it fits best."""
    t = renderer.render(l_shape, [View(30.0, 40.0, 0.0, 400.0)])
    index = LineModIndex("depth", renderer.window_mm)
    index.add(np.array([7]), None, t.depth, t.depth > 0, 400.0)
    assert index.similarities(None, t.depth[0], 400.0)[0] > 90.0
    shifted = np.zeros_like(t.depth[0])
    shifted[:, 12:] = t.depth[0][:, :-12]  # the same object, 12 px (three grid steps) off the centre
    assert index.similarities(None, shifted, 400.0) == {}
