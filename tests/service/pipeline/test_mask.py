"""Models with a mask: the query is described black outside it, and re-ranked where the object is.

An RGB-D model made from a colour trunk model (`posedesc export --as-rgbd`) cuts its mask from depth: a
registered object seen in front of a wall of clutter is answered as that object, at its viewpoint, and
the clutter neither moves the answer nor its re-ranking score."""

from __future__ import annotations

import numpy as np
import pytest
from service_helpers import depth_png, png

from index.geometry.pose import View
from index.templates.register import register
from service.pipeline.query import Query
from service.recognition import recognise
from service.settings import Settings
from service.state import close_state, load_state

pytestmark = pytest.mark.xdist_group("pipeline-mask")  # the module's exported model made once, on one worker


@pytest.fixture(scope="module")
def rgbd_masked(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("masked-models")
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    export_onnx(net, folder / "posedesc-rgbd.onnx", 200.0, {"arch": "trunk"}, depth_mask=(90.0, 99.0))
    return folder


def test_clutter_outside_the_depth_mask_does_not_change_the_answer(tmp_path, rgbd_masked, l_shape, t_shape):
    # the mask alone: a patch with depth is fitted too, which would move the answer off its template
    settings = Settings(
        data_dir=tmp_path, models_dir=rgbd_masked, demo_objects=False, level=1, rerank=50, pose_fit=0
    )
    state = load_state(settings)
    try:
        assert state.embedders["rgbd"].has_mask
        for mesh, name in ((l_shape, "L"), (t_shape, "T")):
            register(
                mesh, name, "none", worker=state.worker, embedders=state.embedders, store=state.store,
                cfg=state.templates,
            )  # fmt: skip
        mi = state.store.snapshot.models["rgbd"]
        az, el, _ = mi.poses[(mi.object_ids == 1) & (mi.poses[:, 2] == 0)][7]  # one of L's templates
        view = View(float(az), float(el), 0.0, 400.0)
        t = state.worker.submit(lambda r: r.render(l_shape, [view])).result()
        rgb, depth = t.rgb[0].copy(), t.depth[0].copy()
        clean = recognise(state, Query(png(rgb), depth_png(depth), k=3))
        wall = depth == 0  # behind the object, 300 mm farther than it: a wall of random colour
        rng = np.random.default_rng(0)
        rgb[wall] = rng.integers(0, 255, (int(wall.sum()), 3), dtype=np.uint8)
        depth[wall] = depth[depth > 0].max() + 300.0
        cluttered = recognise(state, Query(png(rgb), depth_png(depth), k=3))
        for result in (clean, cluttered):
            best = result.matches[0]
            assert state.store.snapshot.objects[best.object_id].name == "L"
            assert abs(best.azimuth - az) < 1e-3 and abs(best.elevation - el) < 1e-3
        # black outside the mask: the wall is gone before the network sees the patch
        assert cluttered.matches[0].distance == pytest.approx(clean.matches[0].distance, abs=0.02)
    finally:
        close_state(state)


def test_the_mask_is_found_once_and_turned_to_each_candidates_roll(tmp_path, rgbd_masked, l_shape, t_shape):
    """The mask of the query cut upright is turned to each roll the re-ranking looks at (`turn_masks`),
    rather than found again per roll: one mask pass per query, whatever the rolls of the candidates."""
    settings = Settings(
        data_dir=tmp_path,
        models_dir=rgbd_masked,
        demo_objects=False,
        level=1,
        rerank=50,
        inplane_step=60.0,
        inplane_max=180.0,
    )
    state = load_state(settings)
    try:
        e = state.embedders["rgbd"]
        for mesh, name in ((l_shape, "L"), (t_shape, "T")):
            register(
                mesh, name, "none", worker=state.worker, embedders=state.embedders, store=state.store,
                cfg=state.templates,
            )  # fmt: skip
        view = View(30.0, 40.0, 0.0, 400.0)
        t = state.worker.submit(lambda r: r.render(l_shape, [view])).result()
        calls: list[int] = []
        whole = e.mask
        e.mask = lambda x, batch=256: calls.append(len(x)) or whole(x, batch)  # type: ignore[method-assign]
        result = recognise(state, Query(png(t.rgb[0]), depth_png(t.depth[0]), k=50))
        assert len({round(m.inplane) for m in result.matches}) > 1  # candidates of several rolls
        assert calls == [1]
    finally:
        close_state(state)
