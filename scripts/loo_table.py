"""Leave-one-out table: for each run that left one object out of training, that object's accuracy on every
frame it appears in (scored with `posedesc evaluate --unseen ID`), beside the other objects', with 95 %
Wilson intervals (an object has ~25-70 instances: a few points either way are noise). With several runs,
a last row pools them: every left-out object's instances together, and every run's other objects'.

    .venv/bin/python scripts/loo_table.py ID=EVAL.json [ID=EVAL.json ...] --json docs/results/loo.json
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def wilson(p: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion p of n."""
    if n == 0:
        return 0.0, 1.0
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def row(group: dict, method: str = "ours") -> dict:
    n = int(group["n_samples"])
    k1 = group[method]["k1"]
    out: dict = {"n": n}
    for key, name in (("20", "within_20"), ("180", "recognised")):
        p = float(k1[key])
        lo, hi = wilson(p, n)
        out[name] = {"value": p, "ci95": [round(lo, 3), round(hi, 3)]}
    return out


def pooled(rows: list[dict]) -> dict:
    """Rows of several runs (`row`) as one: their instances together, each figure the share of all of
    them, with its Wilson interval (the runs' objects and models differ; their instances are counted once)."""
    n = sum(r["n"] for r in rows)
    out: dict = {"n": n}
    for name in ("within_20", "recognised"):
        p = sum(r[name]["value"] * r["n"] for r in rows) / max(n, 1)
        lo, hi = wilson(p, n)
        out[name] = {"value": p, "ci95": [round(lo, 3), round(hi, 3)]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="ID=EVAL.json: the object left out and its evaluation")
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args()
    table = []
    for spec in args.runs:
        oid, path = spec.split("=", 1)
        ev = json.loads(Path(path).read_text())
        table.append(
            {
                "left_out": int(oid),
                "evaluation": path,
                "model": ev["model"],
                "frames": len(ev["frames"]),
                "unseen": row(ev["unseen_objects"]),
                "seen": row(ev["seen_objects"]),
            }
        )
    if len(table) > 1:
        table.append(
            {
                "left_out": "pooled",
                "unseen": pooled([t["unseen"] for t in table]),
                "seen": pooled([t["seen"] for t in table]),
            }
        )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(table, indent=2))
    print(
        "| left out | n | never trained on: 3-D < 20° | recognised | the other objects (n): 3-D < 20° | recognised |"
    )
    print("|---|---|---|---|---|---|")
    for t in table:
        u, s = t["unseen"], t["seen"]

        def cell(r: dict) -> str:
            lo, hi = r["ci95"]
            return f"{100 * r['value']:.0f} % ({100 * lo:.0f}–{100 * hi:.0f})"

        print(
            f"| {t['left_out']} | {u['n']} | {cell(u['within_20'])} | {cell(u['recognised'])} | "
            f"({s['n']}) {cell(s['within_20'])} | {cell(s['recognised'])} |"
        )


if __name__ == "__main__":
    main()
