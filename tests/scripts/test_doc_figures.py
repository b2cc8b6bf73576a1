"""The figures docs/experiments.md gives for this session's measurements are those of their committed JSONs
(docs/results/): the patch windows before and after, the rules per video and the thresholds chosen
leave-one-video-out, the catalogue objectness network's validation, the second depth network's runs, the five
screening places, the two places verified, the quiet speed run, the area weight made again through the chain,
the colour fit models kept on disk (a store of shape-only and textured objects, and patches:
`test_doc_figures_mixed.py`)."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


def experiments() -> str:
    return " ".join((ROOT / "docs" / "experiments.md").read_text().split())


def pct(x: float) -> str:
    return f"{100 * x:.1f}"


def test_the_patch_windows_figures_are_their_jsons() -> None:
    text = experiments()
    before = json.loads((RESULTS / "patch-windows-before.json").read_text())["all"]
    after = json.loads((RESULTS / "patch-windows.json").read_text())["all"]
    row_before = (
        f"| {before['right']} / {before['n']} | {before['unknown']} | {before['wrong']} | "
        f"**{before['confidently wrong']}** |"
    )
    row_after = f"| **{after['right']} / {after['n']}** | {after['unknown']} | {after['wrong']} | **{after['confidently wrong']}** |"
    assert row_before in text and row_after in text


def test_the_rules_and_thresholds_by_video_are_their_json() -> None:
    text = experiments()
    result = json.loads((RESULTS / "rules-by-video.json").read_text())
    for name, lovo in result["lovo"].items():
        chosen, shipped = pct(lovo["mean_f1_left_out"]), pct(lovo["mean_f1_left_out_shipped"])
        assert f"| {chosen} | **{shipped}** |" in text, name
    support = next(r for k, r in result["rules"].items() if k.startswith("support"))
    for video, r in support["videos"].items():
        p_with, p_without = pct(r["with"]["precision"]), pct(r["without"]["precision"])
        assert f"| {video} | " in text and (f"{p_with} / {p_without}" in text), video


def test_the_catalogue_objectness_figures_are_its_json() -> None:
    text = experiments()
    result = json.loads((RESULTS / "objectness-catalogue-val.json").read_text())
    by_window = pct(result["recall_by_window"]["w/8, 12%"]["top20"])
    by_extent = pct(result["recall_by_extent_and_true_diameter"]["w/8, 12%"]["top20"])
    assert f"by window {by_window} %, by extent {by_extent} %" in text
    test = json.loads((RESULTS / "objectness-catalogue-test.json").read_text())  # reported once, on test
    by_window = pct(test["recall_by_window"]["w/8, 12%"]["top20"])
    by_extent = pct(test["recall_by_extent_and_true_diameter"]["w/8, 12%"]["top20"])
    assert test["split"] == "test" and f"by window {by_window} %, by extent {by_extent} %" in text


def test_the_colours_in_the_open_set_are_the_calibration_s_json() -> None:
    text = experiments()
    rgb = json.loads((RESULTS / "reject-posedesc-rgb.json").read_text())
    six = rgb["test"]["local"]["by_registered"]["6"]
    assert rgb["calibrations"]["local"]["colour"]["weight"] == 1.0
    from doc_figures import pct as rounded  # halves to even on the stored value, as the docs round

    row = (
        f"| **{pct(six['rejected_unknown'])} %** | **{pct(six['rejected_registered'])} %** | "
        f"{rounded(six['rejected_right'])} % | {pct(six['rejected_wrong'])} % |"
    )
    assert row in text
    val = rgb["calibrations"]["local"]["at_threshold"]["rejected_registered"]
    assert f"**not met** ({pct(six['rejected_registered'])} %; on validation {pct(val)} %" in text


def test_the_detection_confidence_figures_are_its_json() -> None:
    text = experiments()
    result = json.loads((RESULTS / "detect-confidence-depth.json").read_text())
    for video, r in result["leave_one_video_out"].items():
        before, after = r["verifier"], r["calibrated"]
        assert f"| {video} | {pct(before['ap50'])} / " in text and f"{pct(after['ap50'])}" in text, video
        right = pct(after["right_at_0.5"])
        assert f"| 0 / {after['at_0.5']} ({right} %) |" in text, video
    mean = result["mean_left_out"]
    assert f"| mean | {pct(mean['verifier']['ap50'])} / **{pct(mean['calibrated']['ap50'])}** |" in text
    cal = result["calibration"]
    assert f"slope {cal['slope']:.2f}, midpoint {cal['midpoint']:.3f}" in text


def _right(name: str) -> tuple[list[tuple[float, float]], tuple[float, float]]:
    """Per YCB-V video (right object with the open set on, off) of `ycbv-service-depth-S-<name>.json`, and
    pooled by instances."""
    runs = [json.loads((RESULTS / f"ycbv-service-depth-{s}-{name}.json").read_text()) for s in range(3)]
    per = [
        (r["methods"]["ours"]["k1"]["180"], r["open_set_off"]["methods"]["ours"]["k1"]["180"]) for r in runs
    ]
    n = [r["n_samples"] for r in runs]
    pooled = tuple(sum(w * x[i] for w, x in zip(n, per, strict=True)) / sum(n) for i in (0, 1))
    return per, (pooled[0], pooled[1])


def _rejected(json_name: str) -> list[tuple[float, float]]:
    """Per video (unknowns, registered rejected) of a leave-one-video-out calibration, then their mean."""
    held = json.loads((RESULTS / json_name).read_text())["leave_one_video_out"]
    rows = []
    for _, p in sorted(held.items()):
        by = p["test"]["descriptor"]["by_registered"]
        b = by[min(by, key=int)]
        rows.append((b["rejected_unknown"], b["rejected_registered"]))
    return rows + [(sum(r[0] for r in rows) / 3, sum(r[1] for r in rows) / 3)]


def test_the_second_depth_network_s_figures_are_their_jsons() -> None:
    text = experiments()
    for label, name in (
        ("shipped", "lovo"),
        ("single solids in training", "solids"),
        ("the two joined (fit weight 0.2, as shipped)", "joined"),
        ("the two joined, fit weight 0.1", "joined-fit0.1"),
    ):
        per, pooled = _right(name)
        cells = " | ".join(f"{pct(on)} / {pct(off)}" for on, off in [*per, pooled])
        assert f"| {label} | {cells} | `ycbv-service-depth-S-{name}.json` |" in text
    for label, json_name in (
        ("shipped", "reject-posedesc-depth-real.json"),
        ("single solids in training", "reject-depth-solids-real.json"),
        ("the two joined, fit weight 0.2", "reject-depth-joined-real.json"),
        ("the two joined, fit weight 0.1", "reject-depth-joined-fit0.1-real.json"),
    ):
        cells = " | ".join(f"{pct(u)} / {pct(r)}" for u, r in _rejected(json_name))
        assert f"| {label} | {cells} | `{json_name}` |" in text


def test_the_joined_depth_network_s_detection_figures_are_their_jsons() -> None:
    text = experiments()
    for label, name in (("shipped", "lovo"), ("the two joined (fit weight 0.2)", "joined")):
        runs = [
            json.loads((RESULTS / f"ycbv-detect-rgbd-{s}-{name}.json").read_text())["posedesc"]["all"]
            for s in range(3)
        ]
        targets, hits = sum(r["targets"] for r in runs), sum(r["hits"] for r in runs)
        found = sum(r["true_positives"] for r in runs)
        cells = [f"{pct(r['recall'])} / {pct(r['precision'])}" for r in runs]
        cells.append(f"{pct(found / targets)} / {pct(found / hits)}")
        assert f"| {label} | {' | '.join(cells)} | `ycbv-detect-rgbd-S-{name}.json` |" in text


def test_the_five_screening_places_figures_are_their_jsons() -> None:
    text = experiments()

    def run(name: str) -> dict:
        return json.loads((RESULTS / f"screen5-{name}.json").read_text())

    for name in ("grid", "descriptor-first-2", "descriptor-first-3", "axial", "diagonals"):
        r = run(f"val-rgbd-{name}")
        a = r["posedesc"]["all"]
        cells = [pct(a["recall"]), pct(a["precision"]), pct(a["ap50"]), pct(r["bop"]["ar"])]
        row = " | ".join(f"**{c}**" if name == "diagonals" else c for c in cells)
        assert f"| {row} | `screen5-val-rgbd-{name}.json` |" in text, name
    for video, name in (("0000", "ycbv-0"), ("0001", "ycbv-1"), ("0002", "ycbv-2"), ("LM-O", "val-depth")):
        cells = []
        for grid in ("grid", "diagonals"):
            a = run(f"{name}-{grid}")["posedesc"]["all"]
            cells.append(f"{pct(a['recall'])} / {pct(a['precision'])}")
        assert f" | {cells[0]} | {cells[1]} | `screen5-{name}-{{grid,diagonals}}.json` |" in text, video
    p50 = {
        (g, n): run(f"bench-{g}-{n}")["sections"]["detect"]["by_objects"]["8"]["rgbd"]["p50_ms"]
        for g in ("grid", "diagonals")
        for n in (1, 2)
    }
    said = (
        f"p50 {p50['grid', 1]:,.0f} and {p50['grid', 2]:,.0f} ms with the grid, {p50['diagonals', 1]:,.0f} and "
        f"{p50['diagonals', 2]:,.0f} ms with the diagonals"
    )
    assert said in text
    for name, shipped in (("test-rgbd", "detect-test-rgbd"), ("test-rgbd-loo", "detect36-test-rgbd-loo-1-8")):
        new = run(f"{name}-diagonals")["posedesc"]["all"]
        old = json.loads((RESULTS / f"{shipped}.json").read_text())["posedesc"]["all"]
        a, b = (" / ".join(pct(r[k]) for k in ("recall", "precision", "ap50")) for r in (new, old))
        assert (
            f"{a} against {b}" in text
            and f"(`screen5-{name}-diagonals.json` against `{shipped}.json`" in text
        )


def test_the_two_places_verified_figures_are_their_jsons() -> None:
    text = experiments()

    def cell(name: str) -> str:
        a = json.loads((RESULTS / f"{name}.json").read_text())["posedesc"]["all"]
        return " / ".join(pct(a[k]) for k in ("recall", "precision", "ap50"))

    for label, name in (
        ("YCB-V 0000", "ycbv-0"),
        ("YCB-V 0001", "ycbv-1"),
        ("YCB-V 0002", "ycbv-2"),
        ("LM-O validation, the depth model (rendered depth)", "val-depth"),
    ):
        cells = [
            cell(f"screen5-{name}-grid"),
            cell(f"verify2-{name}-best-fit"),
            cell(f"verify2-{name}-second-look"),
        ]
        assert f"| {label} | {' | '.join(cells)} | `verify2-{name}-*.json` |" in text, label


def test_the_quiet_speed_run_s_figures_are_its_json() -> None:
    text = experiments()
    loaded = json.loads((RESULTS / "bench-roll-28.json").read_text())["summary"]
    quiet = json.loads((RESULTS / "bench-roll-54.json").read_text())["summary"]

    def ms(s: dict, key: str) -> str:
        return f"{s[key]:.1f} ms"

    rows = [
        f"| from a decoded patch to the answer, p50 | {ms(loaded, 'decoded_to_answer_p50_ms_100_q1')} | "
        f"{ms(quiet, 'decoded_to_answer_p50_ms_100_q1')} |",
        f"| the upright baseline (the descriptor and the search alone), same run | "
        f"{ms(loaded, 'decoded_to_answer_upright_p50_ms_100_q1')} | {ms(quiet, 'decoded_to_answer_upright_p50_ms_100_q1')} |",
        f"| the first over the second | {loaded['decoded_to_answer_vs_upright_100_q1']:.1f}× | "
        f"{quiet['decoded_to_answer_vs_upright_100_q1']:.1f}× |",
        f"| {ms(loaded, 'roll_http_frame_p50_ms')}; {loaded['roll_http_frame_requests_per_s_4_clients']:.1f} /s | "
        f"{ms(quiet, 'roll_http_frame_p50_ms')}; {quiet['roll_http_frame_requests_per_s_4_clients']:.1f} /s "
        f"(1 client: {quiet['roll_http_frame_requests_per_s']:.1f}) |",
        f"| {loaded['roll_register_20k_faces_s']:.2f} s | {quiet['roll_register_20k_faces_s']:.2f} s "
        f"({quiet['roll_register_cpu_s']:.2f} CPU-seconds) |",
    ]
    for row in rows:
        assert row in text, row
    stages = json.loads((RESULTS / "bench-roll-54.json").read_text())["sections"]["roll"]["stages_ms_100_q1"]
    listed = ", ".join(
        f"{k} {stages[k]:.2f}" for k in ("cut", "mask", "embed", "search", "local", "sweep", "refine")
    )
    assert f"the stages' medians in that run: {listed} ms)" in text, listed


def test_the_depth_open_set_s_weights_chosen_per_video_are_their_json() -> None:
    text = experiments()
    result = json.loads((RESULTS / "reject-depth-real-weights.json").read_text())["weights_left_out"][
        "descriptor"
    ]
    for video, row in result["videos"].items():
        chosen, shipped = row["chosen"], row["shipped"]
        assert f"| {int(video):04d} | " in text
        figures = (
            f"| {chosen['auc_others']:.3f} | {pct(chosen['rejected_unknown'])} / {pct(chosen['rejected_registered'])} "
            f"| {pct(shipped['rejected_unknown'])} / {pct(shipped['rejected_registered'])} |"
        )
        assert figures in text, figures
    mean = result["mean"]
    assert (
        f"| **{pct(mean['chosen']['rejected_unknown'])} / {pct(mean['chosen']['rejected_registered'])}** | "
        f"{pct(mean['shipped']['rejected_unknown'])} / {pct(mean['shipped']['rejected_registered'])} |"
    ) in text

    def fixed(lead: float | None, fit: float) -> str:
        rows = [
            next(r for r in v["tried"] if r["lead"] == lead and r["fit"] == fit)
            for v in result["videos"].values()
        ]
        unknown = sum(r["rejected_unknown"] for r in rows) / len(rows)
        registered = sum(r["rejected_registered"] for r in rows) / len(rows)
        return f"{pct(unknown)} / {pct(registered)}"

    assert f"the distance + 0.2 gives {fixed(None, 0.2)} and the distance + 0.6 {fixed(None, 0.6)}" in text


def test_the_area_weight_by_video_is_its_json() -> None:
    text = experiments()
    result = json.loads((RESULTS / "area-weight-lovo.json").read_text())
    runs = result["runs"]
    for w in result["weights"]:
        cells = " | ".join(
            f"{pct(runs[f'{w}/{v}']['right'])} / {pct(runs[f'{w}/{v}']['right_open_set_off'])}"
            for v in range(3)
        )
        assert f"{cells} |" in text, (w, cells)

    def pooled(w: str, videos: list[int], metric: str) -> float:
        return sum(runs[f"{w}/{v}"][metric] * runs[f"{w}/{v}"]["n"] for v in videos) / sum(
            runs[f"{w}/{v}"]["n"] for v in videos
        )

    for metric in ("right", "right_open_set_off"):  # each video's weight chosen on the other two, again
        lovo = result["lovo"][metric]
        for v in range(3):
            others = [o for o in range(3) if o != v]
            chosen = max(
                result["weights"], key=lambda w: (round(pooled(w, others, metric), 4), w == result["shipped"])
            )
            assert lovo[str(v)]["chosen"] == chosen
    off = result["lovo"]["right_open_set_off"]
    assert (
        f"pooled {pct(off['pooled_chosen'])} % against the shipped weight's {pct(off['pooled_shipped'])}"
        in text
    )
    on = result["lovo"]["right"]
    assert f"pooled {pct(on['pooled_chosen'])} % both" in text and on["pooled_chosen"] == on["pooled_shipped"]


def test_the_area_weight_made_again_through_the_chain_is_its_jsons() -> None:
    """The per-video rows at 0.3 (the README's runs) and at 0.5 with its own open set, the depth open set's
    unknowns rejected per video, and the pooled figures."""
    text = experiments()

    def runs(prefix: str) -> list[dict]:
        return [
            json.loads((RESULTS / f"{prefix}ycbv-service-depth-{v}-lovo.json").read_text()) for v in range(3)
        ]

    def cell(rs: list[dict]) -> str:
        n = [r["n_samples"] for r in rs]
        on = [r["methods"]["ours"]["k1"]["180"] for r in rs]
        off = [r["open_set_off"]["methods"]["ours"]["k1"]["180"] for r in rs]
        pooled = (
            sum(a * b for a, b in zip(on, n, strict=True)) / sum(n),
            sum(a * b for a, b in zip(off, n, strict=True)) / sum(n),
        )
        return [f"{pct(a)} / {pct(b)}" for a, b in [*zip(on, off, strict=True), pooled]]

    shipped, again = cell(runs("")), cell(runs("area05-"))
    for name, a, b in zip(
        ("0000 (60)", "0001 (80)", "0002 (120)", "pooled (260)"), shipped, again, strict=True
    ):
        assert f"| {name} | {a} | {b} |" in text, name
    for prefix, weight in (("", "0.3"), ("area05-", "0.5")):
        lovo = json.loads((RESULTS / f"{prefix}reject-posedesc-depth-real.json").read_text())[
            "leave_one_video_out"
        ]
        rows = []
        for v in "012":
            by = lovo[v]["test"]["descriptor"]["by_registered"]
            rows.append(by[min(by, key=int)])
        unknown = " / ".join(pct(r["rejected_unknown"]) for r in rows)
        assert f"{unknown} % at {weight}" in text, weight
    for prefix in ("", "area05-"):
        rejected = [
            json.loads((RESULTS / f"{prefix}ycbv-service-depth-{v}-lovo.json").read_text())["rejected"][
                "ours"
            ]
            for v in range(3)
        ]
        right, n = sum(r["right_object_first"] for r in rejected), sum(r["n"] for r in rejected)
        assert f"{right} of {n}" in text, prefix


def test_the_query_turns_on_real_depth_are_their_json() -> None:
    text = experiments()
    runs = json.loads((RESULTS / "query-turns-depth-ycbv.json").read_text())["runs"]
    for n in ("1", "2", "3"):
        cells = " | ".join(
            f"{pct(runs[f'{n}/{v}']['right'])} / {pct(runs[f'{n}/{v}']['right_open_set_off'])}"
            for v in range(3)
        )
        assert f"| {cells} |" in text, n


def test_the_background_work_ab_is_its_json() -> None:
    text = experiments()
    runs = json.loads((RESULTS / "register-background-ab.json").read_text())["runs"]
    for name, r in runs.items():
        arm, n = name.rsplit("-", 1)
        row = (
            f"| {arm}, {n} | {r['wall_s']:.3f} s | {r['cpu_s']} | {r['render_s']:.3f} | {r['embed_s']:.3f} |"
        )
        assert row in text, row


def test_the_kinect_frame_with_the_depth_model_is_its_jsons() -> None:
    text = experiments()
    centre = json.loads((RESULTS / "kinect-depth-model-centre.json").read_text())
    n = centre["n_samples"]
    on = round(centre["methods"]["ours"]["k1"]["180"] * n)
    off = round(centre["open_set_off"]["methods"]["ours"]["k1"]["180"] * n)
    rejected = centre["rejected"]["ours"]
    assert (
        f"names {off} of the {n} instances at least half visible right with the open set off, {on} with it on"
        in text
    )
    assert (
        f"(it rejects {rejected['n']} right answers)" in text
        and rejected["right_object_first"] == rejected["n"]
    )
    whole = json.loads((RESULTS / "kinect-depth-model-detect.json").read_text())["posedesc"]["all"]
    assert whole["targets"] == n
    assert (
        f"finds {whole['true_positives']} of {n} and reports {whole['false_positives']} false detections"
        in text
    )


def test_the_colour_fit_files_ab_is_its_json() -> None:
    text = experiments()
    runs = json.loads((RESULTS / "fit-files-ab.json").read_text())["runs"]
    for name, r in runs.items():
        arm, n = name.rsplit("-", 1)
        a, b = r["colour_8"], r["colour_100"]
        row = (
            f"| {arm}, {n} | {a['p50_ms']} / {a['max_ms']} ms | {b['p50_ms']} / {b['p90_ms']} / {b['max_ms']} ms "
            f"| {r['register_median_s']} s |"
        )
        assert row in text, row
        assert a["detections"] == [6, 7, 2] and b["detections"] == [5, 5, 2]  # the same answers in every run


def test_the_colour_fit_files_at_a_start_are_their_json() -> None:
    text = experiments()
    runs = json.loads((RESULTS / "fit-files-warm.json").read_text())["runs"]
    first, then = (runs[k] for k in sorted(runs))
    assert first["objects"] == then["objects"] == 64
    assert f"{first['wall_s']} s ({first['cpu_s']} CPU-seconds)" in text
    assert f"{then['wall_s']} s ({then['cpu_s']} CPU-seconds)" in text
    one = json.loads((RESULTS / "fit-files-warm.json").read_text())["one_model"]
    made = f"made in {min(one['make_s']):.2f}-{max(one['make_s']):.2f} s, read back in {one['read_ms_median']} ms"
    assert made in text, made
