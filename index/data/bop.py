"""Reader for BOP-format datasets (bop_toolkit, docs/bop_datasets_format.md).

A dataset folder has `models/` (obj_NNNNNN.ply in mm, models_info.json) and one or more split folders
(`test/`, `train/`, `val/`, ...) of scene folders `NNNNNN/` with `rgb/` (or `gray/`), optional `depth/`,
`scene_gt.json`, `scene_camera.json` and optional `scene_gt_info.json`. Any such scene folder works.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
import trimesh

from index.features.patches import PatchSpec, crop
from index.geometry.pose import View, pose_to_view
from index.geometry.sensor import fit_plane, plane_depth
from index.geometry.shape_symmetry import shape_symmetry, textured
from index.geometry.symmetry import bop_form, from_bop
from index.templates.mesh import diameter, load_mesh


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M (SVD). Annotations are stored to a few digits: LM-O's cam_R_m2c are
    up to 1 % off orthonormal (det 1.014 seen), enough to move a trace-based rotation error by 1-2 deg
    and to make it smaller than the viewing-direction error it bounds."""
    u, _, vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


@dataclass(frozen=True)
class Instance:
    """One annotated object in one frame. R, t: BOP cam_R_m2c (3, 3) and cam_t_m2c (3,) in mm."""

    scene_id: int
    frame_id: int
    index: int  # position in the frame's annotation list
    obj_id: int
    R: np.ndarray
    t: np.ndarray
    K: np.ndarray
    rgb_path: Path | None
    depth_path: Path | None
    depth_scale: float
    visib_fract: float  # 1.0 where scene_gt_info.json is absent
    bbox_visib: tuple[int, int, int, int] | None  # [x, y, w, h] px of the visible part (scene_gt_info)
    bbox_obj: tuple[int, int, int, int] | None = None  # [x, y, w, h] px of the whole object, hidden parts too

    @property
    def view(self) -> View:
        """The pose as (azimuth, elevation, in-plane, distance), see index/geometry/pose.py."""
        return pose_to_view(self.R, self.t)

    @property
    def centre_uv(self) -> tuple[float, float]:
        """Pixel where the object's origin projects."""
        p = self.K @ self.t
        return float(p[0] / p[2]), float(p[1] / p[2])

    def load_rgb(self) -> np.ndarray | None:
        """(H, W, 3) uint8 RGB (grey images are repeated to 3 channels)."""
        if self.rgb_path is None:
            return None
        img = cv2.imread(str(self.rgb_path), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"cannot read image {self.rgb_path}")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def load_depth(self) -> np.ndarray | None:
        """(H, W) float32 mm, 0 = no measurement."""
        if self.depth_path is None:
            return None
        d = cv2.imread(str(self.depth_path), cv2.IMREAD_UNCHANGED)
        if d is None:
            raise ValueError(f"cannot read depth {self.depth_path}")
        return d.astype(np.float32) * self.depth_scale


class BopDataset:
    """A BOP dataset folder: models and scenes."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        if not (self.root / "models" / "models_info.json").is_file():
            raise ValueError(f"{self.root} is not a BOP dataset: no models/models_info.json")
        self._symmetry_info: dict[int, dict] = {}

    @cached_property
    def models_info(self) -> dict[int, dict]:
        raw = json.loads((self.root / "models" / "models_info.json").read_text())
        return {int(k): v for k, v in raw.items()}

    @property
    def obj_ids(self) -> list[int]:
        return sorted(self.models_info)

    def mesh_path(self, obj_id: int) -> Path:
        return self.root / "models" / f"obj_{obj_id:06d}.ply"

    def mesh(self, obj_id: int, max_faces: int | None = None) -> trimesh.Trimesh:
        return load_mesh(self.mesh_path(obj_id), units="mm", max_faces=max_faces)

    @cached_property
    def declares_symmetries(self) -> bool:
        """Whether `models_info.json` states symmetries (BOP's `symmetries_*` keys on some object): if it
        does, an object without them has none; if not (YCB-Video's shape-only meshes here), nobody said."""
        return any(k.startswith("symmetries_") for info in self.models_info.values() for k in info)

    def symmetry_info(self, obj_id: int) -> dict:
        """The object's `models_info.json` entry, with, where the dataset declares no symmetries and the
        mesh has no colours, the symmetry of its shape in BOP's form (`index.geometry.shape_symmetry`: a
        shape-only object looks the same after those turns, so its pose errors must forgive them)."""
        if obj_id not in self._symmetry_info:
            info = dict(self.models_info[obj_id])
            if not self.declares_symmetries:
                mesh = self.mesh(obj_id)
                if not textured(mesh):
                    found = shape_symmetry(mesh, float(info.get("diameter") or diameter(mesh)))
                    info |= bop_form(found.symmetry, found.centre) | {"symmetry_from": "shape"}
            self._symmetry_info[obj_id] = info
        return self._symmetry_info[obj_id]

    def symmetry(self, obj_id: int) -> str | list[np.ndarray]:
        return from_bop(self.symmetry_info(obj_id))

    def scene_dirs(self, split: str = "test") -> list[Path]:
        base = self.root / split
        return sorted(p for p in base.iterdir() if (p / "scene_gt.json").is_file()) if base.is_dir() else []

    def instances(
        self, scene: int | str | Path = 2, split: str = "test", min_visib: float = 0.0
    ) -> Iterator[Instance]:
        """Every annotated instance of a scene (id in `split`, or a scene folder), frame order."""
        d = Path(scene) if isinstance(scene, Path) else self.root / split / f"{int(scene):06d}"
        yield from scene_instances(d, min_visib)


def _image_path(folder: Path, frame_id: int) -> Path | None:
    for ext in (".png", ".jpg", ".tif"):
        p = folder / f"{frame_id:06d}{ext}"
        if p.is_file():
            return p
    return None


def scene_instances(scene_dir: Path, min_visib: float = 0.0) -> Iterator[Instance]:
    """Instances of one BOP scene folder."""
    gt = json.loads((scene_dir / "scene_gt.json").read_text())
    cams = json.loads((scene_dir / "scene_camera.json").read_text())
    info_path = scene_dir / "scene_gt_info.json"
    infos = json.loads(info_path.read_text()) if info_path.is_file() else {}
    rgb_dir = scene_dir / "rgb" if (scene_dir / "rgb").is_dir() else scene_dir / "gray"
    scene_id = int(scene_dir.name) if scene_dir.name.isdigit() else -1
    for key in sorted(gt, key=int):
        frame = int(key)
        cam = cams[key]
        K = np.asarray(cam["cam_K"], float).reshape(3, 3)
        rgb_path = _image_path(rgb_dir, frame)
        depth_path = _image_path(scene_dir / "depth", frame)
        for i, ann in enumerate(gt[key]):
            info = infos[key][i] if key in infos else {}
            visib = float(info.get("visib_fract", 1.0))
            if visib < min_visib:
                continue
            bbox, whole = info.get("bbox_visib"), info.get("bbox_obj")
            yield Instance(
                scene_id=scene_id,
                frame_id=frame,
                index=i,
                obj_id=int(ann["obj_id"]),
                R=nearest_rotation(np.asarray(ann["cam_R_m2c"], float).reshape(3, 3)),
                t=np.asarray(ann["cam_t_m2c"], float).reshape(3),
                K=K,
                rgb_path=rgb_path,
                depth_path=depth_path,
                depth_scale=float(cam.get("depth_scale", 1.0)),
                visib_fract=visib,
                bbox_visib=(int(bbox[0]), int(bbox[1]), int(bbox[2]), int(bbox[3])) if bbox else None,
                bbox_obj=(int(whole[0]), int(whole[1]), int(whole[2]), int(whole[3])) if whole else None,
            )


def instance_patch(
    inst: Instance,
    spec: PatchSpec = PatchSpec(),
    rectify: bool = True,
    rgb: np.ndarray | None = None,
    depth: np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, View]:
    """The patch cropped at the true object centre and distance, and the view it shows.

    With `rectify` the true in-plane angle is undone (the paper's protocol) and the returned view has
    in-plane 0. Pass already loaded `rgb`/`depth` frames to avoid reading a frame once per instance."""
    view = inst.view
    rgb = inst.load_rgb() if rgb is None else rgb
    depth = inst.load_depth() if depth is None else depth
    inplane = view.inplane if rectify else 0.0
    prgb, pdepth = crop(rgb, depth, inst.K, inst.centre_uv, view.distance, spec, inplane=inplane)
    if rectify:
        view = View(view.azimuth, view.elevation, 0.0, view.distance)
    return prgb, pdepth, view


def table_depth(
    instances: Sequence[Instance], meshes: Sequence[trimesh.Trimesh], width: int, height: int
) -> np.ndarray:
    """Depth (mm) of the table a frame's objects stand on, for synthetic frames made from its ground
    truth: the plane through the bottoms (lowest bounding-box face, in each object's own frame) of three
    or more instances when they lie on one, within 15 mm; zeros where there is none or it is over 10 m
    away. Shape: (height, width) float32."""
    none = np.zeros((height, width), np.float32)
    if len(instances) < 3:
        return none
    bottoms = []
    for inst, m in zip(instances, meshes, strict=True):
        (x0, y0, z0), (x1, y1, _) = m.bounds
        bottoms.append(inst.R @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, z0]) + np.ravel(inst.t))
    n, d, residual = fit_plane(np.array(bottoms))
    if residual > 15.0:
        return none
    z = plane_depth(instances[0].K, n, d, (height, width))
    return np.where(z < 10_000.0, z, 0.0).astype(np.float32)
