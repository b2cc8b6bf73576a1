"""What a frame's ground truth renders to, every annotated object at its annotated pose with the frame's
camera (the nearest surface wins, so occluders cut each other):

- the visible mask of each object, for the clutter-free bound: `posedesc evaluate --oracle-mask` sends
  each frame with everything but the instance's own pixels black, the best a foreground mask could ever
  do for a descriptor that is about the object at the centre;
- the frame's depth, for real colour frames that have none (LM-O): the objects, the table they stand on
  where no object is, through the sensor model. Whatever the frame shows that is not annotated (clutter)
  gets the table's depth, or none where there is no table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import trimesh

from index.data.bop import Instance, table_depth
from index.geometry.sensor import SensorModel
from index.templates.render import Renderer


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


def rendered_depth(
    renderer: Renderer,
    everyone: Sequence[Instance],
    meshes: Mapping[int, trimesh.Trimesh],
    w: int,
    h: int,
    rng: np.random.Generator | None = None,
    sensor: SensorModel | None = SensorModel(),
) -> np.ndarray:
    """The depth (H, W) float32 mm a sensor would have measured of a frame's ground truth: every annotated
    instance `everyone` (all of the frame's, not only those asked about: they all occlude) at its pose,
    the table (`index.data.bop.table_depth`) where no object is, 0 where neither; through `sensor` (holes at
    depth edges, noise, quantisation; None: clean) with `rng`."""
    # one render of all meshes: the z-buffer keeps the nearest surface
    _, objects = renderer.render_frame([(meshes[i.obj_id], i.R, i.t) for i in everyone], everyone[0].K, w, h)
    table = table_depth(everyone, [meshes[i.obj_id] for i in everyone], w, h)
    depth = np.where(objects > 0, objects, table).astype(np.float32)
    if sensor is None:
        return depth
    _, noisy = sensor.apply(None, depth, rng if rng is not None else np.random.default_rng(0))
    return noisy
