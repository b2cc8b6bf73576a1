"""How the answers of a probe depend on how much of the object the frame shows.

    PYTHONPATH=. .venv/bin/python scripts/by_visibility.py --dataset ../shared/data/lmo \
        docs/results/probe-val-rolls5-rerank400.json [OTHER.json ...] [--json OUT.json]

Reads the `queries` of `scripts/probe_recognise.py` files (frame, object, roll, 3-D error, viewing
direction error, right object) and the dataset's `scene_gt_info.json` (`visib_fract`: the share of the
object's silhouette not hidden by others), and prints, per file and per band of that share, the queries
within 20 deg (3-D and viewing direction) and recognised at k = 1; for a probe run with `--k N`, also
the queries with any of their N answers within 20 deg (its `reach`). A frame sent at several rolls counts
once a roll, as in the probe's own figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from index.data.bop import BopDataset  # noqa: E402

#: bands of the visible share: [low, high)
BANDS = ((0.0, 0.5), (0.5, 0.8), (0.8, 0.95), (0.95, 1.01))


def visibility(dataset: Path, scene: int) -> dict[tuple[int, int], float]:
    """(frame, object) -> visible share. A frame showing an object twice keeps the smaller share."""
    out: dict[tuple[int, int], float] = {}
    for inst in BopDataset(dataset).instances(scene):
        key = (inst.frame_id, inst.obj_id)
        out[key] = min(out.get(key, 1.0), inst.visib_fract)
    return out


def by_band(
    queries: list[list], visible: dict[tuple[int, int], float], reach: list[list] | None = None
) -> list[dict]:
    """Per band with queries: its n and the percentages within 20 deg (3-D, view) and recognised; with the
    probe's `reach` (per query: any of its k answers within 20 deg, 3-D and view), those too."""
    try:
        rows = np.array(
            [[visible[(int(q[0]), int(q[1]))], q[3] < 20, q[4] < 20, q[5]] for q in queries], float
        )
    except KeyError as e:
        raise ValueError(f"no instance {e.args[0]} (frame, object) in the dataset's scene") from None
    out = []
    for lo, hi in BANDS:
        m = (rows[:, 0] >= lo) & (rows[:, 0] < hi) if len(rows) else np.zeros(0, bool)
        if not m.any():
            continue
        pct = [round(100 * float(rows[m, c].mean()), 1) for c in (1, 2, 3)]
        among = {}
        if reach is not None:
            r = np.asarray(reach, float)[m]
            among = {"within_20_among_k": round(100 * float(r[:, 0].mean()), 1),
                     "view_within_20_among_k": round(100 * float(r[:, 1].mean()), 1)}  # fmt: skip
        out.append(
            {
                "visible": [lo, min(hi, 1.0)],
                "n": int(m.sum()),
                "within_20": pct[0],
                "view_within_20": pct[1],
                "right_object": pct[2],
                **among,
            }
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", type=Path, nargs="+", help="JSON files of scripts/probe_recognise.py")
    p.add_argument("--dataset", type=Path, required=True, help="the BOP dataset the probes ran on")
    p.add_argument("--scene", type=int, default=2)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    try:
        visible = visibility(args.dataset, args.scene)
        result = {}
        for f in args.files:
            probe = json.loads(f.read_text())
            queries, reach = probe.get("queries"), probe.get("reach")
            if not queries:
                raise ValueError(f"{f} has no queries: not a file of scripts/probe_recognise.py")
            if reach is not None and len(reach) != len(queries):
                raise ValueError(f"{f}: {len(reach)} reach rows for {len(queries)} queries")
            result[f.name] = by_band(queries, visible, reach)
    except (OSError, ValueError) as e:
        print(f"by_visibility: {e}", file=sys.stderr)
        return 2
    for name, bands in result.items():
        print(name)
        for b in bands:
            lo, hi = b["visible"]
            print(
                f"  visible {lo:.2f}-{hi:.2f}  n {b['n']:4d}  within 20: {b['within_20']:5.1f}  "
                f"view: {b['view_within_20']:5.1f}  object: {b['right_object']:5.1f}"
                + (
                    f"  among k: within 20 {b['within_20_among_k']:5.1f}  view {b['view_within_20_among_k']:5.1f}"
                    if "within_20_among_k" in b
                    else ""
                )
            )
    if args.json:
        command = "scripts/by_visibility.py " + " ".join(sys.argv[1:] if argv is None else argv)
        args.json.write_text(json.dumps({"command": command, "by_visibility": result}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
