"""Each rule of the real-depth detection, with and without it, on each YCB-V video: does it hold on videos it was
not chosen on? And each threshold chosen leave-one-video-out.

    scripts/rules_by_video.py --dataset ../shared/data/ycbv --out /work/runs/rules --json docs/results/rules-by-video.json

`--sweep` also runs the detection per video at each value of the thresholds in `SWEEPS`, and for each video
picks the value with the best mean F1 on the other two (ties: the shipped value), reporting its F1 on the video
left out: `lovo` in the JSON, beside the shipped value's.

Runs `posedesc evaluate --protocol detect --modality rgbd` (the README's YCB-V detection command, without the
false-alarm pass) once per video with the shipped settings and once per rule turned off: through its setting
(a `POSEDESC_*` variable of the run) or its stage's constant (`module.NAME`, set in the run's process before
the service is built: `service.detection.stand.SUNK_SHARE`, `service.detection.report.PART_FIT_FLOOR`), and
the centre-given `--protocol service --modality depth` once per video with and without the depth
re-ordering's area term (`service.pipeline.fit.EXPLAINED_WEIGHT`, a constant too). Writes per rule and video the recall, precision, AP50 and BOP AR (detection) or right object and within 20 deg (centre
given) with and without it, and whether it helps every video. Each run's JSON is kept in `--out`; a run whose
JSON is there is not made again."""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VIDEOS = (0, 1, 2)
SUNK_SHARE = "service.detection.stand.SUNK_SHARE"
PART_FIT_FLOOR = "service.detection.report.PART_FIT_FLOOR"
#: a rule of the detection: what turns it off (settings as `POSEDESC_*` variables, constants as `module.NAME`),
#: and the video it was chosen on
DETECT_RULES = {
    "support: a pose through the table is dropped (stand.SUNK_SHARE 0.01)": ({SUNK_SHARE: "1"}, "0000"),
    "depth-fit floor: 20 % of a detection's points explained (DETECT_DEPTH_FIT_FLOOR 0.2)": (
        {"POSEDESC_DETECT_DEPTH_FIT_FLOOR": "0"},
        "0000",
    ),
    "part floor: 60 % for a part of a segment (report.PART_FIT_FLOOR 0.6)": (
        {PART_FIT_FLOOR: "0"},
        "0000 (parts themselves: 0002)",
    ),
}
#: thresholds swept leave-one-video-out: name -> (the setting or constant, its shipped value, the values)
SWEEPS = {
    "detect_depth_fit_floor": ("POSEDESC_DETECT_DEPTH_FIT_FLOOR", "0.2", ("0.1", "0.2", "0.3", "0.4")),
    "detect_part_fit_floor": (PART_FIT_FLOOR, "0.6", ("0.4", "0.5", "0.6", "0.7")),
}
AREA = "area term: the depth re-ordering weighs the area a pose explains (EXPLAINED_WEIGHT 0.3)"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dataset", type=Path, default=ROOT.parent / "shared" / "data" / "ycbv")
    p.add_argument("--out", type=Path, required=True, help="folder of each run's JSON")
    p.add_argument("--json", type=Path)
    p.add_argument("--videos", default="0,1,2")
    p.add_argument(
        "--sweep", action="store_true", help="also choose each threshold of SWEEPS leave-one-video-out"
    )
    args = p.parse_args(argv)
    videos = [int(v) for v in args.videos.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    table: dict[str, dict] = {}
    for v in videos:
        shipped = _detect(args, v, "shipped", {})
        for rule, (off_by, chosen) in DETECT_RULES.items():
            off = _detect(args, v, _slug(rule), off_by)
            row = table.setdefault(rule, {"chosen_on": chosen, "videos": {}})
            row["videos"][f"{v:04d}"] = {"with": _detect_figures(shipped), "without": _detect_figures(off)}
        with_area, without_area = _service(args, v, 0.3), _service(args, v, 0.0)
        row = table.setdefault(AREA, {"chosen_on": "0000 and LM-O val", "videos": {}})
        row["videos"][f"{v:04d}"] = {"with": with_area, "without": without_area}
    for rule, row in table.items():
        runs = list(row["videos"].values())
        if rule == AREA:  # centre given: the right object and the right pose
            row["gain_right"] = [round(r["with"]["right"] - r["without"]["right"], 4) for r in runs]
            row["gain_within_20"] = [
                round(r["with"]["within_20"] - r["without"]["within_20"], 4) for r in runs
            ]
            row["helps_every_video"] = all(g >= 0 for g in row["gain_right"] + row["gain_within_20"])
        else:  # a floor trades recall for precision: judged by F1, both reported
            for key in ("recall", "precision"):
                row["gain_" + key] = [round(r["with"][key] - r["without"][key], 4) for r in runs]
            row["gain_f1"] = [round(_f1(r["with"]) - _f1(r["without"]), 4) for r in runs]
            row["helps_every_video"] = all(g >= 0 for g in row["gain_f1"])
        gains = {k: v for k, v in row.items() if k.startswith("gain_")}
        print(f"{rule}: {gains} helps every video: {row['helps_every_video']}")
    lovo = _lovo(args, videos) if args.sweep else {}
    result = {
        "dataset": str(args.dataset),
        "rules": table,
        "lovo": lovo,
        "note": "with: the shipped settings; without: the rule off. Detection: posedesc evaluate --protocol detect "
        "--modality rgbd (RGB-D of shape-only meshes: the depth model answers), recall and precision of the "
        "instances at least half visible, a rule helping a video when its F1 does not fall; recall_add_s: BOP's "
        "ADD(-S) < 0.1 d recall of the run's estimates; centre given: --protocol service --modality depth, "
        "k = 1, open set on",
        "command": shlex.join(["scripts/rules_by_video.py", *(argv if argv is not None else sys.argv[1:])]),
    }
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


def _f1(figures: dict) -> float:
    p, r = figures["precision"], figures["recall"]
    return 2 * p * r / (p + r) if p + r else 0.0


def _lovo(args: argparse.Namespace, videos: list[int]) -> dict:
    """Per threshold of `SWEEPS`: each video's figures at each value, and for each video the value the other
    videos choose (best mean F1; ties: the shipped value) with its F1 on the video left out."""
    out: dict[str, dict] = {}
    for name, (setting, shipped, values) in SWEEPS.items():
        runs = {  # the shipped value's run is the shipped settings' run
            (v, x): _detect_figures(
                _detect(args, v, "shipped", {})
                if x == shipped
                else _detect(args, v, f"{name}-{x}", {setting: x})
            )
            for v in videos
            for x in values
        }
        chosen = {}
        for left in videos:
            others = [v for v in videos if v != left]

            score = {x: sum(_f1(runs[(v, x)]) for v in others) / len(others) for x in values}
            best = max(values, key=lambda x: (round(score[x], 6), x == shipped))
            chosen[f"{left:04d}"] = {
                "chosen": best,
                "f1_others": round(score[best], 4),
                "f1_left_out": round(_f1(runs[(left, best)]), 4),
                "f1_left_out_shipped": round(_f1(runs[(left, shipped)]), 4),
                "figures_left_out": runs[(left, best)],
            }
        out[name] = {
            "shipped": shipped,
            "values": list(values),
            "f1": {f"{v:04d}": {x: round(_f1(runs[(v, x)]), 4) for x in values} for v in videos},
            "leave_one_video_out": chosen,
            "mean_f1_left_out": round(sum(c["f1_left_out"] for c in chosen.values()) / len(chosen), 4),
            "mean_f1_left_out_shipped": round(
                sum(c["f1_left_out_shipped"] for c in chosen.values()) / len(chosen), 4
            ),
        }
        print(name, {k: c["chosen"] for k, c in chosen.items()}, out[name]["mean_f1_left_out"])
    return out


def _slug(rule: str) -> str:
    return rule.split(":")[0].replace(" ", "-")


def _posedesc(constants: dict[str, float]) -> list[str]:
    """The `posedesc` command, run by this Python in a process whose stages' constants (`module.NAME`) are set
    first: the service reads them when it builds its stages."""
    sets = "".join(
        f"importlib.import_module({module!r}).{name} = {value!r}; "
        for module, name, value in ((*k.rsplit(".", 1), v) for k, v in constants.items())
    )
    code = f"import importlib, sys; {sets}from posedesc.cli import main; sys.exit(main(sys.argv[1:]))"
    return [sys.executable, "-c", code]


def _detect(args: argparse.Namespace, video: int, name: str, off_by: dict[str, str]) -> dict:
    """The detection run of a video with `off_by` (settings as `POSEDESC_*` variables, constants as
    `module.NAME`), read from `--out` when it was made before."""
    out = args.out / f"detect-{name}-{video}.json"
    if not out.is_file():
        env = {k: v for k, v in off_by.items() if k.startswith("POSEDESC_")}
        constants = {k: float(v) for k, v in off_by.items() if k not in env}
        cmd = [*_posedesc(constants), "evaluate", "--dataset", str(args.dataset)]
        cmd += [
            "--scene",
            str(video),
            "--modality",
            "rgbd",
            "--model",
            str(ROOT / "models" / "posedesc-rgbd.onnx"),
        ]
        cmd += ["--protocol", "detect", "--json", str(out)]
        print(shlex.join(cmd), env, flush=True)
        subprocess.run(cmd, check=True, cwd=ROOT, env={**os.environ, **env}, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


def _detect_figures(run: dict) -> dict:
    a = run["posedesc"]["all"]
    bop = run.get("bop", {})
    return {
        "recall": round(a["recall"], 4),
        "precision": round(a["precision"], 4),
        "ap50": round(a["ap50"], 4),
        "bop_ar": bop.get("ar"),
        "recall_add_s": bop.get("recall_add_s"),
    }


def _service(args: argparse.Namespace, video: int, weight: float) -> dict:
    out = args.out / f"service-depth-area{weight:g}-{video}.json"
    if not out.is_file():
        cmd = [*_posedesc({"service.pipeline.fit.EXPLAINED_WEIGHT": weight}), "evaluate"]
        cmd += ["--dataset", str(args.dataset), "--scene", str(video)]
        cmd += ["--modality", "depth", "--model", str(ROOT / "models" / "posedesc-depth.onnx")]
        cmd += ["--protocol", "service", "--json", str(out)]
        print(shlex.join(cmd), flush=True)
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    run = json.loads(out.read_text())
    return _service_figures(run)


def _service_figures(run: dict) -> dict:
    k1 = run["methods"]["ours"]["k1"]  # within 180 deg: the right object
    return {
        "right": round(k1["180"], 4),
        "within_20": round(k1["20"], 4),
        "bop_ar": run["bop"]["ar"],
        "recall_add_s": run["bop"]["recall_add_s"],
    }


if __name__ == "__main__":
    sys.exit(main())
