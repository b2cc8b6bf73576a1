"""The LineMOD baseline's template index: indices continue across calls to `add` (the benchmark adds one
object at a time)."""

from __future__ import annotations

import numpy as np

from evaluation.linemod import LineModIndex, top_k
from index.pose import View


def test_indices_continue_across_adds(renderer, l_shape):
    views = [View(30.0, 40.0, 0.0, 400.0), View(210.0, 70.0, 0.0, 400.0), View(120.0, 15.0, 0.0, 400.0)]
    t = renderer.render(l_shape, views)
    index = LineModIndex("rgb", renderer.window_mm)
    index.add(np.array([7]), t.rgb[:1], None, t.depth[:1] > 0, 400.0)
    index.add(np.array([8, 9]), t.rgb[1:], None, t.depth[1:] > 0, 400.0)
    for i in range(3):
        idx, sim = top_k(index.similarities(t.rgb[i], None, 400.0), 3)
        assert idx[0] == i and sim[0] > 90.0, (i, idx, sim)
