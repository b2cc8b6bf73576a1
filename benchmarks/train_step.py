"""Training throughput of the paper's network: patches per second through one optimisation step
(forward, the paper's cost with in-batch bootstrapping, backward, Adam), as `training.train` runs it.

A batch is built by the training's own `BatchBuilder` for `samples_per_batch` samples of random objects at
random training viewpoints, so it has the real number of rows (samples plus their templates) and
triplets; the images are random (their content does not change the cost). Making the images (renders
through the sensor model, on the producer thread during training) is not included, nor is mining hard
templates from the bank of all templates (`training/mining.py`: it adds rows to the batch; patches per
second counts rows). torch is imported here only, with the training's thread count."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.timing import measure


@dataclass(frozen=True)
class TrainStepConfig:
    steps: int = 20  # timed steps
    warmup: int = 3
    objects: int = 47  # in the training set (7 LM-O + 40 shapes, as the shipped model's run)
    samples_per_batch: int | None = None  # None: the training's default
    threads: int | None = None  # None: the training's default


def run(modality: str, cfg: TrainStepConfig, seed: int = 0) -> dict:
    import torch

    from index.templates.viewpoints import sphere_views
    from training.batches import BatchBuilder, bootstrap_triplets
    from training.losses import DescriptorLoss
    from training.model import DescriptorNet, NetConfig
    from training.similarity import rotations
    from training.train import TrainConfig

    tc = TrainConfig(modality=modality)
    threads = cfg.threads or tc.threads
    samples = cfg.samples_per_batch or tc.samples_per_batch
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    builder = BatchBuilder(rotations(sphere_views(3)), ["none"] * cfg.objects)
    train_R = rotations(sphere_views(4))
    picks = rng.integers(len(train_R), size=samples)
    batch = builder.make(range(samples), rng.integers(cfg.objects, size=samples), train_R[picks], rng)
    # channels_last, as `training.train` sets it (its first max-pool is much faster so on CPUs)
    net = DescriptorNet(NetConfig(modality, tc.descriptor_dim)).to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    x = torch.randn(len(batch.items), net.cfg.channels, net.cfg.size, net.cfg.size)
    x = x.contiguous(memory_format=torch.channels_last)
    loss_fn = DescriptorLoss(tc.margin, tc.pair_weight, tc.weight_decay)
    opt = torch.optim.Adam(net.parameters(), lr=tc.lr)
    pairs = torch.from_numpy(batch.pairs)

    def step() -> None:
        net.train()
        f = net(x)
        triplets = np.concatenate([batch.triplets, bootstrap_triplets(batch, f.detach().numpy())])
        loss, _ = loss_fn(net, f, torch.from_numpy(triplets), pairs)
        opt.zero_grad()
        loss.backward()
        opt.step()

    t = measure(step, cfg.steps, warmup=cfg.warmup)
    rows = len(batch.items)
    return {
        "modality": modality,
        "torch": torch.__version__,
        "torch_threads": threads,
        "samples_per_batch": samples,
        "patches_per_batch": rows,
        "triplets_per_batch": int(len(batch.triplets)),
        "steps": cfg.steps,
        "step_median_ms": t.median * 1e3,
        "train_patches_per_s": rows / t.median,
        "train_samples_per_s": samples / t.median,
        "parameters": sum(p.numel() for p in net.parameters()),
        "memory_format": "channels_last",
        "not_included": "making images (producer thread), mining from the template bank",
    }
