"""scripts/rules_by_video.py: each rule with and without it per video, judged by F1, and a threshold chosen
leave-one-video-out, from the runs' JSONs (made here as `posedesc evaluate` writes them: the evaluations
themselves are the detect and service protocols' own tests)."""

from __future__ import annotations

import json
from pathlib import Path


def detect_run(recall: float, precision: float) -> dict:
    return {
        "posedesc": {"all": {"recall": recall, "precision": precision, "ap50": 0.5}},
        "bop": {"ar": 0.4, "recall_add_s": recall},
    }


def service_run(right: float) -> dict:
    return {
        "methods": {"ours": {"k1": {"180": right, "20": right / 2}}},
        "bop": {"ar": 0.5, "recall_add_s": 0.4},
    }


def write(folder: Path, name: str, run: dict) -> None:
    (folder / name).write_text(json.dumps(run))


def test_a_rule_is_judged_per_video_and_a_threshold_chosen_on_the_others(tmp_path, script) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    for v, (shipped, off) in enumerate(
        [((0.6, 0.9), (0.9, 0.5)), ((0.7, 0.7), (0.7, 0.6)), ((0.4, 0.7), (0.5, 0.6))]
    ):
        write(runs, f"detect-shipped-{v}.json", detect_run(*shipped))
        for slug in ("support", "depth-fit-floor", "part-floor"):
            write(runs, f"detect-{slug}-{v}.json", detect_run(*off))
        write(runs, f"service-depth-area0.3-{v}.json", service_run(0.8))
        write(runs, f"service-depth-area0-{v}.json", service_run(0.7 if v == 2 else 0.8))
        # the sweeps: the depth-fit floor best at 0.1 on videos 0 and 2, at 0.4 on video 1
        for x, f in {"0.1": 0.9, "0.3": 0.5, "0.4": 0.95 if v == 1 else 0.3}.items():
            write(runs, f"detect-detect_depth_fit_floor-{x}-{v}.json", detect_run(f, f))
        for x in ("0.4", "0.5", "0.7"):
            write(runs, f"detect-detect_part_fit_floor-{x}-{v}.json", detect_run(0.1, 0.1))
    out = tmp_path / "rules.json"
    assert script("rules_by_video").main(["--out", str(runs), "--json", str(out), "--sweep"]) == 0
    result = json.loads(out.read_text())
    support = next(r for k, r in result["rules"].items() if k.startswith("support"))
    # F1 with / without per video: 0.72 / 0.64, 0.70 / 0.65, 0.51 / 0.55
    assert [round(g, 2) for g in support["gain_f1"]] == [0.08, 0.05, -0.04]
    assert support["helps_every_video"] is False and support["gain_recall"] == [-0.3, 0.0, -0.1]
    area = next(r for k, r in result["rules"].items() if k.startswith("area"))
    assert area["gain_right"] == [0.0, 0.0, 0.1] and area["helps_every_video"] is True
    floor = result["lovo"]["detect_depth_fit_floor"]
    chosen = {v: c["chosen"] for v, c in floor["leave_one_video_out"].items()}
    assert chosen == {"0000": "0.1", "0001": "0.1", "0002": "0.1"}  # 0.1 is best on two videos of every pair
    assert floor["leave_one_video_out"]["0001"]["f1_left_out"] == 0.9  # video 1 alone preferred 0.4
    part = result["lovo"]["detect_part_fit_floor"]
    assert {c["chosen"] for c in part["leave_one_video_out"].values()} == {"0.6"}  # the shipped value wins
