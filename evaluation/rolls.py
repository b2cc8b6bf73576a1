"""Frames turned about the camera's optical axis: more validation queries from the same frames.

A camera rolled by an angle about its optical axis sees the same scene, turned: a point X in camera
coordinates is seen at Rz X, so the image is warped by the homography H = K Rz K⁻¹ (exact for any
fx, fy: no approximation but the resampling) and every annotated pose becomes (Rz R, Rz t). The object at
the centre is the same, its pose and its surroundings are seen at another in-plane angle, and the patch
the service cuts is another patch: its pixels are resampled, the clutter around it is met at another
angle, the service's roll search and re-ranking start from elsewhere. So each validation instance,
sent at several rolls, gives several nearly independent queries about the same object and pose; the
yardstick grows without a new frame.

What it does not give: new objects, new lighting, new clutter. The turned frame has black corners
(where the camera saw nothing), and its pixels are resampled once (Lanczos for colour, nearest for
depth), which softens them slightly. Instances whose centre leaves the frame at a roll are dropped at
that roll (`RolledFrames.dropped` counts them); at roll 0 every instance is sent, as without rolls."""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from index.data.bop import Instance


def parse_rolls(text: str) -> tuple[float, ...]:
    """ "0,72,144" -> (0.0, 72.0, 144.0) degrees; each distinct, in [0, 360)."""
    try:
        rolls = tuple(float(p) for p in text.split(",") if p.strip())
    except ValueError:
        raise ValueError(f"rolls must be degrees separated by commas (e.g. 0,72,144), got {text!r}") from None
    if not rolls:
        raise ValueError("rolls: give at least one angle (e.g. 0,72,144)")
    if any(not (0 <= r < 360) or not math.isfinite(r) for r in rolls) or len(set(rolls)) != len(rolls):
        raise ValueError(f"rolls must be distinct degrees in [0, 360), got {text!r}")
    return rolls


def rz(degrees: float) -> np.ndarray:
    """The rotation (3, 3) about the camera's z axis (the optical axis) by `degrees`."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homography(K: np.ndarray, degrees: float) -> np.ndarray:
    """Where a pixel of the frame goes when the camera rolls by `degrees`: K Rz K⁻¹ (3, 3)."""
    return K @ rz(degrees) @ np.linalg.inv(K)


def roll_instance(inst: Instance, degrees: float) -> Instance:
    """The instance as the rolled camera sees it: pose (Rz R, Rz t), same camera, same frame id."""
    R = rz(degrees)
    return replace(inst, R=R @ inst.R, t=R @ inst.t, bbox_visib=None)


def roll_image(image: np.ndarray, K: np.ndarray, degrees: float, depth: bool = False) -> np.ndarray:
    """The frame the rolled camera sees, same size; black (0) where it saw nothing. Colour is resampled
    with Lanczos, depth with the nearest pixel (no depth is invented between surfaces)."""
    h, w = image.shape[:2]
    flags = cv2.INTER_NEAREST if depth else cv2.INTER_LANCZOS4
    return cv2.warpPerspective(image, homography(K, degrees), (w, h), flags=flags, borderValue=0)


def inside(inst: Instance, w: int, h: int) -> bool:
    """Whether the instance's centre (where its origin projects) lies in a w × h frame, in front."""
    if inst.t[2] <= 0:
        return False
    u, v = inst.centre_uv
    return 0 <= u < w and 0 <= v < h


@dataclass
class RolledFrames:
    """`frames` (as `evaluation.queries.frame_files` yields them: instances, rgb file, depth file, depth
    scale) again at every roll of `rolls`; roll 0 sends the frame's own files and instances unchanged.
    A frame is decoded once, and only when a roll other than 0 needs it; the rolled files are PNG
    (lossless: only the warp changes the pixels)."""

    frames: Iterable[tuple[list[Instance], bytes | None, bytes | None, float]]
    rolls: Sequence[float]
    dropped: int = field(default=0, init=False)  # instances whose centre left the frame at some roll

    def __iter__(self) -> Iterator[tuple[list[Instance], bytes | None, bytes | None, float, float]]:
        """(rolled instances, rgb file, depth file, depth scale, roll degrees) per frame and roll."""
        for group, rgb, depth, scale in self.frames:
            decoded = False
            for degrees in self.rolls:
                if degrees == 0:
                    yield group, rgb, depth, scale, 0.0
                    continue
                if not decoded:
                    colour = _decode(rgb, cv2.IMREAD_COLOR)
                    ranged = _decode(depth, cv2.IMREAD_UNCHANGED)
                    shape = (colour if colour is not None else ranged).shape  # type: ignore[union-attr]
                    h, w = shape[:2]
                    K, decoded = group[0].K, True
                turned = [roll_instance(i, degrees) for i in group]
                kept = [i for i in turned if inside(i, w, h)]
                self.dropped += len(turned) - len(kept)
                if not kept:
                    continue
                rgb_out = None if colour is None else _png(roll_image(colour, K, degrees))
                depth_out = None if ranged is None else _png(roll_image(ranged, K, degrees, depth=True))
                yield kept, rgb_out, depth_out, scale, float(degrees)


def _decode(data: bytes | None, flags: int) -> np.ndarray | None:
    if data is None:
        return None
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise ValueError("could not decode a frame to roll it")
    return image


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("could not encode a rolled frame as PNG")
    return buf.tobytes()
