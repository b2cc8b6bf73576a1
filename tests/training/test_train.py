"""A short training run on two small rendered shapes: the loss falls and the descriptors separate them."""

import json

import numpy as np
import pytest
import torch

from training.data import DataConfig
from training.export import torch_descriptors
from training.losses import DescriptorLoss
from training.model import DescriptorNet, NetConfig
from training.render_cache import build
from training.train import BatchProducer, TrainConfig, batch_descriptors, load_checkpoint, train


@pytest.fixture(scope="module")
def two_shapes():
    # No BOP data: two procedural shapes, few training renders, so the test stays fast.
    # Augmentations and roll off: 120 steps are to show the mechanics work, not to learn invariances.
    cfg = DataConfig(
        shapes=2, shape_views=80, occlude=0.0, colour_jitter=0.0, roll=5.0, template_inplane_step=0.0, seed=3
    )
    return build([], cfg)


def batch_loss(net, batches, stems) -> float:
    loss = DescriptorLoss()
    with torch.no_grad():
        terms = [
            loss(
                net,
                batch_descriptors(net, b, x, stems),
                torch.from_numpy(b.triplets),
                torch.from_numpy(b.pairs),
            )
            for b, x in batches
        ]
    return float(np.mean([t[1]["triplet"] for t in terms]))


@pytest.mark.slow
def test_loss_falls_and_shapes_separate(two_shapes, tmp_path):
    data = two_shapes
    cfg = TrainConfig(
        modality="rgb",
        descriptor_dim=8,
        minutes=5.0,
        max_steps=120,
        steps_per_epoch=30,
        samples_per_batch=12,
        lr=2e-3,
        bootstrap_after=0.5,
        seed=0,
        data=data.cfg,
    )
    fixed = BatchProducer(data, TrainConfig(**{**cfg.__dict__, "seed": 7}), start=False)
    batches = [fixed.make() for _ in range(6)]
    torch.manual_seed(cfg.seed)  # the same initial network as train() makes
    stems = data.template_inputs("rgb")  # the paper's network has no stem: its templates' are their inputs
    before = batch_loss(DescriptorNet(NetConfig("rgb", 8)).eval(), batches, stems)

    net = train(cfg, data, tmp_path)
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert len(log) == 4 and log[-1]["step"] == 120
    after = batch_loss(net.eval(), batches, stems)
    assert after < 0.5 * before

    rng = np.random.default_rng(9)
    templates = np.stack([data.template_input(o, t, "rgb") for o in (0, 1) for t in range(0, 301, 3)])
    t_obj = np.repeat([0, 1], len(range(0, 301, 3)))
    samples = [data.draw(o, rng, "rgb", 0.0) for o in (0, 1) for _ in range(20)]
    x = np.stack([data.sample_input(s, "rgb", rng) for s, _ in samples])
    s_obj = np.repeat([0, 1], 20)
    tf, sf = torch_descriptors(net, templates), torch_descriptors(net, x)
    nn = np.argmin(((sf[:, None] - tf[None]) ** 2).sum(-1), axis=1)
    assert (t_obj[nn] == s_obj).mean() >= 0.9

    again, ckpt = load_checkpoint(tmp_path)
    assert ckpt["step"] == 120
    assert np.allclose(torch_descriptors(again, x), sf, atol=1e-6)


def test_trunk_training_runs_on_cached_template_stems(two_shapes, tmp_path):
    """The frozen trunk's template maps are computed once; a step's descriptors equal the whole network's."""
    from training.train import template_stems

    data = two_shapes
    net = DescriptorNet(NetConfig("rgb", 8, arch="trunk")).eval()
    stems = template_stems(net, data.template_inputs("rgb"))
    assert stems.shape[:2] == (2, data.n_templates) and stems.shape[2:] == (24, 16, 16)
    producer = BatchProducer(
        data, TrainConfig(modality="rgb", arch="trunk", samples_per_batch=6), start=False
    )
    batch, x = producer.make()
    f = batch_descriptors(net, batch, x, stems).detach().numpy()
    rows = [it for it in batch.items[len(x) :]]
    full = torch_descriptors(net, np.stack([data.template_input(o, t, "rgb") for _, o, t in rows]))
    np.testing.assert_allclose(f[len(x) :], full, atol=2e-2)  # float16 stems
    np.testing.assert_allclose(f[: len(x)], torch_descriptors(net, x.numpy()), atol=1e-4)
    cfg = TrainConfig(modality="rgb", arch="trunk", descriptor_dim=8, minutes=5.0, max_steps=4,
                      steps_per_epoch=2, samples_per_batch=6, bootstrap_after=0.5, data=data.cfg)  # fmt: skip
    train(cfg, data, tmp_path)
    again, ckpt = load_checkpoint(tmp_path)
    assert ckpt["config"]["arch"] == "trunk" and ckpt["step"] == 4
