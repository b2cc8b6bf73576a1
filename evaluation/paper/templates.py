"""The templates every method is measured against, one set shared by our descriptors, HOG and LineMOD so
that they differ only in how they compare patches.

The views are the service's (`index.templates.register.template_views`): the paper's 301 viewpoints at 400 mm,
fewer for symmetric objects (a "180" object keeps azimuths in [0, 180)). The service protocol uses the
very views the service registers for the model (its in-plane variants included); the paper protocol
upright ones; the full protocol gives every view in-plane variants over the whole turn (`full_inplane`):
real objects appear rolled by anything (LM-O: -105° to 177°)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from index.geometry.pose import View
from index.templates.register import TemplateConfig, template_views
from index.templates.render import Renderer, Templates


def full_inplane(step_deg: float) -> np.ndarray:
    """In-plane angles over the whole turn, (-180, 180], `step_deg` apart (0 included)."""
    n = int(round(360.0 / step_deg))
    return (np.arange(n) - (n - 1) // 2) * (360.0 / n)


@dataclass
class RenderedTemplates:
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

    def object_templates(self, obj_id: int) -> Templates:
        """One object's templates as the renderer made them (what `index.templates.register` embeds)."""
        i = self.of(obj_id)
        rgb = None if self.rgb is None else self.rgb[i]
        depth = None if self.depth is None else self.depth[i]
        return Templates([self.views[j] for j in i], rgb, depth, self.window_mm)  # type: ignore[arg-type]


def service_symmetry(symmetry: object) -> str:
    """The symmetry the service registers an object with; BOP's other discrete symmetries keep every view."""
    return symmetry if isinstance(symmetry, str) else "none"


def object_views(symmetry: object, inplane: np.ndarray | None = None) -> list[View]:
    """The service's upright template views of an object, each times `inplane` (None: upright only)."""
    views = template_views(service_symmetry(symmetry), TemplateConfig(inplane_step=0.0))
    if inplane is None:
        return views
    return [View(v.azimuth, v.elevation, float(ip), v.distance) for v in views for ip in inplane]


def render_template_set(
    meshes: dict[int, trimesh.Trimesh],
    views: dict[int, list[View]],
    modality: str,
    window_mm: float,
    progress: Callable[[int], object] | None = None,
) -> RenderedTemplates:
    """Renders every object's template `views` (a render per viewpoint, in-plane variants turned)."""
    renderer = Renderer(window_mm=window_mm)
    obj_ids: list[np.ndarray] = []
    rgbs: list[np.ndarray] = []
    depths: list[np.ndarray] = []
    masks: list[np.ndarray] = []
    all_views: list[View] = []
    try:
        for obj_id, mesh in meshes.items():
            t = renderer.render(mesh, views[obj_id], progress=progress)
            obj_ids.append(np.full(len(t.views), obj_id))
            all_views += t.views
            if modality in ("rgb", "rgbd"):
                rgbs.append(t.rgb)
            if modality in ("depth", "rgbd"):
                depths.append(t.depth)
            masks.append(t.depth > 0)
    finally:
        renderer.close()
    return RenderedTemplates(
        obj_ids=np.concatenate(obj_ids),
        views=all_views,
        rgb=np.concatenate(rgbs) if rgbs else None,
        depth=np.concatenate(depths) if depths else None,
        mask=np.concatenate(masks),
        window_mm=window_mm,
    )
