"""`recognise_decoded` is what `recognise` (so `POST /recognize`) runs after decoding: the same answers and
timings; `posedesc bench` times it from a decoded patch."""

from __future__ import annotations

from service_helpers import depth_png, png

from index.geometry.pose import View
from index.templates.register import register
from service.pipeline.query import Query, decode
from service.recognition import recognise, recognise_decoded
from service.settings import Settings
from service.state import close_state, load_state


def test_recognise_is_decode_then_recognise_decoded(tmp_path, posedesc_models, l_shape, t_shape):
    settings = Settings(
        data_dir=tmp_path,
        models_dir=posedesc_models,
        demo_objects=False,
        level=1,
        inplane_step=30,
        inplane_max=180,
        query_turns=3,
    )
    state = load_state(settings)
    try:
        for mesh, name in ((l_shape, "L"), (t_shape, "T")):
            register(
                mesh,
                name,
                "none",
                worker=state.worker,
                embedders=state.embedders,
                store=state.store,
                cfg=state.templates,
            )
        view = View(40.0, 30.0, 50.0, 400.0)
        t = state.worker.submit(lambda r: r.render(l_shape, [view])).result()
        rgb, depth = png(t.rgb[0]), depth_png(t.depth[0])
        for q in (Query(rgb, None, k=7), Query(None, depth, k=7), Query(rgb, depth, k=7)):
            full = recognise(state, q)
            d = decode(state, q)
            part = recognise_decoded(state, q, d)
            assert part.model == full.model and len(full.matches) == 7
            assert part.matches == full.matches
            # each stage by its name (these models have no mask and no local features; a patch with depth is
            # fitted in the camera it spans), then the sums
            fit = ["fit"] * (q.depth is not None)
            assert list(full.timings_ms) == ["decode", "cut", "embed", "search", *fit, "patch", "total"]
            assert list(part.timings_ms) == ["cut", "embed", "search", *fit, "patch", "total"]
            assert full.timings_ms["total"] >= full.timings_ms["decode"]
            assert part.timings_ms["patch"] == part.timings_ms["cut"]  # cut + mask, without a mask
    finally:
        close_state(state)
