"""The detection's verification: each proposal checked by the recognition itself.

A depth segment's centre is its visible surface's, not where the object's origin projects, and the
re-ranking's cells are 4 px of a 64 px patch, so each segment is first screened around its centre
(`AppState.screens`: the pipeline with a light re-ranking, no sweep, no fit) on a grid of centres; the
model's whole pipeline (`AppState.pipelines`) then names the object where the screening was most confident,
gives its pose and the open-set verdict. A colour proposal (the objectness network's: the origin's
projection) goes to the whole pipeline at its own centre, whose pose fit moves it (screened too, it lost on
the validation frames: `Settings.detect_shift`). A verified answer's box is its mesh projected at its pose."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from index.draw import project
from index.store import Snapshot
from service.detection.found import Detection, Frame, Proposal
from service.detection.report import confidence
from service.errors import ApiError, NothingMeasured
from service.pipeline.query import Query
from service.state import AppState

log = logging.getLogger("service")


@dataclass(frozen=True)
class Verify:
    """Every proposal of the frame verified (`Settings.detect_shift` and `detect_depth_shift`, `detect_grids`,
    `detect_scale`, `detect_screens`: the screening's grid step as a share of a colour proposal's side and of
    a depth segment's, its grids, its scale factor and how many screenings one proposal may take)."""

    state: AppState
    shift: float
    grids: int
    scale: float
    screens: int
    keep: int = 0  # colour proposals kept after one look each (`looked`); 0: all are verified
    depth_shift: float = 0.0
    name: str = "verify"

    @classmethod
    def build(cls, state: AppState) -> Verify:
        s = state.settings
        keep = s.detect_proposals if s.detect_looked > s.detect_proposals else 0
        grid = (s.detect_shift, s.detect_grids, s.detect_scale, s.detect_screens)
        return cls(state, *grid, keep=keep, depth_shift=s.detect_depth_shift)

    def __call__(self, frame: Frame) -> Frame:
        screened: dict[Proposal, dict] = {p: {} for p in frame.proposals}
        proposals = self.looked(frame, screened) if self.keep else frame.proposals
        # each place on its own (`Settings.detect_threads` at once), answered in the proposals' order
        found = self.state.verifier.map(lambda p: self.verify(frame, p, screened[p]), proposals)
        return replace(frame, detections=tuple(x for x in found if x is not None))

    def looked(self, frame: Frame, screened: dict[Proposal, dict]) -> tuple[Proposal, ...]:
        """The proposals worth verifying: every depth one, and the best `keep` colour ones by the screening's
        confidence at their centre times their score. The network proposes any object, registered or not;
        one screening each says which look like a registered one (`Settings.detect_looked`)."""
        colour = [p for p in frame.proposals if p.source == "colour"]
        if len(colour) <= self.keep:
            return frame.proposals
        looks = {p: self.screen(frame, self.seen(frame, p), p.u, p.v, p, screened[p]) for p in colour}
        best = set(sorted(colour, key=lambda p: -max(looks[p][0], 0.0) * p.score)[: self.keep])
        return tuple(p for p in frame.proposals if p.source != "colour" or p in best)

    @staticmethod
    def seen(frame: Frame, p: Proposal) -> Snapshot:
        """The objects a proposal is verified against (a colour proposal's distance holds for one class)."""
        return frame.snapshot if p.objects is None else frame.snapshot.within(p.objects)

    def verify(self, frame: Frame, p: Proposal, screened: dict | None = None) -> Detection | None:
        """The verifier's answer at a proposal: screened at its shifts (`centred`), then the whole pipeline
        cut at the best of them; None when nothing there can be answered. `screened`: screenings made."""
        d, K = frame.d, frame.K
        seen = self.seen(frame, p)
        at = self.centred(frame, seen, p, {} if screened is None else screened)
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
        return Detection(u, v, box, confidence(result, p), result, p)

    def screen(
        self,
        frame: Frame,
        snapshot: Snapshot,
        u: float,
        v: float,
        p: Proposal,
        seen: dict,
        log_d: float | None = None,
    ) -> tuple[float, float]:
        """The screening pipeline's (confidence, -distance) of its best answer cut at (u, v) at the distance
        `exp(log_d)` (default the proposal's), (-1, 0) when nothing is there, remembered in `seen`."""
        if log_d is None and p.distance_mm is not None:
            log_d = float(np.log(p.distance_mm))
        key = (round(u, 1), round(v, 1), round(log_d, 4) if log_d is not None else 0.0)
        if key not in seen:
            q, d = frame.q, frame.d
            distance = None if log_d is None else float(np.exp(log_d))
            try:
                r = self.state.screens[d.modality](
                    replace(q, u=u, v=v, distance_mm=distance, k=1), d, snapshot
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

    def centred(self, frame: Frame, snapshot: Snapshot, p: Proposal, seen: dict) -> Query | None:
        """Where around the proposal the screening pipeline is most confident: a 3 x 3 grid of centres
        `shift` (a depth segment: `depth_shift`) of its side apart around the proposal's (and, for `grids` >
        1, grids of half the step around the best), then (a colour proposal) its distance nearer and farther
        by `scale`; at most `screens` screenings (`seen`: those made already). With nothing to screen (no
        step, no scale, not looked at), the proposal's own centre, unscreened: the whole pipeline decides.
        None when nothing there can be answered (outside the frame, no depth there)."""
        q, d = frame.q, frame.d
        w, h = d.size
        side = p.box[2] - p.box[0]  # the proposal's window (colour) or the segment's extent (depth), px
        step = (self.shift if p.source == "colour" else self.depth_shift) * side
        log_d = None if p.distance_mm is None else float(np.log(p.distance_mm))
        if step <= 0 and (log_d is None or self.scale <= 1) and not seen:  # nothing to screen: its centre
            if not (0 <= p.u < w and 0 <= p.v < h):
                return None
            return replace(q, u=p.u, v=p.v, distance_mm=p.distance_mm, estimated=True)

        def score(u: float, v: float, log_d: float | None) -> tuple[float, float] | None:
            key = (round(u, 1), round(v, 1), round(log_d, 4) if log_d is not None else 0.0)
            if key not in seen and (not (0 <= u < w and 0 <= v < h) or len(seen) >= self.screens):
                return None
            return self.screen(frame, snapshot, u, v, p, seen, log_d)

        u, v = p.u, p.v
        best = score(u, v, log_d)
        if best is None:
            return None
        for _ in range(self.grids if step > 0 else 0):  # 3 x 3 around the best so far, each step halved
            grid = [(u + i * step, v + j * step) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
            for gu, gv in grid:
                s = score(gu, gv, log_d)
                if s is not None and s > best:
                    best, cu, cv = s, gu, gv
                    u, v = cu, cv
            step /= 2
        if log_d is not None and self.scale > 1:  # then nearer and farther, at the centre found
            centre_log = log_d
            for dl in (np.log(self.scale), -np.log(self.scale)):
                s = score(u, v, centre_log + dl)
                if s is not None and s > best:
                    best, log_d = s, centre_log + dl
        if best[0] < 0:
            return None
        distance = None if log_d is None else float(np.exp(log_d))
        return replace(q, u=u, v=v, distance_mm=distance, estimated=True)


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
