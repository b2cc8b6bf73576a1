"""Calibrate a model's detection confidence on real-depth videos and write it into its metadata.

    PYTHONPATH=. .venv/bin/python scripts/calibrate_detections.py models/posedesc-depth.onnx \
        docs/results/ycbv-detect-rgbd-0.json docs/results/ycbv-detect-rgbd-1.json \
        docs/results/ycbv-detect-rgbd-2.json --out models/posedesc-depth.onnx \
        --json docs/results/detect-confidence-depth.json

The runs are `posedesc evaluate --protocol detect` results, one per video (consecutive frames of a video are
near-duplicates: a video is the unit), each with its detections' cues (`posedesc.cues`: the verifier's
confidence, the depth fit's score, what the detection was). Of the detections from depth segments that the
model verified and fitted, a logistic fit of "the right object" on the fit's score (the share of the object's
visible surface the depth explains) gives `service.detection.report.DetectConfidence`. Each video is measured with the fit of the others (leave one
video out): AP50 of the ranking, the expected calibration error, the detections at confidence 0.5 or more
and how many of them were right, beside the verifier's confidence alone. The fit on every video is what
goes into the model's metadata (`detect_confidence`; only `metadata_props` is rewritten, the graph and
weights are left byte for byte)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.calibration import calibration_error, fit_logistic  # noqa: E402
from evaluation.detect.score import average_precision  # noqa: E402
from service.detection.report import DETECT_KEY, DetectConfidence  # noqa: E402

#: a confidence a user might ask for with `min_confidence`: how many detections reach it, how many are right
AT = 0.5


def cues(run: dict) -> list[dict]:
    """A run's ranked detections that a calibration reads: from depth (a segment or a part), fitted; the
    ignored ones (instances less than half visible) left out, as the detect protocol's AP leaves them."""
    return [
        c
        for c in run["posedesc"]["cues"]
        if c["source"] != "colour" and c["fit"] is not None and c["verifier"] is not None
        and c["outcome"] != "ignored"
    ]  # fmt: skip


def scores(rows: list[dict], key: str) -> np.ndarray:
    return np.array([c[key] for c in rows], float)


def figures(p: np.ndarray, right: np.ndarray, targets: int) -> dict:
    order = np.argsort(-p, kind="stable")
    at = p >= AT
    return {
        "ap50": round(average_precision(right[order].tolist(), targets), 4),
        "calibration_error": round(calibration_error(p, right), 4),
        f"at_{AT:g}": int(at.sum()),
        f"right_at_{AT:g}": round(float(right[at].mean()), 4) if at.any() else None,
    }


def fitted(rows: list[dict]) -> DetectConfidence:
    slope, midpoint = fit_logistic(scores(rows, "fit"), np.array([c["outcome"] == "tp" for c in rows]))
    return DetectConfidence(round(slope, 4), round(midpoint, 4))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("model", type=Path, help="the model whose metadata gets the calibration")
    ap.add_argument("runs", type=Path, nargs="+", help="detect-protocol results, one per video, with cues")
    ap.add_argument("--out", type=Path, default=None, help="model file to write (default: none)")
    ap.add_argument("--json", type=Path, default=None, help="the figures, per video left out")
    args = ap.parse_args(argv)
    runs = {}
    for path in args.runs:
        run = json.loads(path.read_text())
        if "cues" not in run.get("posedesc", {}):
            ap.error(f"{path}: no detection cues (a detect-protocol result of this code is needed)")
        runs[f"{run['scene']:04d}"] = run
    if len(runs) < 2:
        ap.error("at least two videos: each is measured with the calibration of the others")
    rows = {v: cues(run) for v, run in runs.items()}
    per_video = {}
    for v, run in runs.items():
        others = [c for u in runs if u != v for c in rows[u]]
        cal = fitted(others)
        right = np.array([c["outcome"] == "tp" for c in rows[v]])
        calibrated = np.array([cal(f) for f in scores(rows[v], "fit")])
        per_video[v] = {
            "detections": len(rows[v]),
            "fitted_on_the_others": cal.to_json(),
            "verifier": figures(scores(rows[v], "verifier"), right, run["targets"]),
            "calibrated": figures(calibrated, right, run["targets"]),
        }
        print(v, json.dumps(per_video[v]))
    shipped = fitted([c for v in runs for c in rows[v]])
    mean = {
        k: {
            f: round(float(np.mean([per_video[v][k][f] for v in runs])), 4)
            for f in ("ap50", "calibration_error")
        }
        for k in ("verifier", "calibrated")
    }
    result = {
        "model": str(args.model),
        "runs": [str(p) for p in args.runs],
        "cue": "the depth fit's score (service.detection.report.DetectConfidence)",
        "calibration": shipped.to_json(),
        "leave_one_video_out": per_video,
        "mean_left_out": mean,
        "command": " ".join(
            ["scripts/calibrate_detections.py", *(argv if argv is not None else sys.argv[1:])]
        ),
    }
    print("mean over the videos left out:", json.dumps(mean), "shipped:", json.dumps(shipped.to_json()))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    if args.out:
        from evaluation.calibration import write_metadata

        write_metadata(args.model, args.out, {DETECT_KEY: json.dumps(shipped.to_json())})
        print(f"wrote {DETECT_KEY} into {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
