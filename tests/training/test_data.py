"""Training data: the frame split and the in-plane variants of templates."""

import numpy as np
import pytest

from index.templates.render import Renderer
from training.data import DataConfig, TrainingData
from training.render_cache import build, paint_out
from training.splits import SplitConfig, frames_of, split_frames


def test_split_blocks_and_gaps():
    split = split_frames(range(100), SplitConfig(val=((0.2, 0.4),), test=((0.7, 0.9),), gap=2))
    by = frames_of(split)
    assert by["val"] == list(range(20, 40)) and by["test"] == list(range(70, 90))
    gaps = sorted(f for f, s in split.items() if s == "gap")
    assert gaps == [18, 19, 40, 41, 68, 69, 90, 91]
    assert len(by["train"]) == 100 - 40 - 8
    assert not set(by["train"]) & (set(by["val"]) | set(by["test"]))


def test_split_of_unordered_ids():
    split = split_frames([30, 10, 20, 0, 40], SplitConfig(val=((0.0, 0.2),), test=((0.8, 1.0),), gap=0))
    assert frames_of(split) == {"train": [10, 20, 30], "val": [0], "test": [40]}


@pytest.fixture(scope="module")
def rolled() -> TrainingData:
    return build([], DataConfig(shapes=1, shape_views=20, template_inplane_step=90.0, seed=1))


def test_templates_turn_like_the_services(rolled):
    """Template (viewpoint v, in-plane variant k) is the service's render of that view: the same pixels as
    `Renderer.render` at in-plane k * step (the index turns the same wide render)."""
    data = rolled
    assert data.n_templates == 301 * 4 and len(data.inplane) == 4
    mesh = None
    r = Renderer(window_mm=data.cfg.window_mm)
    try:
        from index.templates.shapes import random_shape

        mesh = random_shape(np.random.default_rng(1))  # the first shape `build` made with seed 1
        for t in (0, 5, 4 * 150 + 2, 4 * 300 + 3):
            view = data.template_views[t]
            rgb, depth = data.template_patch(0, t)
            want = r.render(mesh, [view])
            assert view.inplane == 90.0 * (t % 4)
            # the same object, turned the same way: masks agree but for edge pixels
            assert np.mean((depth > 0) != (want.depth[0] > 0)) < 0.01
    finally:
        r.close()


@pytest.mark.slow  # over ~2 s (an export, a render): `make test`, not `make check`
def test_single_solids_are_added_after_the_shapes_and_change_nothing_before_them(rolled):
    """`simple_shapes` appends one-solid objects drawn from their own stream: the composed shape and its
    samples are those of the config without them, to the pixel."""
    more = build(
        [], DataConfig(shapes=1, simple_shapes=1, shape_views=20, template_inplane_step=90.0, seed=1)
    )
    assert more.names == ["shape_000", "solid_000"] and rolled.names == ["shape_000"]
    assert np.array_equal(more.t_depth[0], rolled.t_depth[0])
    first = more.s_obj == 0
    assert np.array_equal(more.s_depth[first], rolled.s_depth) and np.array_equal(more.s_R[first], rolled.s_R)
    assert (more.t_depth[1] > 0).any()  # the solid is drawn
    assert DataConfig().key([]) != DataConfig(simple_shapes=1).key([])


def test_a_single_solid_is_one_body_and_may_be_thin():
    from index.templates.shapes import random_shape

    rng = np.random.default_rng(3)
    solids = [random_shape(rng, n_parts=1) for _ in range(40)]
    assert all(m.body_count == 1 for m in solids)
    # the oriented box's thinnest side against its longest: a marker or a flat box among them
    ratios = [np.sort(m.bounding_box_oriented.primitive.extents) for m in solids]
    assert min(r[0] / r[2] for r in ratios) < 0.3
    assert max(r[0] / r[2] for r in ratios) > 0.6


def test_paint_out_leaves_no_trace_of_the_object():
    rng = np.random.default_rng(0)
    frame = (rng.random((60, 80, 3)) * 40 + 100).astype(np.uint8)
    mask = np.zeros((60, 80), bool)
    mask[20:35, 30:50] = True
    frame[mask] = (255, 0, 0)  # a red object
    out = paint_out(frame, mask)
    assert out[mask][:, 0].max() < 200  # no red left
    assert np.array_equal(out[:5], frame[:5])  # far from it, untouched
