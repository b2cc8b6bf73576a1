"""Bootstrapping beyond the batch: hard templates mined from every template of every object.

The paper bootstraps over its whole training set: after a first phase it adds what violates the
constraints most. In-batch bootstrapping (`batches.bootstrap_triplets`) sees only the couple of hundred
templates a batch happens to hold, while the confusions that cost accuracy (another object's template
that looks like this view; a far-off view of the same object) usually lie elsewhere. So a bank keeps a
descriptor of every template (refreshed a part at a time: every `refresh_every` steps the next of
`parts` slices, so with thousands of in-plane variants an object a refresh stays short; a batch's own
templates after each step); before a step the batch's samples are embedded, their nearest templates in the bank -- of
other objects, and of their own object at a pose over `min_angle` away -- join the batch, and in-batch
bootstrapping picks its hard triplets among them as among the rest.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from training.batches import Batch, with_templates

Embed = Callable[[np.ndarray], np.ndarray]  # network inputs (N, C, S, S) -> descriptors (N, D)


class TemplateBank:
    """Descriptors of all templates: (objects, templates, D), possibly a few hundred steps old."""

    def __init__(self, template_inputs: np.ndarray, dim: int, refresh_every: int = 300, parts: int = 1):
        self.inputs = template_inputs  # (O, T, ...) what `refresh`'s embed takes (templates' stems), float16
        o, t = template_inputs.shape[:2]
        self.f = np.zeros((o, t, dim), np.float32)
        self.refresh_every = refresh_every
        self.parts = parts
        self.refreshed_at: int | None = None
        self._next_part = 0

    def refresh(self, embed: Embed, step: int, chunk: int = 1024) -> None:
        """The first call embeds every template; later ones the next slice of `parts`."""
        flat_in = self.inputs.reshape(-1, *self.inputs.shape[2:])
        flat_f = self.f.reshape(-1, self.f.shape[-1])
        n = len(flat_in)
        if self.refreshed_at is None:
            lo, hi = 0, n
        else:
            size = -(-n // self.parts)
            lo = self._next_part * size
            hi = min(n, lo + size)
            self._next_part = (self._next_part + 1) % self.parts
        for i in range(lo, hi, chunk):
            j = min(hi, i + chunk)
            flat_f[i:j] = embed(flat_in[i:j].astype(np.float32))
        self.refreshed_at = step

    def state_dict(self) -> dict:
        """What a resumed run needs to mine as this one would: the descriptors and where refreshing is."""
        return {"f": self.f.copy(), "refreshed_at": self.refreshed_at, "next_part": self._next_part}

    def load_state_dict(self, state: dict) -> None:
        if state["f"].shape != self.f.shape:
            raise ValueError(f"mining bank of shape {state['f'].shape}, expected {self.f.shape}")
        self.f[...] = state["f"]
        self.refreshed_at, self._next_part = state["refreshed_at"], state["next_part"]

    def due(self, step: int) -> bool:
        return self.refreshed_at is None or step - self.refreshed_at >= self.refresh_every

    def update(self, batch: Batch, f: np.ndarray) -> None:
        """Fresh descriptors of the batch's templates (rows of f, (B, D))."""
        for r, it in enumerate(batch.items):
            if it[0] == "template":
                self.f[it[1], it[2]] = f[r]

    def hard(
        self,
        f: np.ndarray,
        objects: np.ndarray,
        pose_dists: list[np.ndarray],
        n_other: int = 2,
        min_angle: float = 20.0,
    ) -> list[tuple[int, int]]:
        """For samples with descriptors f (S, D), objects (S,) and pose distances (deg) to each template
        of their object ((T,) each): the `n_other` nearest templates of other objects and the nearest of
        their own object over `min_angle` away, as (object, template index)."""
        o_n, t_n, d = self.f.shape
        flat = self.f.reshape(-1, d)
        d2 = (f**2).sum(1)[:, None] - 2 * f @ flat.T + (flat**2).sum(1)[None]  # (S, O * T)
        out: list[tuple[int, int]] = []
        for i, (o, pd) in enumerate(zip(objects, pose_dists, strict=True)):
            row = d2[i].reshape(o_n, t_n)
            other = row.copy()
            other[o] = np.inf
            k = min(n_other, other.size - t_n)
            if k > 0:
                for j in np.argpartition(other.ravel(), k - 1)[:k]:
                    out.append((int(j // t_n), int(j % t_n)))
            same = np.where(pd > min_angle, row[o], np.inf)
            if np.isfinite(same).any():
                out.append((int(o), int(np.argmin(same))))
        return out


def mine(bank: TemplateBank, net: torch.nn.Module, batch: Batch, x: torch.Tensor) -> Batch:
    """The batch with the bank's hard templates for its samples appended as rows. x: the samples'
    inputs, in the order of `batch.sample_rows`."""
    was_training = net.training
    with torch.no_grad():
        f = net.eval()(x).numpy()
    net.train(was_training)
    objects = batch.objects[batch.sample_rows]
    dists = [batch.sample_dists[int(s)] for s in batch.sample_rows]
    batch, _ = with_templates(batch, bank.hard(f, objects, dists))
    return batch
