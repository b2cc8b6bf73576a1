"""The paper's cost: L = L_triplets + L_pairs + lambda * ||w||^2 (Wohlhart & Lepetit 2015, eqs. 2-4).

Triplets and pairs are explicit index tensors into one batch of descriptors, so batch construction
(`training/batches.py`) and the cost can be tested apart."""

from __future__ import annotations

import torch
from torch import nn


def distance(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Euclidean distance per row, eps inside the square root: at distance 0 the gradient is finite
    (sqrt's is infinite there), and a dissimilar pair that collapsed must still be pushed apart.
    Shape: (N, D), (N, D) -> (N,)."""
    return torch.sqrt(((a - b) ** 2).sum(dim=1) + eps)


def triplet_cost(
    f: torch.Tensor,
    anchor: torch.Tensor,
    positive: torch.Tensor,
    negative: torch.Tensor,
    margin: float = 0.01,
) -> torch.Tensor:
    """Mean over triplets of max(0, 1 - ||f_a - f_n|| / (||f_a - f_p|| + m)).

    The ratio form does not care about the descriptors' scale: it asks only that the dissimilar one be
    farther than the similar one by a factor. Shape: f (B, D); indices (T,) -> scalar."""
    if anchor.numel() == 0:
        return f.sum() * 0.0
    d_pos = distance(f[anchor], f[positive])
    d_neg = distance(f[anchor], f[negative])
    return torch.clamp(1.0 - d_neg / (d_pos + margin), min=0.0).mean()


def pair_cost(f: torch.Tensor, first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Mean over pairs of ||f_i - f_j||^2: same object and pose, different imaging conditions.
    Shape: f (B, D); indices (P,) -> scalar."""
    if first.numel() == 0:
        return f.sum() * 0.0
    return ((f[first] - f[second]) ** 2).sum(dim=1).mean()


def weight_decay(net: nn.Module) -> torch.Tensor:
    """Sum of squared weights of the trained conv and linear layers; biases (and a frozen trunk) are not
    decayed."""
    return sum(  # type: ignore[return-value]
        (p**2).sum()
        for name, p in net.named_parameters()
        if name.endswith("weight") and p.dim() > 1 and p.requires_grad
    )


class DescriptorLoss(nn.Module):
    """The whole cost; returns the total and its terms (for the progress bar)."""

    def __init__(self, margin: float = 0.01, pair_weight: float = 1.0, decay: float = 1e-6):
        super().__init__()
        self.margin, self.pair_weight, self.decay = margin, pair_weight, decay

    def forward(
        self,
        net: nn.Module,
        f: torch.Tensor,
        triplets: torch.Tensor,
        pairs: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """f: descriptors (B, D); triplets (T, 3) and pairs (P, 2) of row indices into f."""
        lt = triplet_cost(f, triplets[:, 0], triplets[:, 1], triplets[:, 2], self.margin)
        lp = pair_cost(f, pairs[:, 0], pairs[:, 1])
        lw = weight_decay(net)
        total = lt + self.pair_weight * lp + self.decay * lw
        return total, {
            "triplet": lt.detach().item(),
            "pair": lp.detach().item(),
            "wd": self.decay * lw.detach().item(),
        }
