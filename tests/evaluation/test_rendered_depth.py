"""Real colour with rendered depth on LM-O (skipped without ../shared/data/lmo), which has colour frames
and no depth: the depth the service protocol sends is the frame's ground truth rendered (annotated
objects, their table, the sensor model), and the evaluation's JSON says so."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evaluation.masks import rendered_depth, visible_masks
from evaluation.paper.samples import (
    REAL,
    REAL_COLOUR_RENDERED_DEPTH,
    RENDERED_DEPTH,
    SYNTHETIC,
    frame_size,
    rendered_depth_frames,
    select_instances,
    served_data,
)
from index.data.bop import BopDataset, table_depth

FRAMES = [3, 17]  # 6 and 5 instances; in frame 17 the cat's centre is hidden behind another object


def test_what_the_service_protocol_sends(lmo):
    dataset = BopDataset(lmo)
    instances = select_instances(dataset, 2, 0.5, FRAMES, dataset.obj_ids)
    assert served_data("rgb", instances, None) == REAL
    assert served_data("rgbd", instances, None) == REAL_COLOUR_RENDERED_DEPTH
    assert served_data("depth", instances, None) == RENDERED_DEPTH
    assert served_data("rgbd", instances, True) == SYNTHETIC  # --synthetic: the old scenes
    assert served_data("rgb", instances, True) == SYNTHETIC


@pytest.mark.slow  # over ~2 s (an export, a render): `make test`, not `make check`
def test_rendered_depth_is_the_annotated_objects_on_their_table(lmo, renderer):
    dataset = BopDataset(lmo)
    instances = select_instances(dataset, 2, 0.5, FRAMES, dataset.obj_ids)
    meshes: dict = {}
    frames = list(rendered_depth_frames(dataset, instances, renderer, meshes, 20_000, seed=0))
    assert [g[0].frame_id for g, _ in frames] == FRAMES
    for group, depth in frames:
        w, h = frame_size(group[0])
        assert depth.shape == (h, w) and depth.dtype == np.float32
        everyone = [i for i in dataset.instances(2) if i.frame_id == group[0].frame_id]
        assert len(everyone) >= len(group)
        masks = visible_masks(renderer, everyone, meshes, w, h)
        asked = {i.index for i in group}
        for inst, mask in zip(everyone, masks, strict=True):
            if inst.index not in asked:
                continue
            on = depth[mask]
            assert (on > 0).mean() > 0.9, inst  # a few sensor holes, no more
            # the object's visible surface: about t_z (LM-O objects are up to ~250 mm across)
            assert abs(np.median(on[on > 0]) - inst.t[2]) < 200, (inst.obj_id, np.median(on), inst.t)
        # elsewhere the table (with the sensor's noise), or nothing where it has no plane
        table = table_depth(everyone, [meshes[i.obj_id] for i in everyone], w, h)
        objects = np.any(masks, axis=0)
        off = ~objects & (depth > 0)
        assert off.mean() > 0.5 and (table[off] > 0).all()
        assert np.median(np.abs(depth[off] - table[off])) < 5.0
        assert not depth[~objects & (table == 0)].any()


@pytest.mark.slow  # over ~2 s (an export, a render): `make test`, not `make check`
def test_clean_render_without_the_sensor(lmo, renderer):
    """Without the sensor model every pixel of an object holds its depth; the sensor makes holes."""
    dataset = BopDataset(lmo)
    everyone = [i for i in dataset.instances(2) if i.frame_id == FRAMES[0]]
    meshes = {i.obj_id: dataset.mesh(i.obj_id, max_faces=20_000) for i in everyone}
    w, h = frame_size(everyone[0])
    clean = rendered_depth(renderer, everyone, meshes, w, h, sensor=None)
    noisy = rendered_depth(renderer, everyone, meshes, w, h, np.random.default_rng(0))
    objects = np.any(visible_masks(renderer, everyone, meshes, w, h), axis=0)
    assert (clean[objects] > 0).all()
    assert 0 < (noisy[objects] == 0).mean() < 0.05


@pytest.mark.parametrize(
    ("modality", "test_data"), [("rgbd", "real colour, rendered depth"), ("depth", "rendered depth")]
)
@pytest.mark.slow
def test_service_protocol_sends_rendered_depth(lmo, posedesc_models, tmp_path, modality, test_data):
    """An evaluation on two real frames: real colour (rgbd) with rendered depth, said in the JSON; the
    service measured the distance on that depth where the objects are (their surface, about ‖t‖)."""
    from evaluation.config import Config
    from evaluation.report import write_json
    from evaluation.run import evaluate

    model = posedesc_models / f"posedesc-{modality}.onnx"
    cfg = Config(lmo, model, modality, frames=FRAMES, objects=(5, 8), methods=("ours",))
    ev = evaluate(cfg)
    write_json(ev, tmp_path / "r.json")
    s = json.loads((tmp_path / "r.json").read_text())
    assert s["test_data"] == test_data and s["protocol"] == "service"
    assert any(n.startswith(f"{test_data}: annotated objects and the table only") for n in s["notes"])
    assert any("unannotated clutter has the table's depth" in n for n in s["notes"])
    assert not any("synthetic" in n for n in s["notes"])
    assert s["frames"] == FRAMES and s["n_samples"] == 4 and s["timing_ms"]["calls"] == 4  # none refused
    true = np.array([np.linalg.norm(i.t) for i in _instances(lmo, FRAMES, (5, 8))])
    assert ev.samples.cut_mm is not None
    assert (np.abs(ev.samples.cut_mm - true) < 200).all(), (ev.samples.cut_mm, true)
    assert ev.samples.depth is not None and (ev.samples.depth > 0).mean() > 0.8
    assert (ev.samples.rgb is not None) == (modality == "rgbd")


def _instances(lmo, frames, objects):
    dataset = BopDataset(lmo)
    return select_instances(dataset, 2, 0.5, frames, objects)
