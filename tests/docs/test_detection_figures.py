"""The figures docs/detection.md gives from committed results are those of their JSON (docs/results/), as
the README's tables are theirs (tests/scripts/test_readme_tables.py). The doc's other figures say where they
come from (a session, a run since re-run): those are not checked here."""

from __future__ import annotations

from doc_figures import doc, missing, num, pct, result

DOC = "docs/detection.md"


def detect(name: str) -> dict:
    """The posedesc block of a `--protocol detect` run."""
    return result(name)["posedesc"]


def recall_of(name: str, obj: int) -> str:
    return pct(detect(name)["per_object"][str(obj)]["recall"], 0)


def test_the_screening_figures_are_the_screened_runs() -> None:
    screened = detect("detect36-val-colours.json")["all"]
    assert not missing(
        doc(DOC),
        [
            f"(AP50 {num(screened['ap50'], 3)} against 0.844, found within 20° "
            f"{pct(screened['rotation_within_20'])} % against 53.0 %",
            "share within 20° are `docs/results/detect36-val-colours.json`'s",
        ],
    )


def test_the_colour_check_figures_are_its_runs() -> None:
    colours = result("detect36-val-colours.json")["false_alarms"]["posedesc"]["detections_per_frame"]
    before, after = result("detect36-val-rgbd-before.json"), result("detect36-val-rgbd-colours.json")
    b, a = before["posedesc"]["all"], after["posedesc"]["all"]
    fa = [r["false_alarms"]["posedesc"]["detections_per_frame"] for r in (before, after)]
    assert not missing(
        doc(DOC),
        [
            f"their colours say they are not there ({num(colours, 2)} a frame, "
            "`docs/results/detect36-val-colours.json`)",
            f"objects registered {num(fa[0], 2)} → {num(fa[1], 2)} a frame, precision {num(b['precision'], 2)} → "
            f"{num(a['precision'], 2)}, recall {num(b['recall'], 2)} → {num(a['recall'], 2)}; "
            "`docs/results/detect36-val-rgbd-before.json` → `detect36-val-rgbd-colours.json`",
        ],
    )


def test_the_pose_fit_figures_are_the_readme_fit_tables_runs() -> None:
    off, on = result("detect-test-nofit.json"), result("detect-test.json")
    error = [pct(r["posedesc"]["all"]["median_relative_distance_error"]) for r in (off, on)]
    assert not missing(
        doc(DOC),
        [
            f"the BOP AR of the detections from {pct(off['bop']['ar'])} to {pct(on['bop']['ar'])} and the "
            f"distance error from {error[0]} to {error[1]} % (the README's fit table: "
            "`docs/results/detect-test-nofit.json`",
        ],
    )


def test_the_bench_figures_are_bench_detect() -> None:
    bench = result("bench-detect.json")
    summary, frames = bench["summary"], bench["config"]["detect"]["frames"]
    assert not missing(
        doc(DOC),
        [
            f"(`docs/results/bench-detect.json`: a frame's p50 {num(summary['detect_p50_ms_8'], 0)} ms at 8 "
            f"objects, {num(summary['detect_p50_ms_100'], 0)} ms at 100, {frames} frames each on "
            f"{bench['machine']['cores']} cores)",
        ],
    )


def test_objects_the_objectness_network_never_saw() -> None:
    for split in ("val", "test"):  # "it proposes neither within w/8 and 12 % in its top 10"
        per_object = result(f"objectness-loo-1-8-{split}.json")["per_object_w8_12"]
        assert per_object["1"]["top10"] == per_object["8"]["top10"] == 0, split
    left_out, shipped = "detect36-test-loo-1-8.json", "detect-test.json"
    rgbd_left_out, rgbd_shipped = "detect36-test-rgbd-loo-1-8.json", "detect-test-rgbd.json"
    assert not missing(
        doc(DOC),
        [
            "it proposes neither within w/8 and 12 % in its top 10",
            f"detection finds the ape {recall_of(left_out, 1)} % of the time ({recall_of(shipped, 1)} % with the "
            f"shipped network) and the driller {recall_of(left_out, 8)} % ({recall_of(shipped, 8)} %;",
            "`docs/results/detect36-test-loo-1-8.json` against `detect-test.json`",
            f"find the ape {recall_of(rgbd_left_out, 1)} % of the time and the driller "
            f"{recall_of(rgbd_left_out, 8)} % ({recall_of(rgbd_shipped, 1)} and {recall_of(rgbd_shipped, 8)} % "
            f"with the shipped network; all 7 objects {pct(detect(rgbd_left_out)['all']['recall'])} % against "
            f"{pct(detect(rgbd_shipped)['all']['recall'])} %; rendered depth, "
            "`docs/results/detect36-test-rgbd-loo-1-8.json` against `detect-test-rgbd.json`)",
        ],
    )


def test_the_probe_by_extent() -> None:
    with_extent, without = "detect36-val-loo-1-8-extent-tolerant.json", "detect36-val-loo-1-8.json"
    cost = detect("detect36-val-shipped.json")["all"]["precision"]
    cost -= detect("detect36-val-extent-tolerant.json")["all"]["precision"]
    assert not missing(
        doc(DOC),
        [
            f"found the held-out ape on the validation frames {recall_of(with_extent, 1)} % of the time "
            f"({recall_of(without, 1)} % without; `docs/results/{with_extent}`, `{without}`) at a cost of "
            f"{pct(cost, 0)} points of precision with all seven trained on "
            "(`detect36-val-extent-tolerant.json` against `detect36-val-shipped.json`)",
        ],
    )


def test_the_readme_s_rgbd_whole_frame_figures_are_detect_test_rgbd() -> None:
    """The detection table's note gives the RGB-D whole frames' recall and precision as text
    (`scripts/readme_tables.py`): they are those of the run it cites."""
    run = result("detect-test-rgbd.json")
    a, false = run["posedesc"]["all"], run["false_alarms"]["posedesc"]["detections_per_frame"]
    said = f"recall {pct(a['recall'])}, precision {pct(a['precision'])}, {false:g} false detections a frame"
    assert not missing(doc("README.md"), [said])
