"""Local features fine-tuned for the re-ranking (`posedesc train --arch local`): the training scores what the
service scores, candidates are what they claim, the copy trains, keeps its frozen stages and resumes."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from index.features.local import cell_cosines, masked_distance
from training.data import DataConfig, TrainingData
from training.heads import local as local_module
from training.heads.local import (
    Candidates,
    HardNegatives,
    LocalConfig,
    LocalTrunk,
    OnnxMask,
    Scorer,
    distances,
    jitter_outline,
    load_local,
    train_local,
)
from training.render_cache import build
from training.similarity import pose_distances
from training.trunk import Trunk

pytestmark = pytest.mark.xdist_group("heads-local")  # the module's fixture made once, on one worker;
# every test of the rendered shapes (a render cache, short trainings) is `slow`: `make test`, not `make check`


@pytest.fixture(scope="module")
def shapes() -> TrainingData:
    return build([], DataConfig(shapes=3, shape_views=20, template_inplane_step=90.0, seed=2))


def test_the_training_distance_is_the_services():
    """`distances` (torch, what the loss reads) equals `index.features.local.masked_distance` of the service on the
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


@pytest.mark.slow
def test_candidates_are_the_nearest_template_then_negatives(shapes):
    cfg = LocalConfig(same=6, others=2, far=25.0)
    pick, rng = Candidates(shapes, cfg), np.random.default_rng(3)
    R = shapes.s_R[shapes.s_by_obj[1][0]]
    row = pick(1, R, rng, cfg.same, cfg.others)
    assert len(row) == 9 and [o for o, _ in row[:7]] == [1] * 7 and all(o != 1 for o, _ in row[7:])
    d = pose_distances(R[None], shapes.template_R, shapes.symmetries[1])[0]
    assert d[row[0][1]] == d.min()
    assert all(d[t] > 25.0 for _, t in row[1:7])


@pytest.mark.slow
def test_other_objects_negatives_come_from_real_objects_at_the_share_asked(shapes, monkeypatch):
    """`--local-others-real`: that share of a query's other-object negatives is drawn from the objects with
    real training frames (here object 2 is given some), the rest from every other object."""
    monkeypatch.setattr(shapes, "train_real", {2: [0]})

    def others(share: float) -> list[int]:
        cfg = LocalConfig(same=2, others=400, others_real=share)
        pick, rng = Candidates(shapes, cfg), np.random.default_rng(4)
        return [o for o, _ in pick(1, shapes.template_R[0], rng, cfg.same, cfg.others)[1 + cfg.same :]]

    assert set(others(1.0)) == {2}
    assert set(others(0.0)) == {0, 2}  # every other object alike (three shapes here)
    half = others(0.5)
    assert 0.6 < half.count(2) / len(half) < 0.9  # 0.5 + 0.5 / 2 expected
    assert 1 not in half


@pytest.mark.slow
def test_hard_negatives_are_the_descriptors_nearest_templates_but_the_pose_itself(shapes, posedesc_models):
    """`--hard-negatives`: a query's extra negatives are among the templates nearest it in the model's
    descriptor space, leaving out its own object's templates within `far` of its pose (the template it is
    equal to among them), as the service's first stage would put them before the re-ranking."""
    from index.features.embed import Embedder

    cfg = LocalConfig(far=25.0, hard=5, hard_pool=12, threads=1)
    hard = HardNegatives(shapes, cfg, posedesc_models / "posedesc-rgb.onnx")
    assert len(hard.descriptors) == shapes.n_objects * shapes.n_templates
    obj, t = 1, 7
    x = shapes._template_input(obj, t, "rgb")[None].astype(np.float32)
    R = shapes.template_R[t]
    (row,) = hard(x, [obj], [R], np.random.default_rng(0))
    assert len(row) == cfg.hard and len(set(row)) == cfg.hard
    d = Embedder(posedesc_models / "posedesc-rgb.onnx", 1)(x)[0]
    dist = ((hard.descriptors - d) ** 2).sum(1)
    poses = pose_distances(R[None], shapes.template_R, shapes.symmetries[obj])[0]
    allowed = [i for i in np.argsort(dist) if hard.keys[i, 0] != obj or poses[hard.keys[i, 1]] > cfg.far]
    bound = dist[allowed[cfg.hard_pool - 1]]  # the farthest of the pool (to rounding: two ways of summing)
    where = {(int(o), int(k)): i for i, (o, k) in enumerate(hard.keys)}
    assert all(dist[where[c]] <= bound + 1e-4 * max(1.0, bound) for c in row)
    assert (obj, t) not in row and all(o != obj or poses[k] > cfg.far for o, k in row)


@pytest.mark.slow
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


@pytest.mark.slow
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


SHIPPED_RGB = Path(__file__).resolve().parents[3] / "models" / "posedesc-rgb.onnx"


def test_jitter_moves_the_outline_in_and_out_and_nothing_away_from_it():
    mask = np.zeros((64, 64), bool)
    mask[16:48, 20:44] = True
    m = mask.astype(np.uint8)
    away = np.where(
        mask, cv2.distanceTransform(m, cv2.DIST_L2, 3), cv2.distanceTransform(1 - m, cv2.DIST_L2, 3)
    )
    rng = np.random.default_rng(0)
    assert np.array_equal(jitter_outline(mask, 0.0, rng), mask)
    grown = shrunk = 0
    for _ in range(50):
        j = jitter_outline(mask, 3.0, rng)
        assert not ((j ^ mask) & (away > 3.5)).any()  # only within the jitter of the outline
        grown, shrunk = grown + int((j & ~mask).sum()), shrunk + int((mask & ~j).sum())
    assert grown > 0 and shrunk > 0
    assert not jitter_outline(np.zeros((64, 64), bool), 3.0, rng).any()  # nothing to move


@pytest.mark.slow
def test_an_exported_model_s_mask_blacks_the_queries_and_the_jitter_moves_it(shapes, tmp_path):
    head = OnnxMask(SHIPPED_RGB)
    rng = np.random.default_rng(0)
    x = np.stack(
        [shapes.sample_with_mask(shapes.draw(o, rng, "rgb", 0.0)[0], "rgb", rng)[0] for o in range(3)]
    )
    logits = head(torch.from_numpy(x.astype(np.float32)))
    from index.features.embed import Embedder

    assert np.array_equal(logits.numpy()[:, 0] > 0, Embedder(SHIPPED_RGB, 1).mask(x.astype(np.float32)))
    scorer = Scorer(shapes, LocalTrunk(), head)
    _, plain = scorer.blacked(x.astype(np.float32), np.zeros((3, 64, 64), bool))
    _, moved = scorer.blacked(x.astype(np.float32), np.zeros((3, 64, 64), bool), (3.0, rng))
    assert torch.equal(plain, logits[:, 0] > 0)  # the model's mask, not the (empty) true ones
    assert not torch.equal(plain, moved)
    cfg = LocalConfig(
        minutes=600.0, max_steps=2, batch=2, same=2, others=1, steps_per_epoch=2, threads=1, mask_jitter=3.0
    )
    train_local(cfg, shapes, tmp_path, head)  # trains with the model's masks, moved
    assert load_local(tmp_path, "last")[1]["step"] == 2
