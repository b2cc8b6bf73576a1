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

pytestmark = pytest.mark.slow  # real trainings: `make test`, not `make check`


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


class Scripted:
    """A validation with given scores per epoch (the best is epoch 2) that also reports a number made
    from the network's template descriptors; `stop_at`: the epoch at which the user presses Ctrl-C."""

    SCORES = (0.2, 0.9, 0.5, 0.4)

    def __init__(self, done: int = 0, stop_at: int = 0):
        self.epoch, self.stop_at = done, stop_at

    def __call__(self, net, template_f) -> dict:
        self.epoch += 1
        if self.epoch == self.stop_at:
            raise KeyboardInterrupt
        return {"within_3d_20": self.SCORES[self.epoch - 1], "f0": float(np.abs(template_f(0)).sum())}


def test_a_killed_run_resumed_ends_as_an_uninterrupted_one(two_shapes, tmp_path):
    """8 steps in epochs of 2, bootstrapping and mining from step 3 (bank refreshed by halves every 3
    steps): killed during epoch 3's validation, resumed from epoch 2's checkpoint, the run ends with the
    weights, log and best checkpoint of the run nobody killed, bit for bit (one thread, steps not time:
    the budget is far off). Without the batch generator's state the batches would repeat, without the
    bank's the mining would differ, without the best score best.pt would become epoch 3."""
    cfg = TrainConfig(modality="rgb", descriptor_dim=8, minutes=600.0, max_steps=8, steps_per_epoch=2,
                      samples_per_batch=4, bootstrap_after=0.25, mine_refresh=3, mine_parts=2, threads=1,
                      data=two_shapes.cfg)  # fmt: skip
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    net = train(cfg, two_shapes, whole, Scripted())
    with pytest.raises(KeyboardInterrupt):
        train(cfg, two_shapes, killed, Scripted(stop_at=3))
    assert torch.load(killed / "checkpoint.pt", weights_only=False)["step"] == 4
    assert len((killed / "log.jsonl").read_text().splitlines()) == 2
    again = train(cfg, two_shapes, killed, Scripted(done=2), resume=True)

    for k, v in net.state_dict().items():
        assert torch.equal(v, again.state_dict()[k]), k

    def lines(run) -> list[dict]:
        return [{k: v for k, v in json.loads(s).items() if k != "minutes"} for s in open(run / "log.jsonl")]

    assert lines(killed) == lines(whole)
    assert [r["step"] for r in lines(killed)] == [2, 4, 6, 8] and lines(killed)[1]["best"]
    for run in (whole, killed):
        last, best = load_checkpoint(run)[1], load_checkpoint(run, "best")[1]
        assert (last["epoch"], last["step"], best["epoch"]) == (4, 8, 2)
        assert "resume" not in best  # best.pt keeps only what export reads
    with pytest.raises(ValueError, match="whole budget"):
        train(cfg, two_shapes, killed, Scripted(done=4), resume=True)
    with pytest.raises(ValueError, match=r"descriptor_dim: was 8, now 16"):
        train(
            TrainConfig(**{**cfg.__dict__, "descriptor_dim": 16, "max_steps": 9}),
            two_shapes,
            killed,
            resume=True,
        )
