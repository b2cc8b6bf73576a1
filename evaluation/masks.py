"""The visible mask of every annotated object of a frame, rendered from the ground-truth poses (the
nearest surface wins, so occluders cut it), for the clutter-free bound: `posedesc evaluate
--oracle-mask` sends each frame with everything but the instance's own pixels black, the best a
foreground mask could ever do for a descriptor that is about the object at the centre."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import trimesh

from index.bop import Instance
from index.render import Renderer


def visible_masks(
    renderer: Renderer, group: Sequence[Instance], meshes: Mapping[int, trimesh.Trimesh], w: int, h: int
) -> list[np.ndarray]:
    """One (H, W) bool mask per instance of a frame: its pixels where it is the nearest surface."""
    depths = []
    for inst in group:
        _, d = renderer.render_frame([(meshes[inst.obj_id], inst.R, inst.t)], inst.K, w, h)
        depths.append(np.where(d > 0, d, np.inf))
    stack = np.stack(depths)
    nearest, seen = np.argmin(stack, axis=0), np.isfinite(stack.min(axis=0))
    return [seen & (nearest == k) for k in range(len(group))]


def black_outside(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The frame with every pixel outside `mask` black. Shape: (H, W, 3) -> (H, W, 3)."""
    return np.where(mask[..., None], rgb, 0).astype(rgb.dtype)
