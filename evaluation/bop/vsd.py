"""BOP19's Visible Surface Discrepancy of estimates on frames with real depth: the third of BOP's errors, the
one that looks only at what the camera sees, so that a pose whose difference from the truth is hidden (a mug
turned about its axis with the handle behind it, a brick turned onto a face that shows the same surface) is
right where MSSD and MSPD call it wrong.

Each estimate and its target's truth are rendered at full frame (the object's full mesh, the frame's
camera) and compared where either is visible against the recorded depth (`index.geometry.pose_error.vsd`:
delta 15 mm, distances from the camera centre, BOP19's visibility), at the misalignment tolerances
`VSD_TAUS` times the object's diameter. Only frames with recorded depth are scored: on rendered depth the
visibility test would test the renderer against itself.

A `Vsd` renders on the thread that made it (EGL): the evaluation's main thread, after the service is closed."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import trimesh

from evaluation.bop.recall import VSD_TAUS
from evaluation.paper.samples import SYNTHETIC
from index.data.bop import Instance
from index.geometry.pose_error import VSD_DELTA, render_depths, vsd
from index.templates.render import Renderer

#: What the JSON says VSD was measured against.
VSD_NOTE = (
    "BOP19's VSD (delta 15 mm, taus 0.05-0.5 d, thresholds 0.05-0.5) against each frame's recorded depth, "
    "the full mesh rendered at the estimate and the truth; AR = mean of AR_VSD, AR_MSSD and AR_MSPD"
)
NO_VSD_NOTE = (
    "not computed: the frames have no recorded depth (VSD's visibility needs it; depth rendered from the "
    "truth would test the renderer against itself): AR = mean of AR_MSSD and AR_MSPD"
)


class Vsd:
    """VSD errors (one per tau) of estimates against the recorded depth of their frames; keeps the last
    frame's depth (targets come frame by frame)."""

    def __init__(self, meshes: Mapping[int, trimesh.Trimesh], diameters: Mapping[int, float]):
        self.meshes, self.diameters = meshes, diameters
        self._renderer = Renderer()
        self._frame: tuple[int, int] | None = None
        self._depth: np.ndarray | None = None

    def test_depth(self, inst: Instance) -> np.ndarray:
        key = (inst.scene_id, inst.frame_id)
        if key != self._frame:
            depth = inst.load_depth()
            if depth is None:
                raise ValueError(f"scene {inst.scene_id} frame {inst.frame_id} has no recorded depth")
            self._frame, self._depth = key, depth.astype(np.float32)
        assert self._depth is not None
        return self._depth

    def errors(self, inst: Instance, R: np.ndarray, t: np.ndarray) -> list[float]:
        """The VSD of the estimate (R, t) of `inst`'s object against `inst`, one per `VSD_TAUS`."""
        depth = self.test_depth(inst)
        h, w = depth.shape
        est, gt = render_depths(self._renderer, self.meshes[inst.obj_id], inst.K, w, h, R, t, inst.R, inst.t)
        taus = VSD_TAUS * self.diameters[inst.obj_id]
        return [round(float(e), 4) for e in vsd(est, gt, depth, VSD_DELTA, taus, inst.K)]

    def close(self) -> None:
        self._renderer.close()


def vsd_for(
    instances: Sequence[Instance],
    meshes: Mapping[int, trimesh.Trimesh],
    diameters: Mapping[int, float],
    sent: str,
) -> Vsd | None:
    """A `Vsd` where the frames sent (`sent`: `evaluation.paper.samples.served_data`'s kind) are the
    dataset's own and every one has recorded depth, whatever the modality asked (BOP scores colour methods'
    VSD too); None otherwise (`NO_VSD_NOTE`)."""
    if sent == SYNTHETIC or not instances or any(i.depth_path is None for i in instances):
        return None
    return Vsd(meshes, diameters)
