"""Registration: mesh -> templates of every model -> store, with the real renderer and untrained models."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from index.features.embed import Embedder, ModelInfo, fingerprint, load_models, store_key, store_keys
from index.geometry.pose import View
from index.store import Store
from index.templates.mesh import MeshError
from index.templates.register import (
    TemplateConfig,
    embed_templates,
    make_templates,
    model_views,
    reembed,
    register,
    template_views,
)
from index.templates.viewpoints import hemisphere, recorded_whole, whole_sphere

CFG = TemplateConfig(level=2)  # 71 viewpoints: the same code path as level 3, four times faster


@pytest.fixture(scope="module")
def embedders(posedesc_models):
    return load_models(posedesc_models)


def test_template_views_per_symmetry():
    full_set = hemisphere(3)
    assert len(template_views("none")) == len(full_set) == 301
    half, fifth = template_views("180"), template_views("full")

    def az(v):  # 359.99999 is 0
        return (v.azimuth + 1e-6) % 360

    assert all(az(v) < 180 for v in half) and 140 <= len(half) <= 160
    assert all(az(v) < 72 for v in fifth) and 55 <= len(fifth) <= 65
    # the 72 degree wedge keeps every elevation of the set (the icosphere is 5-fold symmetric about z)
    assert {round(v.elevation, 3) for v in fifth} == {round(e, 3) for e in full_set[:, 1]}
    assert len(template_views("none", TemplateConfig(inplane_step=15))) == 301 * 7
    with pytest.raises(MeshError, match="symmetry"):
        template_views("90")


def test_a_flip_keeps_the_upper_half_of_every_sides_views_when_the_rolls_hold_the_rest():
    """Every side, a box's or a double-ended can's views from below are its views from above rolled: with
    the whole turn of roll (a model trained with it) the upper half's are kept; upright templates keep all."""
    sphere = TemplateConfig(whole=True)
    every = template_views("180", sphere, model_step=30.0)
    box = template_views("180+flip@28", sphere, model_step=30.0)
    assert min(v.elevation for v in every) < -80 and min(v.elevation for v in box) > -1e-6
    upper_half = [v for v in every if v.elevation > -1e-6]
    assert box == upper_half and len(every) > 1.8 * len(box)  # the equator is in both halves
    assert template_views("180+flip", sphere, model_step=0.0) == template_views("180", sphere, model_step=0.0)
    assert template_views("full+flip", TemplateConfig(), 30.0) == template_views(
        "full", TemplateConfig(), 30.0
    )
    # round about y: no azimuth wedge (that is about z), but turned over from every side
    assert template_views("y:full", TemplateConfig(), 30.0) == template_views("none", TemplateConfig(), 30.0)
    upright = [v for v in template_views("none", sphere, 30.0) if v.elevation > -1e-6]
    assert template_views("y:full", sphere, 30.0) == upright
    with pytest.raises(MeshError, match="unknown symmetry 'box'"):
        template_views("box")


def test_register_then_find_its_own_templates(tmp_path, l_shape, render_worker, embedders):
    store = Store(tmp_path, store_keys(embedders))
    with ThreadPoolExecutor(2) as pool:
        reg = register(
            l_shape, "L", "none", worker=render_worker, embedders=embedders, store=store, cfg=CFG, pool=pool
        )
    n = len(template_views("none", CFG))
    assert reg.record.templates == {"rgb": n, "depth": n, "rgbd": n}
    assert set(reg.timings) == {"render", "embed", "store", "total"}
    assert all(t > 0 for t in reg.timings.values())
    # Templates rendered again at three of the views must find themselves (ids, poses and descriptors
    # stay aligned through the chunks), at distance ~0.
    views = [template_views("none", CFG)[i] for i in (0, n // 2, n - 1)]
    rendered = render_worker.submit(lambda r: {200.0: r.render(l_shape, views)}).result()
    for m, e in embedders.items():
        ts = embed_templates(e, rendered)
        for view, matches in zip(views, store.search(m, ts.descriptors, 1), strict=True):
            assert matches[0].name == "L"
            assert (matches[0].azimuth, matches[0].elevation) == pytest.approx(
                (view.azimuth, view.elevation), abs=1e-3
            )
            assert matches[0].distance < 1e-3


def test_in_plane_variants_are_stored_with_their_angle(tmp_path, l_shape, render_worker, embedders):
    cfg = TemplateConfig(level=1, inplane_step=30, inplane_max=30)
    only_rgb = {"rgb": embedders["rgb"]}
    store = Store(tmp_path, store_keys(only_rgb))
    register(l_shape, "L", "none", worker=render_worker, embedders=only_rgb, store=store, cfg=cfg)
    mi = store.snapshot.models["rgb"]
    assert sorted(set(np.round(mi.poses[:, 2]).tolist())) == [-30.0, 0.0, 30.0]
    view = View(float(mi.poses[4, 0]), float(mi.poses[4, 1]), float(mi.poses[4, 2]))
    rendered = render_worker.submit(lambda r: {200.0: r.render(l_shape, [view])}).result()
    (match,) = store.search("rgb", embed_templates(only_rgb["rgb"], rendered).descriptors, 1)[0]
    assert match.inplane == view.inplane and match.distance < 1e-3


def test_unusable_meshes(tmp_path, render_worker, embedders):
    store = Store(tmp_path, store_keys(embedders))
    speck = trimesh.creation.box(extents=[0.01, 0.01, 0.01])  # a mesh in metres given as mm
    with pytest.raises(MeshError, match="invisible"):
        register(speck, "speck", "none", worker=render_worker, embedders=embedders, store=store, cfg=CFG)
    assert store.snapshot.objects == {} and store.snapshot.models["rgb"].size == 0


def test_reembed_after_a_model_changed(tmp_path, l_shape, render_worker, embedders):
    only_rgb = {"rgb": embedders["rgb"]}
    store = Store(tmp_path, store_keys(only_rgb))
    reg = register(l_shape, "L", "180", worker=render_worker, embedders=only_rgb, store=store, cfg=CFG)
    store.close()
    store = Store(tmp_path, store_keys(embedders))  # depth and rgbd are new: the object lacks their templates
    assert store.missing() == {"rgb": [], "depth": [reg.record.object_id], "rgbd": [reg.record.object_id]}
    assert reembed(store, render_worker, embedders, CFG) == 2
    assert store.missing() == {"rgb": [], "depth": [], "rgbd": []}
    n = len(template_views("180", CFG))
    assert store.snapshot.objects[reg.record.object_id].templates == {"rgb": n, "depth": n, "rgbd": n}


def test_an_object_seen_from_every_side_keeps_its_viewpoints_when_made_again(
    tmp_path, l_shape, render_worker, embedders
):
    """`viewpoints="sphere"`: templates from below the mesh's xy plane too, stored with their elevations and
    recorded, so that a new model's templates are made from the same sides; not said, the config's (the upper
    half by default); an unknown word is refused before anything is stored."""
    only_rgb = {"rgb": embedders["rgb"]}
    store = Store(tmp_path, store_keys(only_rgb))
    reg = register(
        l_shape,
        "L",
        "none",
        worker=render_worker,
        embedders=only_rgb,
        store=store,
        cfg=CFG,
        viewpoints="sphere",
    )
    n = len(template_views("none", replace(CFG, whole=True)))
    assert n > 1.9 * len(template_views("none", CFG)) and reg.record.templates == {"rgb": n}
    assert reg.record.extra["viewpoints"] == "sphere" and recorded_whole(reg.record.extra)
    upper = register(l_shape, "L-up", "none", worker=render_worker, embedders=only_rgb, store=store, cfg=CFG)
    assert upper.record.extra["viewpoints"] == "upper"
    with pytest.raises(MeshError, match="viewpoints"):
        register(l_shape, "L?", "none", worker=render_worker, embedders=only_rgb, store=store, cfg=CFG,
                 viewpoints="below")  # fmt: skip
    assert store.snapshot.named("L?") is None
    store.close()
    store = Store(tmp_path, store_keys(embedders))  # depth and rgbd are new: made again from every side
    assert reembed(store, render_worker, embedders, CFG) == 4
    rec = store.snapshot.objects[reg.record.object_id]
    assert rec.templates == {"rgb": n, "depth": n, "rgbd": n}
    assert whole_sphere(None, True) and not whole_sphere("upper", replace(CFG, whole=True))


def test_template_in_plane_angles_follow_the_model_unless_overridden():
    legacy, rolled = 0.0, 30.0
    assert TemplateConfig().inplane(legacy).tolist() == [0.0]
    assert TemplateConfig().inplane(rolled).tolist() == [float(a) for a in range(-150, 181, 30)]
    assert len(TemplateConfig(inplane_step=15).inplane(legacy)) == 7  # +-45, as the setting always was
    assert len(TemplateConfig(inplane_step=15).inplane(rolled)) == 24  # the whole turn, finer
    assert TemplateConfig(inplane_step=0).inplane(rolled).tolist() == [0.0]
    assert len(TemplateConfig(inplane_step=30, inplane_max=180).inplane(legacy)) == 12
    assert TemplateConfig(inplane_max=60).inplane(rolled).tolist() == [-60.0, -30.0, 0.0, 30.0, 60.0]
    assert TemplateConfig().inplane_spacing(rolled) == 30.0 and TemplateConfig().inplane_spacing(legacy) == 0
    assert len(template_views("none", CFG, rolled)) == 12 * len(template_views("none", CFG, legacy))


@pytest.fixture(scope="module")
def rolled_rgb(posedesc_models, tmp_path_factory):
    """The untrained rgb model saying it was trained with the whole turn of roll, every 90°."""
    onnx = pytest.importorskip("onnx")
    model = onnx.load(str(posedesc_models / "posedesc-rgb.onnx"))
    model.metadata_props.add(key="inplane_step", value="90")
    path = tmp_path_factory.mktemp("rolled") / "posedesc-rgb.onnx"
    onnx.save(model, str(path))
    return Embedder(path)


def test_each_model_gets_its_own_in_plane_templates(tmp_path, l_shape, render_worker, embedders, rolled_rgb):
    """A model trained with roll and a legacy one in one registration: one render per viewpoint, the
    first model's templates over the whole turn, the second's upright."""
    assert rolled_rgb.info.inplane_step == 90.0 and embedders["depth"].info.inplane_step == 0.0
    models = {"rgb": rolled_rgb, "depth": embedders["depth"]}
    store = Store(tmp_path, store_keys(models))
    cfg = TemplateConfig(level=1)
    reg = register(l_shape, "L", "none", worker=render_worker, embedders=models, store=store, cfg=cfg)
    n = len(template_views("none", cfg))
    assert reg.record.templates == {"rgb": 4 * n, "depth": n}
    rgb, depth = store.snapshot.models["rgb"], store.snapshot.models["depth"]
    assert sorted(set(rgb.poses[:, 2].tolist())) == [-90.0, 0.0, 90.0, 180.0]
    assert set(depth.poses[:, 2].tolist()) == {0.0}
    view = View(float(rgb.poses[5, 0]), float(rgb.poses[5, 1]), float(rgb.poses[5, 2]))
    rendered = render_worker.submit(lambda r: {200.0: r.render(l_shape, [view])}).result()
    (match,) = store.search("rgb", embed_templates(rolled_rgb, rendered).descriptors, 1)[0]
    assert (match.azimuth, match.elevation, match.inplane) == (view.azimuth, view.elevation, view.inplane)
    assert match.distance < 1e-3


def test_model_metadata_in_plane_step():
    base = {"modality": "rgb", "window_mm": "200", "size": "64", "descriptor_dim": "16"}
    assert ModelInfo.from_metadata(base).inplane_step == 0.0
    assert ModelInfo.from_metadata({**base, "inplane_step": "30"}).inplane_step == 30.0
    for bad in ("-5", "360", "often"):
        with pytest.raises(ValueError, match="not a posedesc model"):
            ModelInfo.from_metadata({**base, "inplane_step": bad})


@pytest.mark.slow
def test_an_rgbd_model_made_from_the_rgb_one_shares_its_templates(
    tmp_path, l_shape, render_worker, embedders
):
    """The RGB-D model written from the rgb run (`export --as-rgbd`: the colour network, its mask from
    depth) makes the rgb model's very templates: registration embeds them once and stores them for both.
    Another colour network (other weights), or depth alone, is not a twin."""
    torch = pytest.importorskip("torch")
    from index.templates.register import template_twins
    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(1)
    net = DescriptorNet(NetConfig("rgb", 32, arch="trunk"))
    folder = tmp_path / "models"
    rgb = Embedder(export_onnx(net, folder / "rgb.onnx", 200.0, {"arch": "trunk"}))
    rgbd = Embedder(export_onnx(net, folder / "rgbd.onnx", 200.0, {"arch": "trunk"}, depth_mask=(90.0, 99.0)))
    other = Embedder(export_onnx(DescriptorNet(NetConfig("rgb", 32, arch="trunk")), folder / "o.onnx", 200.0))
    assert template_twins({"rgb": rgb, "rgbd": rgbd, "depth": embedders["depth"]}) == {"rgbd": "rgb"}
    assert template_twins({"rgb": other, "rgbd": rgbd}) == {}
    assert template_twins({"rgb": embedders["rgb"], "rgbd": embedders["rgbd"]}) == {}  # paper nets read depth

    models = {"rgb": rgb, "rgbd": rgbd}
    store = Store(tmp_path / "store", store_keys(models))
    with ThreadPoolExecutor(2) as pool:
        register(
            l_shape, "L", "none", worker=render_worker, embedders=models, store=store, cfg=CFG, pool=pool
        )
    a, b = store.snapshot.models["rgb"], store.snapshot.models["rgbd"]
    np.testing.assert_array_equal(a.poses, b.poses)
    assert a.local.keys() == b.local.keys() and len(a.local) == len(template_views("none", CFG))
    for k, f in a.local.items():
        np.testing.assert_array_equal(f, b.local[k])
    # and they are what the rgbd model itself makes of those renders: one view, embedded by it directly
    view = View(float(a.poses[7, 0]), float(a.poses[7, 1]), float(a.poses[7, 2]))
    rendered = render_worker.submit(lambda r: {200.0: r.render(l_shape, [view])}).result()
    (match,) = store.search("rgbd", embed_templates(rgbd, rendered).descriptors, 1)[0]
    assert (match.azimuth, match.elevation) == (view.azimuth, view.elevation) and match.distance < 1e-4


def test_chunked_templates_are_those_of_one_render(l_shape, render_worker, posedesc_models):
    """`make_templates` renders in chunks and turns and embeds each chunk on the pool while the next renders:
    with a pool or without, its templates are, bit for bit, those of every view rendered in one go and
    embedded whole by each model (the shipped models where they are: in-plane variants, local features)."""
    shipped = Path(__file__).parents[3] / "models"
    models = load_models(shipped if (shipped / "posedesc-rgb.onnx").is_file() else posedesc_models)
    cfg = TemplateConfig(level=1)
    views = model_views("none", cfg, models)
    with ThreadPoolExecutor(2) as pool:
        pooled, _, offsets = make_templates(render_worker, models, l_shape, views, pool, chunks=3)
    serial, _, _ = make_templates(render_worker, models, l_shape, views, None, chunks=2)
    whole = {
        m: render_worker.submit(lambda r, vs=vs: {200.0: r.render(l_shape, vs)}).result()
        for m, vs in views.items()
    }
    for m, e in models.items():
        want = embed_templates(e, whole[m])
        for got in (pooled[m], serial[m]):
            for field in ("poses", "descriptors", "local_rows", "local"):
                np.testing.assert_array_equal(
                    getattr(got, field), getattr(want, field), err_msg=f"{m} {field}"
                )
    assert len(offsets) == len(hemisphere(1))


def test_a_store_made_before_the_relief_makes_local_templates_again(embedders):
    """`store_key`: a model with local features files its templates under its graph's digest tagged with
    the relief's layout, so a store made before that layout makes them again (`Store.missing`, as for a
    changed model); a model without local features is keyed by its graph's digest alone."""
    plain = embedders["rgb"]
    assert not plain.has_local and store_key(plain) == (plain.dim, plain.graph_digest)
    shipped = Path(__file__).parents[3] / "models" / "posedesc-rgb.onnx"
    if not shipped.is_file():
        pytest.skip("no shipped rgb model")
    e = Embedder(shipped, 1)
    assert e.has_local
    dim, tag = store_key(e)
    assert dim == e.dim and tag != e.graph_digest and len(tag) == 16


def test_a_new_calibration_keeps_the_templates(tmp_path, embedders):
    """Rewriting a model's metadata (a calibration, `scripts/calibrate_reject.py`) changes the file, not
    what it computes: its templates stay filed under the same key; another network gets another."""
    import onnx

    e = embedders["rgb"]
    proto = onnx.load(str(e.path))
    proto.metadata_props.add(key="reject_above", value="{}")
    onnx.save(proto, str(tmp_path / "recalibrated.onnx"))
    again = Embedder(tmp_path / "recalibrated.onnx", 1)
    assert fingerprint(again.path) != fingerprint(e.path) and store_key(again) == store_key(e)
    assert store_key(embedders["depth"]) != store_key(e)


def test_registration_reports_its_progress(tmp_path, l_shape, render_worker, embedders):
    store = Store(tmp_path, store_keys(embedders))
    told: list[tuple[str, int, int]] = []
    cfg = TemplateConfig(level=1)
    reg = register(
        l_shape,
        "L",
        "none",
        worker=render_worker,
        embedders=embedders,
        store=store,
        cfg=cfg,
        progress=lambda *a: told.append(a),
    )
    views = len(template_views("none", cfg))
    made = [t for t in told if t[0] != "store"]
    # chunk by chunk, waiting on its render, then on its embedding, with the views done before it
    assert [s for s, _, _ in made] == ["render", "embed"] * (len(made) // 2) and len(made) >= 4
    assert all(total == views for _, _, total in made)
    render, embed = ([d for s, d, _ in made if s == stage] for stage in ("render", "embed"))
    assert render == embed and render[0] == 0 and render == sorted(set(render)) and render[-1] < views
    stored = sum(reg.record.templates.values())
    assert told[-2:] == [("store", 0, stored), ("store", stored, stored)]
