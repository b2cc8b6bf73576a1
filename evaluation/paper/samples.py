"""Test patches: one per annotated instance, cut at the true object centre and distance.

Real frames where the dataset has the modality's images; otherwise synthetic test scenes: every frame's
annotated objects rendered at their annotated poses with the frame's camera (so the arrangement and the
occlusions between annotated objects are the real ones), over a random background, through the sensor
model. The service protocol has a third kind where only depth is missing: the real colour frame with
depth rendered from the same ground truth (`rendered_depth_frames`). Instances are chosen by the
dataset's visible fraction in every case."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from index.data.bop import BopDataset, Instance, instance_patch, table_depth
from index.features.patches import PatchSpec
from index.geometry.pose import View
from index.templates.render import Renderer

if TYPE_CHECKING:
    from evaluation.config import Config


@dataclass
class Samples:
    """Test patches. rgb (N, S, S, 3) uint8 or None; depth (N, S, S) mm or None; views: the true view
    of each patch (in-plane 0 when rectified); source: "real" or "synthetic"; cut_mm (N,): the distance
    each was cut at (None: the true one, the views')."""

    obj_ids: np.ndarray
    frame_ids: np.ndarray
    visib: np.ndarray
    views: list[View]
    rgb: np.ndarray | None
    depth: np.ndarray | None
    source: str
    cut_mm: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.views)

    @property
    def distances(self) -> np.ndarray:
        """The distance (mm) each patch was cut at: its window spans window_mm there."""
        return self.cut_mm if self.cut_mm is not None else np.array([v.distance for v in self.views])


def select_instances(
    dataset: BopDataset, scene: int, min_visib: float, frames: Sequence[int] | None, obj_ids: Sequence[int]
) -> list[Instance]:
    """Instances of `scene` with visible fraction ≥ min_visib, in `frames` (None: all), of known objects."""
    wanted = None if frames is None else set(frames)
    return [
        inst
        for inst in dataset.instances(scene, min_visib=min_visib)
        if (wanted is None or inst.frame_id in wanted) and inst.obj_id in obj_ids
    ]


def instances_of(cfg: Config, dataset: BopDataset, obj_ids: Sequence[int]) -> list[Instance]:
    """The instances `cfg` asks for (`select_instances`); none is an error."""
    instances = select_instances(dataset, cfg.scene, cfg.min_visib, cfg.frames, obj_ids)
    if not instances:
        raise ValueError(
            f"{cfg.dataset}: no instance of scene {cfg.scene} with visible fraction ≥ {cfg.min_visib} "
            "in the frames and objects asked for"
        )
    return instances


def needs_synthetic(modality: str, instances: Sequence[Instance]) -> bool:
    """True when some instance lacks an image the modality needs."""
    need_depth = modality in ("depth", "rgbd")
    need_rgb = modality in ("rgb", "rgbd")
    return any((need_depth and i.depth_path is None) or (need_rgb and i.rgb_path is None) for i in instances)


#: What test frames are made of (the JSON's `test_data`): the dataset's own images; synthetic scenes of
#: its ground truth (`synthetic_frames`); or its real colour with depth rendered from the ground truth
#: (`rendered_depth_frames`; "rendered depth" when no colour is used)
REAL, SYNTHETIC = "real", "synthetic"
REAL_COLOUR_RENDERED_DEPTH, RENDERED_DEPTH = "real colour, rendered depth", "rendered depth"
#: what a report says of synthetic test frames
SYNTHETIC_NOTE = (
    "test frames are synthetic: the annotated objects rendered at their annotated poses with the frame's "
    "camera, on random backgrounds, through the sensor model (in-distribution for our model only)"
)
RENDERED = (REAL_COLOUR_RENDERED_DEPTH, RENDERED_DEPTH)


def served_data(modality: str, instances: Sequence[Instance], synthetic: bool | None) -> str:
    """What the service protocol sends: synthetic scenes when asked (`synthetic`) or when colour the
    modality needs is missing; the real colour (if needed) with rendered depth when only depth is
    missing; else the real frames."""
    need_depth = modality in ("depth", "rgbd")
    need_rgb = modality in ("rgb", "rgbd")
    if synthetic or (need_rgb and any(i.rgb_path is None for i in instances)):
        return SYNTHETIC
    if need_depth and any(i.depth_path is None for i in instances):
        return REAL_COLOUR_RENDERED_DEPTH if need_rgb else RENDERED_DEPTH
    return REAL


def by_frame(instances: Sequence[Instance]) -> dict[int, list[Instance]]:
    frames: dict[int, list[Instance]] = {}
    for inst in instances:
        frames.setdefault(inst.frame_id, []).append(inst)
    return frames


def real_samples(
    instances: Sequence[Instance],
    modality: str,
    spec: PatchSpec,
    rectify: bool,
    progress: Callable[[int], object] | None = None,
) -> Samples:
    """Patches from the real frames; each frame is read once."""
    rgbs, depths, views = [], [], []
    ordered = []
    for group in by_frame(instances).values():
        rgb = group[0].load_rgb() if modality in ("rgb", "rgbd") else None
        depth = group[0].load_depth() if modality in ("depth", "rgbd") else None
        for inst in group:
            prgb, pdepth, view = instance_patch(inst, spec, rectify, rgb=rgb, depth=depth)
            rgbs.append(prgb)
            depths.append(pdepth)
            views.append(view)
            ordered.append(inst)
        if progress:
            progress(len(group))
    return _samples(ordered, views, rgbs, depths, "real")


def synthetic_samples(
    dataset: BopDataset,
    instances: Sequence[Instance],
    modality: str,
    spec: PatchSpec,
    rectify: bool,
    seed: int = 0,
    progress: Callable[[int], object] | None = None,
) -> Samples:
    """Patches from synthetic frames (`synthetic_frames`)."""
    rgbs, depths, views, ordered = [], [], [], []
    for group, rgb, depth in synthetic_frames(dataset, instances, seed):
        for inst in group:
            prgb, pdepth, view = instance_patch(inst, spec, rectify, rgb=rgb, depth=depth)
            rgbs.append(prgb if modality in ("rgb", "rgbd") else None)
            depths.append(pdepth if modality in ("depth", "rgbd") else None)
            views.append(view)
            ordered.append(inst)
        if progress:
            progress(len(group))
    return _samples(ordered, views, rgbs, depths, "synthetic")


def synthetic_frames(
    dataset: BopDataset, instances: Sequence[Instance], seed: int = 0
) -> Iterator[tuple[list[Instance], np.ndarray, np.ndarray]]:
    """Per frame of `instances`: (its instances, rgb (H, W, 3) uint8, depth (H, W) float32 mm) of a
    synthetic frame: the annotated objects of the frame rendered at their annotated poses with its camera,
    standing on their table (`index.data.bop.table_depth`, textured like a background), composited over a
    random background, through the sensor model."""
    from index.geometry.sensor import SensorModel, random_background, with_support

    rng = np.random.default_rng(seed)
    sensor = SensorModel()
    meshes: dict[int, trimesh.Trimesh] = {}
    renderer = Renderer()
    try:
        for group, everyone in _with_everyone(dataset, instances):
            _load_meshes(dataset, everyone, meshes, 20_000)
            w, h = frame_size(group[0])
            rgb, depth = renderer.render_frame(
                [(meshes[i.obj_id], i.R, i.t) for i in everyone], group[0].K, w, h
            )
            far = max(float(np.linalg.norm(i.t)) for i in everyone)
            bg_rgb, bg_depth = random_background((h, w), rng, far)
            # the objects stand on their table, as in the real frames (when they show one)
            table = table_depth(everyone, [meshes[i.obj_id] for i in everyone], w, h)
            bg_depth, bg_rgb = with_support(bg_depth, bg_rgb, table, random_background((h, w), rng, far)[0])
            rgb, depth = sensor.apply(rgb, depth, rng, bg_rgb, bg_depth)
            yield group, rgb, depth
    finally:
        renderer.close()


def rendered_depth_frames(
    dataset: BopDataset,
    instances: Sequence[Instance],
    renderer: Renderer,
    meshes: dict[int, trimesh.Trimesh],
    max_faces: int,
    seed: int = 0,
) -> Iterator[tuple[list[Instance], np.ndarray]]:
    """Per frame of `instances`: (its instances, depth (H, W) float32 mm) rendered from the frame's ground
    truth (`evaluation.masks.rendered_depth`: every annotated object, the table, the sensor model), to go
    with its real colour. `renderer` must belong to the calling thread; `meshes` (dataset object id ->
    mesh) is a cache, filled with objects it lacks, loaded with at most `max_faces`."""
    from evaluation.masks import rendered_depth

    rng = np.random.default_rng(seed)
    for group, everyone in _with_everyone(dataset, instances):
        _load_meshes(dataset, everyone, meshes, max_faces)
        w, h = frame_size(group[0])
        yield group, rendered_depth(renderer, everyone, meshes, w, h, rng)


def _with_everyone(
    dataset: BopDataset, instances: Sequence[Instance]
) -> Iterator[tuple[list[Instance], list[Instance]]]:
    """Per frame of `instances`: (its instances, every annotated instance of the frame): every annotated
    object occludes, not only the selected ones."""
    scenes = {i.scene_id for i in instances}
    everyone_by_frame = by_frame([a for s in scenes for a in dataset.instances(s)])
    for frame_id, group in by_frame(instances).items():
        yield group, everyone_by_frame[frame_id]


def _load_meshes(
    dataset: BopDataset, instances: Sequence[Instance], meshes: dict[int, trimesh.Trimesh], max_faces: int
) -> None:
    for inst in instances:
        if inst.obj_id not in meshes:
            meshes[inst.obj_id] = dataset.mesh(inst.obj_id, max_faces=max_faces)


def frame_size(inst: Instance) -> tuple[int, int]:
    """(width, height) of the instance's frame: from its image when there is one, else from K."""
    import cv2

    for path in (inst.rgb_path, inst.depth_path):
        if path is not None:
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is not None:
                return img.shape[1], img.shape[0]
    return int(round(2 * inst.K[0, 2] + 1)), int(round(2 * inst.K[1, 2] + 1))


def _samples(instances, views, rgbs, depths, source: str) -> Samples:
    return Samples(
        obj_ids=np.array([i.obj_id for i in instances], int),
        frame_ids=np.array([i.frame_id for i in instances], int),
        visib=np.array([i.visib_fract for i in instances]),
        views=views,
        rgb=np.stack(rgbs) if rgbs and rgbs[0] is not None else None,
        depth=np.stack(depths) if depths and depths[0] is not None else None,
        source=source,
    )
