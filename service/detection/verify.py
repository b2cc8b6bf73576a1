"""The detection's verification: each proposal checked by the recognition itself.

A depth segment's centre is its visible surface's, not where the object's origin projects, and the
re-ranking's cells are 4 px of a 64 px patch, so each segment is first screened around its centre
(`AppState.screens`: the pipeline with a light re-ranking, no sweep, no fit) on a grid of centres; the
model's whole pipeline (`AppState.pipelines`) then names the object where the screening was most confident,
gives its pose and the open-set verdict. A colour proposal (the objectness network's: the origin's
projection) goes to the whole pipeline at its own centre, whose pose fit moves it (screened too, it lost on
the validation frames: docs/experiments.md). A verified answer's box is its mesh projected at its pose."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from index.draw import project
from index.store import Snapshot
from service.detection.found import Detection, Frame, Proposal
from service.detection.report import confidence, read_detect_confidence
from service.errors import ApiError, NothingMeasured
from service.pipeline.query import Query
from service.state import AppState

log = logging.getLogger("service")

#: a depth segment is screened at a 3 x 3 grid of centres this share of its extent apart (0: verified at its
#: centre). A depth segment's centre is its surface's, not the origin's projection: screened around it and
#: verified where the screening was most confident, the real Kinect frame had 4 of 6 instances found against
#: 1 of 6; YCB-V video 0000 (real depth) recall 0.667, precision 0.381 against 0.533, 0.451 at their centres.
#: w/12 was chosen against w/8 when colour proposals were screened too (AP50 0.34 / 0.21, an earlier
#: objectness checkpoint); screening them lost on the validation frames (w/12: AP50 0.731, within 20 deg
#: 45.2 %, 1.36 s a frame against 0.844, 53.0 %, 0.62 s at their centres) and left the service
#: (docs/experiments.md)
DEPTH_SHIFT = 1 / 12


@dataclass(frozen=True)
class Verify:
    """Every proposal of the frame verified: a colour proposal at its own centre and distance, a depth
    segment where the screening is most confident on a 3 x 3 grid of centres `depth_shift` of its extent
    apart (`DEPTH_SHIFT`). Screening colour proposals too (a grid, a second finer grid, the
    distance nearer and farther), and screening more of them to verify the best, lost on the validation
    frames and left the service (docs/experiments.md)."""

    state: AppState
    depth_shift: float = 0.0
    name: str = "verify"

    @classmethod
    def build(cls, state: AppState) -> Verify:
        return cls(state, depth_shift=DEPTH_SHIFT)

    def __call__(self, frame: Frame) -> Frame:
        # each place on its own (`Settings.detect_threads` at once), answered in the proposals' order
        found = self.state.verifier.map(lambda p: self.verify(frame, p), frame.proposals)
        return replace(frame, detections=tuple(x for x in found if x is not None))

    @staticmethod
    def seen(frame: Frame, p: Proposal) -> Snapshot:
        """The objects a proposal is verified against (a colour proposal's distance holds for one class)."""
        return frame.snapshot if p.objects is None else frame.snapshot.within(p.objects)

    def verify(self, frame: Frame, p: Proposal) -> Detection | None:
        """The verifier's answer at a proposal: the whole pipeline cut where `centred` says; None when
        nothing there can be answered."""
        d, K = frame.d, frame.K
        seen = self.seen(frame, p)
        at = self.centred(frame, seen, p)
        if at is None:
            return None
        try:
            result = self.state.pipelines[d.modality](at, d, seen)
        except NothingMeasured:  # nothing measurable there (an empty depth patch): not an object
            return None
        except ApiError:  # any other refusal of a query the service made itself is a failure: counted
            log.exception("verifying the proposal at (%.1f, %.1f) failed; it is not reported", p.u, p.v)
            self.state.metrics.failed("verify")
            return None
        if not result.matches:
            return None
        best = result.matches[0]
        mesh = self.state.draw_meshes.get(best.object_id)
        R, t = result.pose(0)
        box = _box(mesh.vertices if mesh is not None else None, R, t, K, d.size, p)
        assert at.u is not None and at.v is not None  # `centred` gives a centre
        u, v = (at.u, at.v) if result.fitted(0) is None else tuple(float(x) for x in (K @ t)[:2] / t[2])
        calibrated = read_detect_confidence(d.embedder.info.extra)
        return Detection(u, v, box, confidence(result, p, calibrated), result, p)

    def screen(
        self,
        frame: Frame,
        snapshot: Snapshot,
        u: float,
        v: float,
        p: Proposal,
        seen: dict,
    ) -> tuple[float, float]:
        """The screening pipeline's (confidence, -distance) of its best answer cut at (u, v) at the proposal's
        distance (a depth segment's: none, the depth there measures it), (-1, 0) when nothing is there,
        remembered in `seen`."""
        key = (round(u, 1), round(v, 1))
        if key not in seen:
            q, d = frame.q, frame.d
            try:
                r = self.state.screens[d.modality](
                    replace(q, u=u, v=v, distance_mm=p.distance_mm, k=1), d, snapshot
                )
            except NothingMeasured:  # no depth there
                seen[key] = (-1.0, 0.0)
            except ApiError:  # a failure, not a place without an object: counted, and nothing there
                log.exception("screening (%.1f, %.1f) failed", u, v)
                self.state.metrics.failed("screen")
                seen[key] = (-1.0, 0.0)
            else:
                seen[key] = (
                    (float(r.confidences[0] or 0.0), -r.matches[0].distance) if r.matches else (-1.0, 0.0)
                )
        return seen[key]

    def centred(self, frame: Frame, snapshot: Snapshot, p: Proposal) -> Query | None:
        """Where the proposal is verified: a colour proposal (or with no step) at its own centre and
        distance, unscreened (the whole pipeline decides, its pose fit moves it); a depth segment at the
        best of a 3 x 3 grid of centres `depth_shift` of its extent apart, by the screening pipeline's
        confidence. None when nothing there can be answered (outside the frame, no depth there)."""
        q, d = frame.q, frame.d
        w, h = d.size
        step = (0.0 if p.source == "colour" else self.depth_shift) * (p.box[2] - p.box[0])
        if not (0 <= p.u < w and 0 <= p.v < h):  # a place off the frame is skipped by this check
            return None
        if step <= 0:
            return replace(q, u=p.u, v=p.v, distance_mm=p.distance_mm, estimated=True)
        seen: dict = {}
        # its own centre first, then the grid row by row: the first of equals stays
        grid = [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
        places = [(p.u, p.v)] + [(p.u + i * step, p.v + j * step) for i, j in grid]
        scored = [
            (self.screen(frame, snapshot, u, v, p, seen), u, v)
            for u, v in places
            if 0 <= u < w and 0 <= v < h
        ]
        best, u, v = max(scored, key=lambda x: x[0])  # ties: the first, the segment's own centre
        if best[0] < 0:
            return None
        return replace(q, u=u, v=v, distance_mm=p.distance_mm, estimated=True)


def _box(
    vertices: np.ndarray | None,
    R: np.ndarray,
    t: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    p: Proposal,
) -> tuple[float, float, float, float]:
    """The mesh's extent at the pose in the frame (clipped to it); without a mesh, the proposal's."""
    w, h = size
    if vertices is not None:
        px, z = project(vertices, R, t, K)
        px = px[z > 0]
        if len(px):
            x0, y0 = px.min(axis=0)
            x1, y1 = px.max(axis=0)
            return (float(max(x0, 0)), float(max(y0, 0)), float(min(x1, w)), float(min(y1, h)))
    return p.box
