"""Local features fine-tuned for the re-ranking (`posedesc train --arch local`): the training scores what the
service scores, candidates are what they claim, the copy trains, keeps its frozen stages and resumes."""

import json

import numpy as np
import pytest
import torch

from index.local import cell_cosines, masked_distance
from training import local as local_module
from training.data import DataConfig, TrainingData
from training.local import Candidates, LocalConfig, LocalTrunk, distances, load_local, train_local
from training.render_cache import build
from training.similarity import pose_distances
from training.trunk import Trunk


@pytest.fixture(scope="module")
def shapes() -> TrainingData:
    return build([], DataConfig(shapes=3, shape_views=20, template_inplane_step=90.0, seed=2))


def test_the_training_distance_is_the_services():
    """`distances` (torch, what the loss reads) equals `index.local.masked_distance` of the service on the
    same maps and masks, an empty query mask included."""
    rng = np.random.default_rng(0)
    b, k, c, g = 3, 4, 24, 16
    fq, ft = rng.normal(size=(b, c, g, g)), rng.normal(size=(b, k, c, g, g))
    qm = (rng.random((b, g * g)) > 0.5).astype(np.float32)
    qm[2] = 0.0
    sil = rng.random((b, k, g * g)).astype(np.float32) * (rng.random((b, k, g * g)) > 0.4)
    ours = distances(*(torch.from_numpy(a).float() for a in (fq, ft, qm, sil))).numpy()
    for i in range(b):
        cos = cell_cosines(fq[i].reshape(1, -1), ft[i].reshape(k, -1), g)
        service = masked_distance(cos, sil[i], np.repeat(qm[i][None], k, 0))
        np.testing.assert_allclose(ours[i], service, atol=1e-5)


def test_candidates_are_the_nearest_template_then_negatives(shapes):
    cfg = LocalConfig(same=6, others=2, far=25.0)
    pick, rng = Candidates(shapes, cfg), np.random.default_rng(3)
    R = shapes.s_R[shapes.s_by_obj[1][0]]
    row = pick(1, R, rng, cfg.same, cfg.others)
    assert len(row) == 9 and [o for o, _ in row[:7]] == [1] * 7 and all(o != 1 for o, _ in row[7:])
    d = pose_distances(R[None], shapes.template_R, shapes.symmetries[1])[0]
    assert d[row[0][1]] == d.min()
    assert all(d[t] > 25.0 for _, t in row[1:7])


def test_a_short_run_moves_only_the_stages_it_trains_and_reloads(shapes, tmp_path):
    cfg = LocalConfig(minutes=600.0, max_steps=4, batch=4, same=3, others=1, steps_per_epoch=2, threads=1)
    net = train_local(cfg, shapes, tmp_path)
    imagenet = Trunk()
    for name, v in net.state_dict().items():
        stage = int(name.split(".")[1])
        same = torch.equal(v, imagenet.state_dict()[name])
        if "running" in name or "num_batches" in name:
            assert same, name  # BatchNorm keeps ImageNet's statistics
        elif stage < cfg.frozen_stages:
            assert same, name
    assert any(
        not torch.equal(v, imagenet.state_dict()[k])
        for k, v in net.state_dict().items()
        if int(k.split(".")[1]) >= cfg.frozen_stages
    )
    back, state = load_local(tmp_path, "last")
    assert state["step"] == 4 and isinstance(back, LocalTrunk)
    for k, v in net.state_dict().items():
        assert torch.equal(v, back.state_dict()[k]), k
    steps = [json.loads(s)["step"] for s in (tmp_path / "local-log.jsonl").read_text().splitlines()]
    assert steps == [0, 2, 4]  # the ImageNet trunk's score first


def test_a_local_run_interrupted_and_resumed_ends_as_an_uninterrupted_one(shapes, tmp_path, monkeypatch):
    cfg = LocalConfig(minutes=600.0, max_steps=5, batch=3, same=2, others=1, steps_per_epoch=2, threads=1)
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    net = train_local(cfg, shapes, whole)
    draw, calls = local_module._batch, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:  # as step 3 asks for its batch: after the checkpoint of step 2
            raise KeyboardInterrupt
        return draw(*args, **kwargs)

    monkeypatch.setattr(local_module, "_batch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_local(cfg, shapes, stopped)
    monkeypatch.setattr(local_module, "_batch", draw)
    assert load_local(stopped, "last")[1]["step"] == 2
    again = train_local(cfg, shapes, stopped, resume=True)
    for k, v in net.state_dict().items():
        assert torch.equal(v, again.state_dict()[k]), k
    with pytest.raises(ValueError, match="whole budget"):
        train_local(cfg, shapes, stopped, resume=True)
