"""Fitting the `pca` descriptor: principal components of pretrained trunk features of templates.

No metric loss: the projection keeps what varies most across the templates of procedural shapes (views,
in-plane turns included, of objects no user registers), so nothing about the BOP objects, their frames or
their clutter reaches the model. The descriptor is the trunk's map pooled and L2-normalised, centred and
projected on the first `descriptor_dim` components; distances between descriptors approximate distances
between the normalised maps (template matching on early ImageNet features), at a fraction of the size."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from training.data import TrainingData
from training.model import DescriptorNet, NetConfig


def fit(net: DescriptorNet, data: TrainingData, per_object: int = 200, seed: int = 0) -> dict[str, float]:
    """Sets `net`'s projection from `per_object` random templates of every procedural shape; returns the
    share of the normalised maps' variance the components keep."""
    rng = np.random.default_rng(seed)
    shapes = range(data.real_objects, data.n_objects)
    if not len(shapes):
        raise ValueError("the pca descriptor is fitted on procedural shapes: --shapes must be > 0")
    picks = [(o, int(t)) for o in shapes for t in rng.choice(data.n_templates, per_object, replace=False)]
    x = np.stack([data.template_input(o, t, net.cfg.modality) for o, t in picks])
    pre = net.body[:-1]  # pool, flatten, unit length
    with torch.no_grad():
        feats = np.concatenate(
            [pre(net.stem(torch.from_numpy(x[i : i + 256]))).numpy() for i in range(0, len(x), 256)]
        )
    mean = feats.mean(axis=0)
    _, s, vt = np.linalg.svd(feats - mean, full_matrices=False)
    d = net.cfg.descriptor_dim
    basis = vt[:d]  # (D, N)
    project = net.body[-1]
    assert isinstance(project, torch.nn.Linear)
    with torch.no_grad():
        project.weight.copy_(torch.from_numpy(basis.astype(np.float32)))
        project.bias.copy_(torch.from_numpy((-basis @ mean).astype(np.float32)))
    var = s**2
    return {"templates": len(picks), "variance_kept": float(var[:d].sum() / var.sum())}


def run(cfg, data: TrainingData, out: Path, command: str = "") -> DescriptorNet:
    """`posedesc train --arch pca`: fits the projection and writes the run folder as `train` does
    (checkpoint.pt, best.pt: the same, nothing to choose; log.jsonl). cfg: a `training.train.TrainConfig`."""
    out.mkdir(parents=True, exist_ok=True)
    net = DescriptorNet(NetConfig(cfg.modality, cfg.descriptor_dim, data.spec.size, "pca", cfg.pool)).eval()
    stats = fit(net, data, seed=cfg.seed)
    ckpt = {
        "net": net.state_dict(),
        "config": asdict(cfg),
        "size": data.spec.size,
        "window_mm": data.spec.window_mm,
        "epoch": 1,
        "step": 0,
        "command": command,
        "val": None,
    }
    torch.save(ckpt, out / "checkpoint.pt")
    torch.save(ckpt, out / "best.pt")
    with (out / "log.jsonl").open("a") as f:
        f.write(json.dumps({"epoch": 1, "step": 0, "pca": stats}) + "\n")
    print(json.dumps({"pca": stats}), flush=True)
    return net
