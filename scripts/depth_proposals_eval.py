"""How well `service.detection.depth_segments` finds the annotated objects of depth frames.

On the real Kinect frame (../shared/data/lmo-depth) and on synthetic depth made from LM-O colour frames'
ground truth (every annotated object at its pose standing on the table through the bottoms of their
bounding boxes, `evaluation.masks.rendered_depth`, through the Kinect-like sensor model). An instance
with visib_fract >= 0.5 is found when a proposal's centre lies within a quarter of its whole box's larger
side (bbox_obj) of where its origin projects and the proposal's box overlaps its visible box (bbox_visib)
with IoU >= 0.5. Also reported: the proposals per frame, the rank of each instance's first hit, the
distance error of the hits, and the time per frame (median of repeats, one core).

OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python scripts/depth_proposals_eval.py --repeats 30 \
    --json docs/results/depth_proposals.json --png /tmp/depth_proposals.png
OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python scripts/depth_proposals_eval.py --repeats 30 \
    --sizes 40 400 --json docs/results/depth_proposals-40-400.json    # LineMOD's objects' range

The centre estimate, measured on the instances' true visible pixels (their rendered masks, support plane
removed) so that segmentation plays no part; median 3-D error of the estimated centre, mm (real frame: 6
instances; 12 synthetic frames: 68):

| estimate                                                              | real | synthetic |
|-----------------------------------------------------------------------|------|-----------|
| nearest surface point, no push                                        | 68.9 | 55.6      |
| centroid + half the visible depth extent along the ray                | 33.3 | 20.6      |
| nearest + half the smaller lateral extent (x/y; PCA: 32.8 / 17.6)     | 31.9 | 17.6      |
| nearest + half the mean of the two PCA lateral extents                | 24.9 | 14.3      |
| nearest + half the larger lateral extent                              | 23.3 | 13.6      |
| the same, no lower than half the height above the support (shipped)   | 18.1 | 10.7      |
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from evaluation.masks import rendered_depth
from index.data.bop import BopDataset, Instance
from index.templates.render import Renderer
from service.detection.depth_segments import Proposal, depth_proposals

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
MIN_VISIB = 0.5
CENTRE_SHARE = 0.25  # of the whole box's larger side
MIN_IOU = 0.5
LIMIT = 30
SIZES: dict = {}


def iou(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    w, h = min(a[2], b[2]) - max(a[0], b[0]), min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    return w * h / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h)


def whole_boxes(scene_dir: Path) -> dict[tuple[int, int], tuple[int, int, int, int]]:
    info = json.loads((scene_dir / "scene_gt_info.json").read_text())
    return {(int(f), i): tuple(a["bbox_obj"]) for f, anns in info.items() for i, a in enumerate(anns)}


def score_frame(
    insts: list[Instance], props: list[Proposal], boxes: dict[tuple[int, int], tuple[int, int, int, int]]
) -> list[dict]:
    rows = []
    for inst in insts:
        if inst.visib_fract < MIN_VISIB or inst.bbox_visib is None:
            continue
        x, y, w, h = inst.bbox_visib
        visib = (x, y, x + w, y + h)
        bw, bh = boxes[(inst.frame_id, inst.index)][2:]
        u, v = inst.centre_uv
        hits = [
            k
            for k, p in enumerate(props)
            if np.hypot(p.u - u, p.v - v) <= CENTRE_SHARE * max(bw, bh) and iou(p.box, visib) >= MIN_IOU
        ]
        row: dict = {"frame": inst.frame_id, "obj_id": inst.obj_id, "visib": round(inst.visib_fract, 3)}
        row["rank"] = hits[0] if hits else None
        overlaps = [iou(p.box, visib) for p in props]
        if overlaps and max(overlaps) >= MIN_IOU:  # how well the best-fitting segment places the centre
            p = props[int(np.argmax(overlaps))]
            c = np.linalg.solve(inst.K, [p.u, p.v, 1.0])
            row["centre_3d_err_mm"] = round(
                float(np.linalg.norm(c / np.linalg.norm(c) * p.distance_mm - inst.t)), 1
            )
        if hits:
            p = props[hits[0]]
            row["centre_px"] = round(float(np.hypot(p.u - u, p.v - v)), 1)
            row["distance_err_mm"] = round(p.distance_mm - float(np.linalg.norm(inst.t)), 1)
        rows.append(row)
    return rows


def timed(depth: np.ndarray, K: np.ndarray, repeats: int, limit: int) -> tuple[list[Proposal], float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        props = depth_proposals(depth, K, limit=limit, **SIZES)
        times.append(time.perf_counter() - t0)
    return props, 1000 * float(np.median(times))


def summary(rows: list[dict], counts: list[int], ms: list[float]) -> dict:
    found = [r for r in rows if r["rank"] is not None]
    return {
        "instances": len(rows),
        "found": len(found),
        "proposals_per_frame": round(float(np.mean(counts)), 1),
        "median_rank": float(np.median([r["rank"] for r in found])) if found else None,
        "median_centre_px": float(np.median([r["centre_px"] for r in found])) if found else None,
        "median_abs_distance_err_mm": (
            float(np.median([abs(r["distance_err_mm"]) for r in found])) if found else None
        ),
        "median_ms": round(float(np.median(ms)), 1),
        "median_centre_3d_err_mm": float(
            np.median([r["centre_3d_err_mm"] for r in rows if "centre_3d_err_mm" in r])
        ),
    }


def draw(depth: np.ndarray, insts: list[Instance], props: list[Proposal], path: str) -> None:
    valid = depth > 0
    grey = np.zeros(depth.shape, np.uint8)
    if valid.any():
        lo, hi = np.percentile(depth[valid], [1, 99])
        grey[valid] = np.clip(255 - (depth[valid] - lo) / max(hi - lo, 1) * 200, 40, 255).astype(np.uint8)
    img = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    for p in props:
        x0, y0, x1, y1 = (int(c) for c in p.box)
        cv2.rectangle(img, (x0, y0), (x1, y1), (0, 200, 255), 1)
        cv2.circle(img, (int(p.u), int(p.v)), 3, (0, 200, 255), -1)
    for inst in insts:
        u, v = inst.centre_uv
        cv2.drawMarker(img, (int(u), int(v)), (0, 255, 0), cv2.MARKER_CROSS, 12, 2)
    cv2.imwrite(path, img)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", default=str(SHARED / "lmo-depth"))
    ap.add_argument("--lmo", default=str(SHARED / "lmo"))
    ap.add_argument("--frames", type=int, default=12, help="synthetic frames, spread over scene 2")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--json")
    ap.add_argument("--limit", type=int, default=LIMIT)
    ap.add_argument("--sizes", type=float, nargs=2, metavar=("MIN_MM", "MAX_MM"), help="the size range asked")
    ap.add_argument("--png", help="the real frame's proposals drawn (synthetic: *_synth.png)")
    args = ap.parse_args()
    if args.sizes:
        SIZES.update(min_size_mm=args.sizes[0], max_size_mm=args.sizes[1])

    real = BopDataset(args.real)
    insts = list(real.instances(2))
    depth = insts[0].load_depth()
    assert depth is not None
    props, ms = timed(depth, insts[0].K, args.repeats, args.limit)
    real_rows = score_frame(insts, props, whole_boxes(real.root / "test" / "000002"))
    if args.png:
        draw(depth, insts, props, args.png)

    lmo = BopDataset(args.lmo)
    everything = list(lmo.instances(2))
    frames = sorted({i.frame_id for i in everything})
    chosen = [frames[int(k)] for k in np.linspace(0, len(frames) - 1, args.frames)]
    boxes = whole_boxes(lmo.root / "test" / "000002")
    meshes = {o: lmo.mesh(o, max_faces=20_000) for o in {i.obj_id for i in everything}}
    synth_rows, counts, times = [], [], []
    renderer = Renderer()
    try:
        for n, f in enumerate(chosen):
            group = [i for i in everything if i.frame_id == f]
            d = rendered_depth(renderer, group, meshes, 640, 480, np.random.default_rng(f))
            p, t = timed(d, group[0].K, 3, args.limit)
            synth_rows += score_frame(group, p, boxes)
            counts.append(len(p))
            times.append(t)
            if args.png and n == 0:
                draw(d, group, p, args.png.replace(".png", "_synth.png"))
    finally:
        renderer.close()

    out = {
        "real": {**summary(real_rows, [len(props)], [ms]), "instances_detail": real_rows},
        "synthetic": {**summary(synth_rows, counts, times), "frames": chosen},
        "synthetic_missed": [r for r in synth_rows if r["rank"] is None],
    }
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")


if __name__ == "__main__":
    main()
