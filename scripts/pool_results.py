"""Pools `posedesc evaluate` results of several scenes (one run per video, as YCB-V's frames must be split)
into one JSON, as if one run had sent every frame.

- the service protocol: each share weighted by its run's queries (BOP's by its targets), counts summed, the
  translation errors of the right objects pooled. A float is a share, an integer a count;
- the detect protocol: the counts summed and recall, precision and found within 20° made again from them (per
  object too), BOP's shares weighted by targets. What needs the runs' rankings or frames (AP50, the median
  distance error, frame times) is not pooled: it is listed under `not_pooled`.

    PYTHONPATH=. .venv/bin/python scripts/pool_results.py docs/results/ycbv-service-depth-{0,1,2}-sym.json \
        --json docs/results/ycbv-service-depth.json
    PYTHONPATH=. .venv/bin/python scripts/pool_results.py docs/results/ycbv-detect-rgbd-{0,1,2}.json \
        --json docs/results/ycbv-detect-rgbd.json
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

SHARES = ("methods", "view_direction", "open_set_off", "rejected")  # shares of each run's queries
BOP_SHARES = (
    "ar",
    "ar_mssd",
    "ar_mspd",
    "ar_vsd",
    "recall_add_s",
    "recall_5deg_5cm",
)  # shares of its targets


def pooled_bop(runs: list[dict]) -> dict[str, Any]:
    """BOP's shares of the runs weighted by their targets; AR_VSD only where every run measured it (frames
    with recorded depth), else None, as a run without it says."""
    targets = [r["bop"]["n_targets"] for r in runs]
    out: dict[str, Any] = {}
    for k in BOP_SHARES:
        values = [r["bop"].get(k) for r in runs]
        out[k] = None if None in values else float(np.average(values, weights=targets))
    return out | {"n_targets": sum(targets), "n_estimated": sum(r["bop"]["n_estimated"] for r in runs)}


def pooled_share(parts: list[Any], weights: list[float]) -> Any:
    """The weighted mean of the floats at the same place in every part, the sum of the integers (dicts
    walked key by key; a key missing from a part, or a value that is not a number, is left out)."""
    if all(isinstance(p, dict) for p in parts):
        keys = [k for k in parts[0] if all(k in p for p in parts)]
        out = {}
        for k in keys:
            value = pooled_share([p[k] for p in parts], weights)
            if value is not None:
                out[k] = value
        return out
    if all(isinstance(p, int) and not isinstance(p, bool) for p in parts):
        return sum(parts)  # a count
    if all(isinstance(p, (int, float)) and not isinstance(p, bool) for p in parts):
        return float(np.average(parts, weights=weights))
    return None


def pool(runs: list[dict]) -> dict:
    """One result of several runs of the service protocol (see the module's docstring)."""
    n = [r["n_samples"] for r in runs]
    out: dict[str, Any] = {
        "n_samples": sum(n),
        "modality": runs[0]["modality"],
        "dataset": runs[0]["dataset"],
        "scenes": [r["scene"] for r in runs],
        "test_data": runs[0]["test_data"],
    }
    for key in SHARES:
        out[key] = pooled_share([r[key] for r in runs], n)
    bop = pooled_bop(runs)
    te = [i["te"] for r in runs for i in r["bop"]["per_instance"] if i.get("te") is not None]
    bop |= {
        "te_mm_right_object": {
            "n": len(te),
            "median": float(np.median(te)) if te else None,
            "p90": float(np.percentile(te, 90)) if te else None,
        },
    }
    out["bop"] = bop
    return out


COUNTS = ("targets", "hits", "true_positives", "false_positives", "duplicates", "ignored")


def detections(blocks: list[dict]) -> dict:
    """One detect protocol's figures block (`evaluation.detect.score.scores`) of several: counts summed, the
    shares made again from them."""
    out = {k: sum(b[k] for b in blocks) for k in COUNTS}
    tp, fp, targets = out["true_positives"], out["false_positives"], out["targets"]
    within = sum((b["rotation_within_20"] or 0.0) * b["targets"] for b in blocks)  # None: no target
    return out | {
        "recall": tp / targets if targets else 0.0,
        "precision": tp / (tp + fp) if tp + fp else 0.0,
        "rotation_within_20": within / targets if targets else 0.0,
    }


def pool_detect(runs: list[dict]) -> dict:
    """One result of several runs of the detect protocol (see the module's docstring)."""
    frames = [len(r["frames"]) for r in runs]
    objects = sorted({o for r in runs for o in r["posedesc"]["per_object"]}, key=int)
    return {
        "protocol": "detect",
        "modality": runs[0]["modality"],
        "dataset": runs[0]["dataset"],
        "scenes": [r["scene"] for r in runs],
        "frames": sum(frames),
        "posedesc": {
            "all": detections([r["posedesc"]["all"] for r in runs]),
            "per_object": {
                o: detections(
                    [r["posedesc"]["per_object"][o] for r in runs if o in r["posedesc"]["per_object"]]
                )
                for o in objects
            },
            "detections_per_frame": float(
                np.average([r["posedesc"]["detections_per_frame"] for r in runs], weights=frames)
            ),
        },
        "bop": pooled_bop(runs),
        **({"false_alarms": pooled_false_alarms(runs)} if all("false_alarms" in r for r in runs) else {}),
        "not_pooled": "AP50, the median distance error and the frame times: each run's own, in its JSON",
    }


def pooled_false_alarms(runs: list[dict]) -> dict:
    """The runs' false detections with none of their objects registered (`--false-alarms`): per frame,
    weighted by the runs' frames; the frames with any summed; the most in a frame."""
    blocks = [r["false_alarms"]["posedesc"] for r in runs]
    frames = [r["false_alarms"]["frames"] for r in runs]
    return {
        "objects": runs[0]["false_alarms"]["objects"],
        "frames": sum(frames),
        "posedesc": {
            "detections_per_frame": float(
                np.average([b["detections_per_frame"] for b in blocks], weights=frames)
            ),
            "frames_with_any": sum(b["frames_with_any"] for b in blocks),
            "most_in_a_frame": max(b["most_in_a_frame"] for b in blocks),
        },
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", type=Path, nargs="+", help="results JSONs of the service or the detect protocol")
    p.add_argument("--json", type=Path, required=True)
    args = p.parse_args(argv)
    runs = []
    for path in args.runs:
        if not path.is_file():
            p.error(f"{path} does not exist")
        run = json.loads(path.read_text())
        service = run.get("protocol") == "service" and "n_samples" in run
        if not service and not (run.get("protocol") == "detect" and "posedesc" in run):
            p.error(f"{path}: not a service- or detect-protocol result of posedesc evaluate")
        runs.append(run)
    if len({(r["protocol"], r["modality"], r["dataset"]) for r in runs}) > 1:
        p.error("the runs pooled must be of one protocol and one model's modality on one dataset")
    pooled = pool(runs) if runs[0]["protocol"] == "service" else pool_detect(runs)
    out = pooled | {
        "sources": [str(x) for x in args.runs],
        "command": shlex.join(["PYTHONPATH=.", ".venv/bin/python", "scripts/pool_results.py", *sys.argv[1:]]),
    }
    args.json.write_text(json.dumps(out, indent=1) + "\n")
    size = f"{out['n_samples']} queries" if "n_samples" in out else f"{out['frames']} frames"
    print(f"{args.json}: {size} of {len(runs)} runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
