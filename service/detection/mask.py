"""The detection's last stage: each reported object's mask, its mesh's silhouette at the answered pose in the
frame, as COCO writes a segmentation (compressed RLE: `{"size": [h, w], "counts": "..."}`, the string of
pycocotools' `mask.encode`). It is the whole object's outline at its pose (what hides part of it is not
known), as the box is. The silhouette is of the mesh cut to `index.draw.MASK_FACES` faces
(`AppState.mask_meshes`): on LM-O's seven meshes (12-20k faces) at three poses 0.99 IoU or more with the
drawing mesh's, in a quarter to a sixth of the time (a face filled at a time, ~15 ms against 45-100)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from index.draw import silhouette
from service.detection.found import Frame
from service.state import AppState


@dataclass(frozen=True)
class Silhouettes:
    """A mask for every detection reported (only those: a frame's masks cost a silhouette each)."""

    state: AppState
    name: str = "mask"

    @classmethod
    def build(cls, state: AppState) -> Silhouettes:
        return cls(state)

    def __call__(self, frame: Frame) -> Frame:
        w, h = frame.d.size
        out = []
        for x in frame.detections:
            mesh = self.state.mask_meshes.get(x.result.matches[0].object_id)
            if mesh is None:  # deleted since it was verified
                out.append(x)
                continue
            R, t = x.result.pose(0)
            out.append(replace(x, mask=rle(silhouette(mesh, R, t, frame.K, (h, w)) > 0)))
        return replace(frame, detections=tuple(out))


def rle(mask: np.ndarray) -> dict[str, object]:
    """A boolean mask (H, W) as COCO's compressed RLE: runs over the pixels in column-major order, the first
    of background, each written as pycocotools writes them (6 bits a character, each count after the second
    less the one two before it)."""
    h, w = mask.shape
    flat = mask.T.reshape(-1)  # column-major: down each column, left to right
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    edges = np.concatenate([[0], changes, [flat.size]])
    counts = np.diff(edges).tolist()
    if flat.size and flat[0]:
        counts = [0, *counts]  # the first run is of zeros, even when empty
    return {"size": [h, w], "counts": _string(counts)}


def _string(counts: list[int]) -> str:
    out = []
    for i, c in enumerate(counts):
        x = c - counts[i - 2] if i > 2 else c
        more = True
        while more:
            b = x & 0x1F
            x >>= 5
            more = x != -1 if b & 0x10 else x != 0
            out.append(chr(48 + (b | 0x20 if more else b)))
    return "".join(out)
