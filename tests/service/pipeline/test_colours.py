"""`service.pipeline.colours`: the colours at the best answer's pose, measured in a colour frame sent with its
camera and the object's centre, and judged by a calibration's colour term. A real renderer draws the frame;
the object in it has the named object's shape with its own colours or with other ones."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from service_helpers import calibrated

from index.features.embed import Embedder
from index.refine.chroma import SurfaceColours
from index.refine.fit import Fit
from index.store import Match
from service.pipeline.answer import Result
from service.pipeline.colours import Colours
from service.pipeline.context import Context
from service.pipeline.query import Decoded, Query
from service.rejection import Calibration, Term

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
#: the object tilted towards the camera, 600 mm away
R = trimesh.transformations.euler_matrix(0.6, 0.3, 0.2)[:3, :3]
t = np.array([10.0, -5.0, 600.0])
COLOUR = Term(weight=1.0, threshold=0.3, slope=10.0, midpoint=0.2)


@pytest.fixture(scope="module")
def embedder(posedesc_models, tmp_path_factory) -> Embedder:
    """The test rgb model with a descriptor calibration whose colour term rejects at 0.3 (its statistic's
    own threshold, 10, rejects nothing)."""
    cal = Calibration("descriptor", 10.0, 10.0, 5.0, colour=COLOUR)
    return calibrated(posedesc_models, tmp_path_factory.mktemp("coloured-models"), "rgb", {"descriptor": cal})


def frame(renderer, mesh: trimesh.Trimesh) -> np.ndarray:
    return renderer.render_frame([(mesh, R, t)], K, 640, 480)[0]


def recoloured(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same shape, its colours' channels turned (red -> green -> blue -> red)."""
    other = mesh.copy()
    rgba = np.asarray(mesh.visual.vertex_colors).copy()
    rgba[:, :3] = rgba[:, [2, 0, 1]]
    other.visual = trimesh.visual.ColorVisuals(other, vertex_colors=rgba)
    return other


def asked(embedder: Embedder, rgb: np.ndarray, **query: object) -> tuple[Result, list[Context]]:
    """The answer "object 1 at (R, t)" to a query of `rgb`, as the pipeline leaves it before this step."""
    u, v = (K @ t)[:2] / t[2]
    fields = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "u": float(u), "v": float(v)}
    q = Query(rgb=b"", depth=None, **{**fields, **query})  # type: ignore[arg-type]
    d = Decoded("rgb", embedder, rgb, None)
    ctx = Context(q, d, None)  # type: ignore[arg-type]  # the step reads no snapshot
    result = Result(
        "posedesc-rgb", [Match(1, "l", 0.0, 0.0, 0.0, 0.1)], {}, np.array([0.0, 0.0, 1.0]), 600.0,
        "descriptor", [0.9], None, [600.0], [Fit(R, t, 1.0, 0.5, 3, True)], statistic=0.1,
    )  # fmt: skip
    return result, [ctx]


def test_its_own_colours_stand_and_another_object_s_are_rejected(renderer, l_shape, embedder):
    colours = Colours(lambda oid: SurfaceColours.of(l_shape) if oid == 1 else None)
    right = colours(*asked(embedder, frame(renderer, l_shape)))
    wrong = colours(*asked(embedder, frame(renderer, recoloured(l_shape))))
    assert right is not None and wrong is not None
    assert right.colour_distance is not None and wrong.colour_distance is not None
    assert right.colour_distance < 0.15 < 0.3 < wrong.colour_distance
    assert right.reason is None  # 0.1 + its colour distance: under the term's 0.3
    assert wrong.reason is not None and "colour distance" in wrong.reason  # the same statistic, other colours
    assert right.confidences[0] is not None and wrong.confidences[0] is not None
    assert wrong.confidences[0] < 0.5 < right.confidences[0]


def test_a_patch_a_detection_and_an_object_without_colours_are_judged_as_before(renderer, l_shape, embedder):
    colours = Colours(lambda oid: SurfaceColours.of(l_shape))
    rgb = frame(renderer, recoloured(l_shape))
    result, runs = asked(embedder, rgb)
    patch = [replace(runs[0], query=replace(runs[0].query, fx=None, fy=None, cx=None, cy=None))]
    assert colours(result, patch) is None  # no camera: no pose in the frame to look at
    estimated = [replace(runs[0], query=replace(runs[0].query, estimated=True))]
    assert colours(result, estimated) is None  # a detection's verification: its own colour check weighs it
    assert Colours(lambda oid: None)(result, runs) is None  # a shape-only object: no colours to check
    off = Colours(lambda oid: SurfaceColours.of(l_shape), setting="off")(result, runs)
    assert off is not None and off.reason is None and off.colour_distance is not None  # measured, not judged
