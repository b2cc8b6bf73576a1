"""Where in a whole frame an object may be, before anything names it: the detection's first stage
(`Propose`; `service.detection.verify` checks each place).

- colour: the objectness network (`index.features.objectness`, `models/posedesc-objectness.onnx`): object centres
  and how large each object looks, over an image pyramid. How large it looks is the side of its window
  in px, so each window class among the registered objects puts it at its own distance (fx * window mm /
  window px);
- depth: what stands on the support, segmented (`service.detection.depth_segments`), at the distance it is measured.

With both (RGB-D), both kinds are verified, the depth's first: where depth saw something, its distance
is measured rather than inferred from a size."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from index.features.objectness import Colour
from index.templates.windows import object_diameter, window_classes
from service.detection.depth_segments import DepthScene, depth_proposals, depth_scene, largest_visible
from service.detection.found import DEPTH_PART, Frame, Proposal
from service.errors import ApiError
from service.pipeline.query import Decoded
from service.settings import Settings


def propose(
    d: Decoded,
    K: np.ndarray,
    colour: Colour | None,
    windows: Mapping[float, frozenset[int]],
    limit: int,
    depth_limit: int,
    largest_mm: float | None = None,
    scene: DepthScene | None = None,
) -> list[Proposal]:
    """At most `limit` colour proposals and `depth_limit` depth ones for the decoded frame, best first.
    `windows`: the window classes (mm) among the registered objects, and their objects
    (`index.templates.windows.window_classes`); `colour` None when the service has no objectness model.
    `largest_mm`: the largest visible extent a registered object shows (`depth_segments.largest_visible`): a
    larger depth segment is also proposed in parts. `scene`: the depth's `depth_segments.depth_scene`, when the caller has it."""
    out: list[Proposal] = []
    if d.depth is not None:
        out += [
            Proposal(p.u, p.v, None, p.box, p.score, DEPTH_PART if p.part else "depth")
            for p in depth_proposals(d.depth, K, limit=depth_limit, largest_mm=largest_mm, scene=scene)
        ]
    if d.rgb is not None and d.modality != "depth":  # the depth model answers: its segments only
        if colour is None:
            if d.depth is None:
                raise ApiError(
                    422,
                    "this service has no objectness model (posedesc-objectness.onnx in its models dir) to find "
                    "objects in a colour frame: send u and v (and distance_mm), or depth",
                )
        else:
            focal = (K[0, 0] + K[1, 1]) / 2
            for p in colour(d.rgb, limit):
                half = p.window_px / 2
                box = (p.u - half, p.v - half, p.u + half, p.v + half)
                if d.depth is not None:  # the pipeline measures the distance at the centre: no size assumed
                    out.append(Proposal(p.u, p.v, None, box, p.score, "colour"))
                    continue
                # the network's window is of an object filling it as the model's objects fill theirs: an
                # object of another class looking that large is as much nearer or farther as its window
                one = len(windows) <= 1
                out += [
                    Proposal(p.u, p.v, focal * w / p.window_px, box, p.score, "colour", None if one else ids)
                    for w, ids in windows.items()
                ]
    return out


@dataclass(frozen=True)
class Propose:
    """The frame's proposals: at most `limit` colour places (`Settings.detect_proposals`) and `depth_limit`
    depth segments (`Settings.detect_depth_proposals`), best first. A colour detection's confidence is at
    most its proposal's score (`service.detection.report.confidence`): one under the frame's floor is
    dropped here, as it could not be reported. `colour`: the objectness network (None: the service has none).
    A frame with depth also gets its support (`depth_segments.Support`: the plane its objects stand on), which
    `service.detection.stand` holds the detections' poses to."""

    colour: Colour | None
    limit: int
    depth_limit: int
    name: str = "propose"

    @classmethod
    def build(cls, settings: Settings, colour: Colour | None) -> Propose:
        return cls(colour, settings.detect_proposals, settings.detect_depth_proposals)

    def __call__(self, frame: Frame) -> Frame:
        windows = window_classes(frame.snapshot.objects, frame.d.embedder.info.window_mm)
        largest, scene = None, None
        if frame.d.depth is not None:
            scene = depth_scene(frame.d.depth, frame.K)
            diameters = (object_diameter(r.extra) for r in frame.snapshot.objects.values())
            largest = largest_visible(d for d in diameters if d is not None)
        found = propose(frame.d, frame.K, self.colour, windows, self.limit, self.depth_limit, largest, scene)
        kept = tuple(p for p in found if p.source != "colour" or p.score >= frame.floor)
        return replace(frame, proposals=kept, support=None if scene is None else scene.support)
