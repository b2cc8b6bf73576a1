"""`service.pipeline.unexplained`: what the depth leaves unexplained at the best answer's pose, measured in a
frame sent with its camera, its depth and the object's centre, and judged by a calibration's fit term. A
real renderer draws the frame: the named object alone, half hidden behind a nearer board, or another
object where the answer puts it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from service_helpers import calibrated

from index.features.embed import Embedder
from index.refine.depth import DepthModel, score_of, unexplained_of
from index.refine.fit import Fit
from index.store import Match
from service.pipeline.answer import Result
from service.pipeline.context import Context
from service.pipeline.query import Decoded, Query
from service.pipeline.unexplained import Unexplained
from service.rejection import Calibration, Term

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
#: the object tilted towards the camera, 600 mm away
R = trimesh.transformations.euler_matrix(0.6, 0.3, 0.2)[:3, :3]
t = np.array([10.0, -5.0, 600.0])
FIT = Term(weight=1.0, threshold=0.5, slope=10.0, midpoint=0.4)


@pytest.fixture(scope="module")
def embedder(posedesc_models, tmp_path_factory) -> Embedder:
    """The test depth model with a descriptor calibration whose fit term rejects above 0.5 (its statistic's
    own threshold, 10, rejects nothing)."""
    cal = Calibration("descriptor", 10.0, 10.0, 5.0, statistic="lead", weight=0.5, fit=FIT)
    return calibrated(posedesc_models, tmp_path_factory.mktemp("fitted-models"), "depth", {"descriptor": cal})


def depth_of(renderer, *placed: tuple[trimesh.Trimesh, np.ndarray, np.ndarray]) -> np.ndarray:
    return renderer.render_frame(list(placed), K, 640, 480)[1]


def board(l_shape: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    """A board 150 mm in front of the object, over the left half of its image."""
    side = float(np.ptp(l_shape.vertices, axis=0).max())
    plate = trimesh.creation.box(extents=[side, 2 * side, 5.0])
    return plate, np.eye(3), t + np.array([-side / 2, 0.0, -150.0])


def asked(embedder: Embedder, depth: np.ndarray, **query: object) -> tuple[Result, list[Context]]:
    """The answer "object 1 at (R, t)" to a query of `depth`, as the pipeline leaves it before this step."""
    u, v = (K @ t)[:2] / t[2]
    fields = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "u": float(u), "v": float(v)}
    q = Query(rgb=None, depth=b"", **{**fields, **query})  # type: ignore[arg-type]
    d = Decoded("depth", embedder, None, depth)
    ctx = Context(q, d, None)  # type: ignore[arg-type]  # the step reads no snapshot
    result = Result(
        "posedesc-depth", [Match(1, "l", 0.0, 0.0, 0.0, 0.1)], {}, np.array([0.0, 0.0, 1.0]), 600.0,
        "descriptor", [0.9], None, [600.0], [Fit(R, t, 1.0, 0.5, 3, True)], statistic=0.1,
    )  # fmt: skip
    return result, [ctx]


def test_a_nearer_object_hiding_half_of_it_is_no_evidence_against_it(renderer, l_shape):
    model = DepthModel.of(l_shape)
    alone = depth_of(renderer, (l_shape, R, t))
    hidden = depth_of(renderer, (l_shape, R, t), board(l_shape))
    assert score_of(model, R, t, K, alone) > 0.9
    # the score counts the hidden points as unexplained; the share left unexplained leaves them out
    assert score_of(model, R, t, K, hidden) < 0.75
    assert unexplained_of(model, R, t, K, alone) < 0.1  # type: ignore[operator]
    assert unexplained_of(model, R, t, K, hidden) < 0.1  # type: ignore[operator]
    # all of it hidden: the share is of at least half its seen points, so it does not fit by a few
    wall = trimesh.creation.box(extents=[2000.0, 2000.0, 5.0])
    behind = depth_of(renderer, (l_shape, R, t), (wall, np.eye(3), t - np.array([0.0, 0.0, 300.0])))
    assert unexplained_of(model, R, t, K, behind) == pytest.approx(1.0)
    assert unexplained_of(model, R, t + np.array([0.0, 0.0, -1e4]), K, alone) is None  # behind the camera


def test_its_own_surface_stands_and_another_object_s_is_rejected(renderer, l_shape, t_shape, embedder):
    step = Unexplained(lambda oid: DepthModel.of(l_shape) if oid == 1 else None)
    right = step(*asked(embedder, depth_of(renderer, (l_shape, R, t), board(l_shape))))
    wrong = step(*asked(embedder, depth_of(renderer, (t_shape, R, t))))
    assert right is not None and wrong is not None
    assert right.unexplained is not None and wrong.unexplained is not None
    assert right.unexplained < 0.1 < 0.4 < wrong.unexplained
    # 0.1 + 1 x the share: under the term's 0.5 for its own surface, above it for another object's
    assert right.reason is None and right.confidences[0] == pytest.approx(
        FIT.confidence(0.1 + right.unexplained)
    )
    assert wrong.reason is not None and "the share of it the depth leaves unexplained" in wrong.reason
    assert wrong.confidences[0] < 0.5


def test_what_it_cannot_measure_is_judged_as_before(renderer, l_shape, embedder):
    step = Unexplained(lambda oid: DepthModel.of(l_shape) if oid == 1 else None)
    depth = depth_of(renderer, (l_shape, R, t))
    result, runs = asked(embedder, depth)
    # a detection's verification (its centre estimated) is judged by its own floors
    assert step(result, [replace(runs[0], query=replace(runs[0].query, estimated=True))]) is None
    assert step(result, [replace(runs[0], query=replace(runs[0].query, u=None, v=None))]) is None  # no centre
    assert step(replace(result, matches=[Match(2, "m", 0.0, 0.0, 0.0, 0.1)]), runs) is None  # no mesh
    nothing = Decoded("depth", embedder, None, None)
    assert step(result, [replace(runs[0], decoded=nothing)]) is None  # no depth
