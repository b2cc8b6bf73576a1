"""The pose fit in `POST /recognize` (`service.pipeline.fit`): a frame's best answer moved from its
template's pose to the pose that explains the frame, every pose field giving the fitted pose and
`template` the template's. The shipped models, one object registered at level 1 (templates ~20 deg
apart, so a template's pose is visibly off), a rendered frame at a pose between the templates."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import (
    ROOT,
    K,
    depth_png,
    frame,
    frame_fields,
    png,
    register,
    service_settings,
    wait_ready,
)

from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_error
from index.refine.depth import Outline
from index.refine.fit import Fit
from index.store.records import Match
from service.main import create_app
from service.pipeline.answer import Result
from service.pipeline.fit import EXPLAINED_WEIGHT, first, reranked

#: between level 1's viewpoints and off the in-plane grid
VIEW, UV = View(52.0, 38.0, 11.0, 600.0), (350.0, 230.0)


@pytest.fixture(scope="module")
def client(tmp_path_factory, l_shape):
    settings = service_settings(tmp_path_factory.mktemp("data"), ROOT / "models", level=1, reject_above="off")
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        register(c, l_shape, "ell")
        yield c


@pytest.fixture(scope="module")
def shot(renderer, l_shape):
    rgb, depth = frame(renderer, l_shape, VIEW, UV, wall_mm=900.0)
    ray = np.linalg.inv(K) @ np.array([UV[0], UV[1], 1.0])
    R, t = view_to_pose(VIEW, ray=ray)
    return {"rgb": rgb, "depth": depth, "R": R, "t": t}


def best(client, files: dict, **extra) -> dict:
    r = client.post("/recognize", files=files, data=frame_fields(UV, k="3", **extra))
    assert r.status_code == 200, r.text
    return r.json()["matches"][0]


def pose(m: dict) -> tuple[np.ndarray, np.ndarray]:
    return np.reshape(m["R"], (3, 3)), np.asarray(m["t"])


def template_pose(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """The pose of the answer's template, along the query's ray at the fitted distance."""
    ray = np.linalg.inv(K) @ np.array([UV[0], UV[1], 1.0])
    view = View(**m["template"], distance=float(np.linalg.norm(m["t"])))
    return view_to_pose(view, ray=ray)


def test_with_depth_the_best_answer_is_fitted_nearer_the_truth_than_its_template(client, shot):
    m = best(client, {"rgb": ("f.png", png(shot["rgb"])), "depth": ("d.png", depth_png(shot["depth"]))})
    assert m["name"] == "ell" and m["refined"] is True
    R, t = pose(m)
    R0, _ = template_pose(m)
    assert rotation_error(R, shot["R"]) < rotation_error(R0, shot["R"])
    assert rotation_error(R, shot["R"]) < 3.0
    assert np.linalg.norm(t - shot["t"]) < 5.0  # mm, at 600 mm


def test_a_fitted_answers_fields_all_give_its_fitted_pose(client, shot):
    m = best(client, {"rgb": ("f.png", png(shot["rgb"])), "depth": ("d.png", depth_png(shot["depth"]))})
    R, t = pose(m)
    # the angles are the fitted pose's, read along the ray through its origin
    view = View(m["azimuth"], m["elevation"], m["inplane"], float(np.linalg.norm(t)))
    R_angles, t_angles = view_to_pose(view, ray=t)
    assert np.abs(R_angles - R).max() < 1e-6 and np.abs(t_angles - t).max() < 1e-6
    # and u, v where that origin projects
    uv = (K @ t)[:2] / t[2]
    assert np.abs(uv - [m["u"], m["v"]]).max() < 1e-6
    assert (m["azimuth"], m["elevation"], m["inplane"]) != tuple(m["template"].values())


def test_a_colour_patch_is_not_fitted(client, shot):
    r = client.post("/recognize", files={"rgb": ("p.png", png(np.full((64, 64, 3), 90, np.uint8)))})
    m = r.json()["matches"][0]
    assert m["refined"] is False and m["u"] is None and m["v"] is None
    assert (m["azimuth"], m["elevation"], m["inplane"]) == tuple(m["template"].values())


def test_a_patch_with_depth_is_fitted_in_the_camera_it_spans(client, shot):
    """A patch with depth (no camera) is fitted against its own depth in the virtual camera it spans
    (`service.pipeline.fit.fitted_camera`), its answers posed on its optical axis: nearer the truth than its
    template, with colour and depth as with depth alone. Before, a patch was never fitted."""
    from index.features.patches import crops

    window = client.get("/objects").json()[0]["window_mm"]
    spec = replace(client.app.state.posedesc.embedders["depth"].info.spec, window_mm=window)
    rgbs, depths = crops(shot["rgb"], shot["depth"], K, UV, VIEW.distance, spec, (0.0,))
    axis = np.array([0.0, 0.0, 1.0])
    truth, _ = view_to_pose(VIEW, ray=axis)
    depth = ("d.png", depth_png(depths[0]))
    for files in ({"depth": depth}, {"rgb": ("p.png", png(rgbs[0])), "depth": depth}):
        r = client.post("/recognize", files=files, data={"k": "3", "window_mm": str(window)})
        assert r.status_code == 200, r.text
        m = r.json()["matches"][0]
        assert m["name"] == "ell" and m["refined"] is True and m["u"] is None
        R0, _ = view_to_pose(View(**m["template"], distance=VIEW.distance), ray=axis)
        error = rotation_error(np.reshape(m["R"], (3, 3)), truth)
        assert error < min(3.0, rotation_error(R0, truth)), (error, rotation_error(R0, truth))


def test_in_colour_only_the_best_answer_is_fitted_by_default(client, shot):
    r = client.post(
        "/recognize",
        files={"rgb": ("f.png", png(shot["rgb"]))},
        data=frame_fields(UV, k="3", distance_mm="600"),
    )
    matches = r.json()["matches"]
    assert len(matches) == 3 and matches[0]["refined"] is True
    assert [m["refined"] for m in matches[1:]] == [False] * (len(matches) - 1)
    assert "fit" in r.json()["timings_ms"]


def test_with_depth_the_best_three_of_the_reordered_answers_are_fitted_fully(client, shot):
    """The depth re-ordering looks at the first `depth_rerank` (20) answers coarsely, and fits the best
    `DEPTH_REFINE` (3) of them fully: those three come first, each moved off its template by its fit."""
    files = {"rgb": ("f.png", png(shot["rgb"])), "depth": ("d.png", depth_png(shot["depth"]))}
    r = client.post("/recognize", files=files, data=frame_fields(UV, k="10"))
    assert r.status_code == 200, r.text
    matches = r.json()["matches"]
    assert len(matches) == 10 and [m["refined"] for m in matches[:3]] == [True] * 3, matches
    R, _ = pose(matches[0])
    assert rotation_error(R, shot["R"]) < 3.0


def test_with_depth_one_answer_asked_is_still_chosen_among_the_fitted_ones(client, shot):
    files = {"rgb": ("f.png", png(shot["rgb"])), "depth": ("d.png", depth_png(shot["depth"]))}
    r = client.post("/recognize", files=files, data=frame_fields(UV, k="1"))
    assert r.status_code == 200, r.text
    matches = r.json()["matches"]
    assert len(matches) == 1 and matches[0]["name"] == "ell" and matches[0]["refined"] is True


def result_of(scores: list[float | None], confidences: list[float | None], n: int) -> Result:
    matches = [Match(i, f"o{i}", 10.0 * i, 20.0, 0.0, 0.1 * i) for i in range(n)]
    fits = [
        None if s is None else Fit(np.eye(3), np.array([0.0, 0.0, 500.0 + i]), s, s, 1, True)
        for i, s in enumerate(scores)
    ]
    return Result(
        "m",
        matches,
        {},
        np.array([0.0, 0.0, 1.0]),
        500.0,
        "local",
        confidences,
        None,
        [500.0 + i for i in range(n)],
        fits,
    )


def test_the_fitted_answers_are_ordered_by_the_depth_they_explain_plus_their_confidence():
    r = reranked(result_of([0.1, 0.9, 0.5, None], [0.5, 0.3, 0.2, 0.9], 5), 4)
    # 0.6, 1.2, 0.7, 0.9 (not fitted: its confidence alone); the fifth, not fitted, stays last
    assert [m.object_id for m in r.matches] == [1, 3, 2, 0, 4]
    assert r.confidences == [0.3, 0.9, 0.2, 0.5]  # each list moved with its answer
    assert r.origins_mm == [501.0, 503.0, 502.0, 500.0, 504.0]
    assert [f.score if f else None for f in r.fits] == [0.9, None, 0.5, 0.1]
    assert [m.object_id for m in first(r, 2).matches] == [1, 3] and len(first(r, 2).fits) == 2


def test_an_object_whose_measured_surface_goes_on_past_it_is_ordered_lower():
    """`beyond` (the depth's surface going on around an answer's silhouette) counts against an object by its
    least among its answers: a small object posed on a larger one's face loses to the larger one, while the
    order of one object's poses stays the fit's."""
    r = result_of([0.9, 0.8, 0.7, 0.75], [0.5, 0.5, 0.5, 0.5], 4)
    r = replace(r, matches=[replace(m, object_id=o) for m, o in zip(r.matches, [0, 1, 0, 1], strict=True)])
    # object 0: every answer with its surface going on (0.6, 0.5); object 1: one answer with none (0.0)
    out = reranked(r, 4, [Outline(b, 0.0) for b in (0.6, 0.0, 0.5, 0.4)])
    assert [m.object_id for m in out.matches] == [1, 1, 0, 0]
    assert [f.score for f in out.fits] == [0.8, 0.75, 0.9, 0.7]  # each object's poses in the fit's order
    assert [m.object_id for m in reranked(r, 4).matches] == [0, 1, 1, 0]  # without it: 1.4, 1.3, 1.25, 1.2


def test_an_answer_that_explains_more_of_the_image_is_ordered_higher():
    """The area a pose explains, as a share of the largest among the answers, weighs `EXPLAINED_WEIGHT`: a
    larger object partly hidden (its fit explaining a smaller share of its own points) passes a small object
    posed on its visible face, which its fit explains whole but which covers a fifth of the area."""
    r = result_of([0.85, 0.65, 0.5], [0.3, 0.3, 0.3], 3)
    r = replace(r, matches=[replace(m, object_id=o) for m, o in zip(r.matches, [0, 1, 2], strict=True)])
    looks = [Outline(0.0, 2000.0), Outline(0.0, 10000.0), Outline(0.0, 1000.0)]
    assert [m.object_id for m in reranked(r, 3).matches] == [0, 1, 2]  # 1.15, 0.95, 0.8
    assert EXPLAINED_WEIGHT > 0.25  # 1.15 + 0.2 w, 0.95 + w, 0.8 + 0.1 w: the larger one first
    assert [m.object_id for m in reranked(r, 3, looks).matches] == [1, 0, 2]
    assert (
        reranked(r, 3, [Outline(0.0, 0.0)] * 3).matches == reranked(r, 3).matches
    )  # nothing explained: as before


def test_colour_only_the_rotation_is_fitted_and_the_sent_centre_and_distance_kept(client, shot):
    distance = float(np.linalg.norm(shot["t"]))
    m = best(client, {"rgb": ("f.png", png(shot["rgb"]))}, distance_mm=f"{distance:.3f}")
    assert m["name"] == "ell" and m["refined"] is True
    R, t = pose(m)
    R0, t0 = template_pose(m)
    assert rotation_error(R, shot["R"]) < 5.0 < rotation_error(R0, shot["R"])
    assert np.abs(t - shot["t"]).max() < 0.01  # the sent centre and distance: the true ones
    assert abs(m["u"] - UV[0]) < 1e-6 and abs(m["v"] - UV[1]) < 1e-6


def test_a_fit_that_fails_leaves_the_answer_at_its_template(client, shot, monkeypatch):
    import service.pipeline.fit as fit

    def broken(*args, **kwargs):
        raise FloatingPointError("a degenerate outline")

    def failures() -> float:
        for line in client.get("/metrics").text.splitlines():
            if line.startswith('posedesc_pipeline_failures_total{stage="fit"}'):
                return float(line.split()[-1])
        return 0.0

    before = failures()
    monkeypatch.setattr(fit, "fit_colour", broken)  # a fault injected where a mesh could make one
    m = best(client, {"rgb": ("f.png", png(shot["rgb"]))}, distance_mm="600")
    assert m["name"] == "ell" and m["refined"] is False
    assert (m["azimuth"], m["elevation"], m["inplane"]) == tuple(m["template"].values())
    assert failures() == before + 1  # logged and counted: /metrics says the pipeline failed inside


def test_of_two_parts_the_answer_shown_best_is_chosen_first_by_what_its_kind_can_show():
    """`best_part` (a store of shape-only and textured objects, an RGB-D frame with its centre): an answer its
    model accepts with its object's colours, then one accepted without colours to check, then the rest; the
    depth's evidence only among equals."""

    from index.draw import MeshCache
    from service.pipeline.fit import best_part

    shapes: Any = SimpleNamespace(depth=MeshCache(lambda _: None))  # no depth models: no outlines
    depth, K = np.zeros((48, 64), np.float32), np.eye(3)

    def part(score: float, colour: float | None = None, reason: str | None = None) -> Result:
        return replace(result_of([score], [0.5], 1), colour_distance=colour, reason=reason)

    textured, shape = part(0.5, colour=0.1), part(0.9)
    assert best_part([shape, textured], shapes, depth, K, ceiling=0.25) == 1  # its colours agree: first
    assert best_part([shape, part(0.5, colour=0.4)], shapes, depth, K, ceiling=0.25) == 0  # another's colours
    assert best_part([shape, part(0.5, colour=0.4)], shapes, depth, K, ceiling=2.0) == 1  # no ceiling
    assert best_part([part(0.9, reason="far"), part(0.2)], shapes, depth, K, ceiling=0.25) == 1  # rejected
    assert best_part([part(0.3), part(0.8)], shapes, depth, K, ceiling=0.25) == 1  # equals: the depth's say
    assert best_part([part(0.5), part(0.5)], shapes, depth, K, ceiling=0.25) == 0  # ties: the first
    empty = replace(part(0.9), matches=[], fits=[], confidences=[], origins_mm=[])
    assert best_part([empty, part(0.1, reason="far")], shapes, depth, K, ceiling=0.25) == 1


def test_two_parts_answers_follow_the_chosen_ones_each_field_with_its_answer():
    """`service.recognition.followed`: the chosen result's answers, then the other's, every per-answer list
    padded where it was shorter (fits of answers not fitted), cut to k; its verdict and model; times summed."""
    from service.recognition import followed

    a = replace(
        result_of([0.9], [0.8, 0.7], 2), model="posedesc-depth", timings_ms={"fit": 2.0, "total": 5.0}
    )
    b = result_of([0.4, 0.3], [0.6, 0.5], 2)
    b = replace(b, matches=[replace(m, object_id=7 + i) for i, m in enumerate(b.matches)])
    b = replace(b, timings_ms={"fit": 1.0, "local": 3.0, "total": 4.0}, reason="far")
    out = followed(a, [b], 3)
    assert [m.object_id for m in out.matches] == [0, 1, 7] and out.model == "posedesc-depth"
    assert out.confidences == [0.8, 0.7, 0.6] and out.origins_mm == [500.0, 501.0, 500.0]
    assert [f.score if f else None for f in out.fits] == [0.9, None, 0.4]
    assert out.reason is None and out.timings_ms == {"fit": 3.0, "total": 9.0, "local": 3.0}


def test_of_two_parts_a_patch_is_answered_by_what_its_answer_shows_then_the_more_confident():
    """`service.recognition.best_patch_part` (a patch, no camera: no fit to judge the parts by): as `best_part`,
    an answer its model accepts with its object's colours in the patch, then one accepted without colours to
    check, then the rest; among equals the more confident; ties the first; a part without answers never. And
    `split`: an RGB-D patch is asked of each part, as a frame with its centre; a whole frame is the detection's."""
    from service.pipeline.query import Query
    from service.recognition import best_patch_part, split

    def part(confidence: float | None, reason: str | None = None) -> Result:
        return replace(result_of([None], [confidence], 1), fits=[], reason=reason)

    def chosen(parts: list[Result], colours: list[float | None] | None = None) -> int:
        return best_patch_part(parts, colours or [None] * len(parts), 0.25)

    assert chosen([part(0.9), part(0.5)], [None, 0.1]) == 1  # its colours agree: first
    assert chosen([part(0.4), part(0.9)], [None, 0.4]) == 0  # another object's colours: after the shape
    assert chosen([part(0.9, reason="lead"), part(0.3)]) == 1  # accepted first
    assert chosen([part(0.4), part(0.7)]) == 1  # then the more confident
    assert chosen([part(0.2, reason="lead"), part(0.6, reason="lead")]) == 1
    assert chosen([part(0.5), part(0.5)]) == 0 and chosen([part(None), part(0.1)]) == 1
    empty = replace(part(0.9), matches=[], confidences=[], origins_mm=[])
    assert chosen([empty, part(0.1, reason="lead")]) == 1
    d: Any = SimpleNamespace(modality="rgbd", depth=np.ones((4, 4), np.float32))
    camera = dict(fx=500.0, fy=500.0, cx=2.0, cy=2.0)
    assert split(Query(b"c", b"d"), d) and split(Query(b"c", b"d", u=2.0, v=2.0, **camera), d)
    assert not split(Query(b"c", b"d", **camera), d)  # a whole frame: the detection splits it
    assert not split(Query(b"c", b"d"), SimpleNamespace(modality="rgb", depth=None))
