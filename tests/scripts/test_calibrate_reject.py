"""scripts/calibrate_reject.py on hand-made answers: the statistics it thresholds are the service's, the
filtered stand-in for left-out runs is compared with them, and the metadata it writes leaves the graph as
it was."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from evaluation.calibration import at_least
from evaluation.openset import Answers, best_values, compare_filtered
from index.features.embed import Embedder
from service.rejection import Calibration, read_calibrations


def answers() -> Answers:
    """Objects 1 and 3; run 0 both registered, run 1 without 3. Lists of 3 answers, -1 / nan past them."""
    rows = [  # run, obj, listed ids, distances
        (0, 1, [1, 1, 3], [0.1, 0.2, 0.5]),
        (0, 3, [3, 3, 1], [0.1, 0.15, 0.3]),
        (1, 1, [1, 1, -1], [0.1, 0.2, np.nan]),
        (1, 3, [1, 1, 1], [0.3, 0.32, 0.4]),  # unregistered: another object, as near as it gets
    ]
    return Answers(
        obj=[r[1] for r in rows],
        registered=[r[0] == 0 or r[1] != 3 for r in rows],
        run=[r[0] for r in rows],
        frame=[7] * len(rows),
        objects={"local": [r[2] for r in rows]},
        distances={"local": [r[3] for r in rows]},
        settings={"local": {"rerank": 400}},
        data="real",
    )


LEAD = Calibration("local", 0.0, 0.0, 0.0, statistic="lead", weight=1.0)


def test_the_best_answers_statistic_is_the_services(script):
    a = answers()
    ids, dist = a.lists("local")
    assert best_values(ids, dist, LEAD) == pytest.approx([0.1 - 0.4, 0.1 - 0.2, 0.1 - 0.1, 0.3 - 0.1])
    s, right, reg, obj = a.arrays("local", LEAD)
    assert list(right) == [True, True, True, False] and list(reg) == [True, True, True, False]
    # the stand-in for run 1 (object 3 filtered out of run 0's lists) answers the same object as the run
    cmp = compare_filtered(a, "local", LEAD)
    assert cmp["n"] == 2 and cmp["same_object"] == 1.0
    # object 1's patch: [1, 1] left of [1, 1, 3], as the run listed it; object 3's: [1] left, lead 0 (one
    # answer listed) where the run listed two more of object 1, lead 0.1: the stand-in is not exact here
    assert cmp["statistic_difference"]["median_abs"] == pytest.approx(0.05)


def test_a_reordered_first_answer_is_read_against_the_nearest_others():
    """A list the depth re-ordered (the answer listed first is not the nearest): its statistic is its distance
    less its lead over the nearest answer of another object, none when one is nearer."""
    ids = np.array([[3, 1, 3, 2], [1, 3, 1, -1]])
    dist = np.array([[0.3, 0.2, 0.25, 0.6], [0.25, 0.3, 0.2, np.nan]])
    assert best_values(ids, dist, LEAD) == pytest.approx([0.3, 0.25 - 0.05])


def test_a_threshold_is_written_never_below_the_rule_s():
    assert at_least(0.7880912) == 0.78810 and at_least(0.14937) == 0.14937 and at_least(0.123456) == 0.12346
    rows = np.array([0.7880912] * 3 + [0.9])
    assert (rows <= at_least(0.7880912)).sum() == 3  # rounded to the nearest, 0.78809 rejected all three


def test_statistics_are_parsed_per_score_kind(script):
    parse = script("calibrate_reject").statistics
    assert parse(["lead:2", "descriptor=distance"]) == {"": ("lead", 2.0), "descriptor": ("distance", 0.0)}
    for bad in (["lead"], ["distance:1"], ["mystery=lead:1"], ["vibes"]):
        with pytest.raises(ValueError):
            parse(bad)


def test_the_calibration_goes_into_the_metadata_only(script, posedesc_models, tmp_path):
    import onnx

    model, out = posedesc_models / "posedesc-rgb.onnx", tmp_path / "posedesc-rgb.onnx"
    cal = Calibration("descriptor", 0.3, 9.0, 0.2, statistic="lead", weight=2.0, settings={"level": 3})
    script("calibrate_reject").write_metadata(model, out, {"descriptor": cal.to_json()})
    assert onnx.load(str(out)).graph.SerializeToString() == onnx.load(str(model)).graph.SerializeToString()
    written = read_calibrations(Embedder(out).info.extra)["descriptor"]
    assert written == cal and written.settings == {"level": 3}


def videos(root: Path) -> None:
    """A BOP dataset of three videos (scenes 0, 1, 2), no objects or frames: enough to split."""
    (root / "models").mkdir()
    (root / "models" / "models_info.json").write_text("{}")
    for s in (0, 1, 2):
        (root / "test" / f"{s:06d}").mkdir(parents=True)
        (root / "test" / f"{s:06d}" / "scene_gt.json").write_text("{}")


def test_collected_answers_are_read_again_only_for_the_same_network(
    script, posedesc_models, tmp_path, monkeypatch
):
    """The cache of collected answers is the network's: a calibration written into the file keeps it, another
    network under the same file name (a retrained model) collects its own."""
    from evaluation.calibration import write_metadata

    mod = script("calibrate_reject")
    collected: list[str] = []

    def collect(model, dataset, frames, sets, scenes, seed=0):
        collected.append(Embedder(model).graph_digest)
        return answers()

    monkeypatch.setattr(mod, "collect", collect)
    model = tmp_path / "posedesc-x.onnx"
    model.write_bytes((posedesc_models / "posedesc-rgb.onnx").read_bytes())
    args = argparse.Namespace(
        model=model, dataset=tmp_path, cache=tmp_path / "cache", video_split=None, scene=2, seed=0
    )
    first = mod.answers(args, "val", [1, 2], [[1, 3]])
    assert first.obj == answers().obj and len(collected) == 1
    mod.answers(args, "val", [1, 2], [[1, 3]])
    write_metadata(model, model, {"note": "a calibration"})  # a calibration: the same network
    mod.answers(args, "val", [1, 2], [[1, 3]])
    assert len(collected) == 1
    model.write_bytes((posedesc_models / "posedesc-depth.onnx").read_bytes())  # another network, same name
    mod.answers(args, "val", [1, 2], [[1, 3]])
    assert len(collected) == 2 and collected[0] != collected[1]


def test_a_video_split_validates_on_the_videos_named_and_tests_on_the_rest(script, tmp_path):
    """`--video-split 0,1`: leave-one-video-out, the threshold chosen on two videos and measured on the
    third; every video named: no test; a video the dataset lacks: a one-line error."""
    videos(tmp_path)
    scenes_of = script("calibrate_reject").scenes_of

    def split(v: str | None) -> tuple[list[int], list[int]]:
        args = argparse.Namespace(video_split=v, dataset=tmp_path, scene=2)
        return scenes_of(args, "val"), scenes_of(args, "test")

    assert split("0") == ([0], [1, 2])
    assert split("0,2") == ([0, 2], [1])
    assert split("0,1,2") == ([0, 1, 2], [])
    assert split(None) == ([2], [2])
    with pytest.raises(SystemExit, match="no scene 5"):
        split("1,5")


def test_each_video_is_measured_with_the_calibration_chosen_on_the_others(script, posedesc_models, tmp_path):
    """`--leave-one-video-out`: the fit sees the other videos' rows only, each video is measured alone, and
    `--held-out-models` gets the model calibrated without that video, its graph unchanged."""
    import onnx

    a = answers()
    a.scene = [0, 1, 0, 1]  # video 0: object 1 in both runs; video 1: object 3, registered and then not
    seen: list[list[int]] = []

    def fit(x: Answers, kind: str) -> tuple[Calibration, dict]:
        seen.append(sorted(set(x.scene)))
        return replace(LEAD, threshold=0.25 if x.scene[0] == 1 else 0.05), {}

    def describe(cal: Calibration, videos: list[int]) -> dict:
        return {**cal.to_json(), "dataset": "+".join(map(str, videos))}

    model = tmp_path / "posedesc-rgb.onnx"
    model.write_bytes((posedesc_models / "posedesc-rgb.onnx").read_bytes())
    beside = tmp_path / "posedesc-depth.onnx"  # another model of its folder: copied as it is
    beside.write_bytes((posedesc_models / "posedesc-depth.onnx").read_bytes())
    args = argparse.Namespace(fold=1, held_out_models=tmp_path / "held", model=model)
    per_video, mean = script("calibrate_reject").held_out(args, a, [[1, 3], [1]], fit, describe)
    assert seen == [[1], [0]]  # video 0 is measured with the calibration of video 1, and the other way
    assert per_video["0"]["calibrated_on"] == [1] and per_video["0"]["thresholds"] == {"local": 0.25}
    assert per_video["1"]["thresholds"] == {"local": 0.05}
    assert per_video["0"]["test"]["local"]["per_unregistered_object"].keys() == {"1"}
    unknown = per_video["1"]["test"]["local"]["per_unregistered_object"]["3"]
    assert unknown["n"] == 1 and unknown["n_registered"] == 0  # run 1, object 3 unregistered: video 1's alone
    assert mean["local"]["videos"] == [0, 1]
    for video, threshold in (("000000", 0.25), ("000001", 0.05)):
        written = read_calibrations(Embedder(tmp_path / "held" / video / model.name).info.extra)["local"]
        assert written.threshold == threshold
    assert onnx.load(str(tmp_path / "held" / "000000" / model.name)).graph == onnx.load(str(model)).graph
    assert (tmp_path / "held" / "000001" / beside.name).read_bytes() == beside.read_bytes()


@pytest.mark.parametrize(
    "extra, says",
    [
        (["--held-out-models", "held"], "--held-out-models: only with --leave-one-video-out"),
        (["--choose-weights"], "--choose-weights: only with --leave-one-video-out"),
        (["--leave-one-video-out", "--video-split", "0"], "not with --video-split or --shipped"),
        (["--leave-one-video-out", "--out", "nowhere/posedesc-rgb.onnx"], "--out: no folder nowhere"),
    ],
)
def test_what_a_left_out_video_cannot_be_is_one_line(
    script, posedesc_models, tmp_path, monkeypatch, extra, says
):
    """Options that do not go together, or a model written nowhere, stop the script in one line before any
    answer is collected."""
    videos(tmp_path)
    argv = [
        "calibrate_reject",
        str(posedesc_models / "posedesc-rgb.onnx"),
        "--dataset",
        str(tmp_path),
        *extra,
    ]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", argv)
    with pytest.raises(SystemExit, match=says):
        script("calibrate_reject").main()
