"""What a user sends to `POST /recognize` about a dataset's instances, as the service protocol and the
scripts that probe the service send it: the frame as image bytes (the dataset's own PNG/JPEG file; a
synthetic or rendered frame encoded as PNG), the camera's fx, fy, cx, cy, the centre (u, v) where the
object's origin projects, and for colour without depth the distance to the origin along that ray (‖t‖);
with depth, the frame's depth image and no distance (the service measures it)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import trimesh

from evaluation.paper.metric import K_MAX
from evaluation.paper.samples import RENDERED, SYNTHETIC, by_frame, rendered_depth_frames, synthetic_frames
from index.data.bop import BopDataset, Instance
from index.templates.render import Renderer
from service.pipeline.query import Decoded, Query, cut

#: what a user may send as an image file; anything else is encoded as PNG first
SENDABLE = (".png", ".jpg", ".jpeg")


def frame_files(
    dataset: BopDataset,
    instances: Sequence[Instance],
    modality: str,
    kind: str,
    seed: int,
    renderer: Renderer | None = None,
    meshes: dict[int, trimesh.Trimesh] | None = None,
    max_faces: int = 200_000,
) -> Iterator[tuple[list[Instance], bytes | None, bytes | None, float]]:
    """Per frame: its instances, and the rgb and depth files a user would send, with the depth scale.
    `kind`: `evaluation.paper.samples.served_data`; the rendered-depth kinds need `renderer` (of this thread)
    and `meshes` (dataset object id -> mesh; objects it lacks are added, with at most `max_faces`)."""
    colour, ranged = modality in ("rgb", "rgbd"), modality in ("depth", "rgbd")
    if kind == SYNTHETIC:
        for group, rgb, depth in synthetic_frames(dataset, instances, seed):
            yield group, png(rgb[..., ::-1]) if colour else None, png(_mm16(depth)) if ranged else None, 1.0
        return
    if kind in RENDERED:
        if renderer is None or meshes is None:
            raise ValueError(f"{kind} frames need a renderer and the meshes")
        for group, depth in rendered_depth_frames(dataset, instances, renderer, meshes, max_faces, seed):
            yield group, _rgb_file(group[0]) if colour else None, png(_mm16(depth)), 1.0
        return
    for group in by_frame(instances).values():
        first = group[0]
        rgb_file = _rgb_file(first) if colour else None
        depth_file = (_sendable(first.depth_path) or png(_depth16(first))) if ranged else None
        yield group, rgb_file, depth_file, first.depth_scale


def query(inst: Instance, rgb: bytes | None, depth: bytes | None, depth_scale: float) -> Query:
    """What a user sends about one instance: the frame, the camera, where the object's origin projects,
    and, without depth, its distance along that ray (‖t‖)."""
    K, (u, v) = inst.K, inst.centre_uv
    return Query(
        rgb=rgb,
        depth=depth,
        depth_scale=depth_scale,
        fx=K[0, 0],
        fy=K[1, 1],
        cx=K[0, 2],
        cy=K[1, 2],
        u=u,
        v=v,
        distance_mm=float(np.linalg.norm(inst.t)) if depth is None else None,
        k=K_MAX,
    )


def patch_query(q: Query, d: Decoded, window_mm: float) -> Query:
    """What a user who cuts patches sends about an instance: the patch the service cuts from the frame query
    `q` (`d`: its decoded images, as `service.pipeline.query.cut` takes them) through `window_mm` (its object's
    registered window) at the distance `q` gives (or its depth at the centre), sent with that window and
    distance and no camera (colour as PNG, depth as 16-bit PNG in mm), as `posedesc render --patches` writes
    it."""
    spec = replace(d.embedder.info.spec, window_mm=window_mm)
    p = cut(q, d.rgb, d.depth, spec, patch_distance_mm=0.0)  # (a frame's distance: sent, or its depth's)
    rgb = None if p.rgb is None else png(np.ascontiguousarray(p.rgb[0][..., ::-1]))
    depth = None if p.depth is None else png(np.round(p.depth[0]).astype(np.uint16))
    return Query(rgb=rgb, depth=depth, window_mm=window_mm, distance_mm=float(p.distance), k=q.k)


def png(image: np.ndarray) -> bytes:
    """An image (BGR or grey, 8 or 16 bit) as PNG file bytes."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("could not encode a frame as PNG")
    return buf.tobytes()


def _rgb_file(inst: Instance) -> bytes:
    return _sendable(inst.rgb_path) or png(inst.load_rgb()[..., ::-1])  # type: ignore[index]


def _sendable(path: Path | None) -> bytes | None:
    """The file itself when it is what a user may send (PNG, JPEG)."""
    return path.read_bytes() if path is not None and path.suffix.lower() in SENDABLE else None


def _depth16(inst: Instance) -> np.ndarray:
    """The instance's depth file as 16-bit in its own unit (sent with its depth_scale)."""
    return _mm16(inst.load_depth() / inst.depth_scale)  # type: ignore[operator,arg-type]


def _mm16(depth: np.ndarray) -> np.ndarray:
    return np.clip(np.round(depth), 0, 65535).astype(np.uint16)
