"""The templates every method is measured against: each object rendered from the paper's 301 template
viewpoints (and, for the full protocol, in-plane variants), one set shared by our descriptors, HOG and
LineMOD so that they differ only in how they compare patches."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from index.pose import View
from index.render import Renderer
from index.viewpoints import template_views

#: Template distance, mm: LineMOD's. The patch window is metric, so only perspective depends on it.
TEMPLATE_DISTANCE_MM = 400.0


def full_inplane(step_deg: float) -> np.ndarray:
    """In-plane angles over the whole turn, (-180, 180], `step_deg` apart (0 included)."""
    n = int(round(360.0 / step_deg))
    return (np.arange(n) - (n - 1) // 2) * (360.0 / n)


@dataclass
class TemplateSet:
    """Templates of several objects, concatenated. rgb (T, S, S, 3) uint8 or None, depth (T, S, S) mm or
    None (only what the modality needs is kept: the full protocol has tens of thousands), mask (T, S, S)
    bool where the object is; obj_ids (T,); views: their pose (in-plane included)."""

    obj_ids: np.ndarray
    views: list[View]
    rgb: np.ndarray | None
    depth: np.ndarray | None
    mask: np.ndarray
    window_mm: float

    def __len__(self) -> int:
        return len(self.views)

    def of(self, obj_id: int) -> np.ndarray:
        """Indices of one object's templates."""
        return np.flatnonzero(self.obj_ids == obj_id)


def render_templates(
    meshes: dict[int, trimesh.Trimesh],
    modality: str,
    window_mm: float,
    inplane: np.ndarray | None = None,
    progress: Callable[[int], None] | None = None,
) -> TemplateSet:
    """Renders every object from the 301 template viewpoints x `inplane` (None: in-plane 0 only)."""
    renderer = Renderer(window_mm=window_mm)
    views = template_views(3, inplane, TEMPLATE_DISTANCE_MM)
    obj_ids, rgbs, depths, masks, all_views = [], [], [], [], []
    try:
        for obj_id, mesh in meshes.items():
            t = renderer.render(mesh, views, progress=progress)
            obj_ids.append(np.full(len(views), obj_id))
            all_views += t.views
            rgbs.append(t.rgb if modality in ("rgb", "rgbd") else None)
            depths.append(t.depth if modality in ("depth", "rgbd") else None)
            masks.append(t.depth > 0)
    finally:
        renderer.close()
    return TemplateSet(
        obj_ids=np.concatenate(obj_ids),
        views=all_views,
        rgb=np.concatenate(rgbs) if rgbs and rgbs[0] is not None else None,
        depth=np.concatenate(depths) if depths and depths[0] is not None else None,
        mask=np.concatenate(masks),
        window_mm=window_mm,
    )
