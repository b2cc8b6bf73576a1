"""A probe of registration-conditioned colour proposals (issue 36, item 1; not used by the service): where a
frame looks like a registered object, with no training for that object.

Each object is rendered from the level-1 viewpoints at 4 rolls (its 200 mm window over `RENDER_PX` px, on a
flat random grey); the frozen ImageNet stride-16 map of the objectness network (`models/posedesc-objectness.onnx`,
the 64 channels its head reads) gives the cells the object covers (>= 75 %), unit length: the object's bag
of cells. A frame is run at windows of 64 px to 362 px (half-octaves, each level scaled so that the window
spans `RENDER_PX`); each cell's similarity to an object is the mean of its 5 best cosines in the object's
bag, blurred over the object's interior (0.35 of its diameter) less `surround` times the ring around it;
the peaks of every level, suppressed within a quarter window, are the object's proposals (centre, window).
Recall: each instance (visible >= 0.5) found among its own object's best 10, at each tolerance.

    PYTHONPATH=. .venv/bin/python scripts/probe_appearance.py --split val --json docs/results/appearance-probe-val.json
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402

RENDER_PX = 128  # the 200 mm window's side in a render and in each frame level
STRIDE = 16
WINDOWS = tuple(64 * 2 ** (k / 2) for k in range(6))  # 64 .. 362 px
TOLERANCES = {"w/8, any scale": (1 / 8, None), "w/4, any scale": (1 / 4, None), "w/4, 30 %": (1 / 4, 0.3),
              "w/2, any scale": (1 / 2, None)}  # fmt: skip


def stride16(objectness: Path, threads: int = 2) -> ort.InferenceSession:
    """The objectness network cut at its stride-16 map: the input of the resize its head upsamples."""
    model = onnx.load(str(objectness))
    resize = next(n for n in model.graph.node if n.op_type == "Resize")
    sub = onnx.utils.Extractor(model).extract_model([model.graph.input[0].name], [resize.input[0]])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
    return ort.InferenceSession(sub.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def cells(session: ort.InferenceSession, img: np.ndarray) -> np.ndarray:
    """Unit stride-16 cells of an RGB image. Shape: (H, W, 3) uint8 -> (64, ceil(H / 16), ceil(W / 16))."""
    h, w = img.shape[:2]
    x = np.zeros((1, 3, -(-h // STRIDE) * STRIDE, -(-w // STRIDE) * STRIDE), np.float32)
    x[0, :, :h, :w] = img.transpose(2, 0, 1)
    f = session.run(None, {session.get_inputs()[0].name: x})[0][0]
    return f / (np.linalg.norm(f, axis=0, keepdims=True) + 1e-6)


def bag(session: ort.InferenceSession, rgb: np.ndarray, depth: np.ndarray, seed: int = 0) -> np.ndarray:
    """The cells renders of an object cover (>= 75 %). Shape: (N, S, S, 3), (N, S, S) -> (M, 64)."""
    rng = np.random.default_rng(seed)
    out = []
    for c, d in zip(rgb, depth, strict=True):
        img = np.where((d > 0)[..., None], c, rng.integers(60, 200, 3).astype(np.uint8)).astype(np.uint8)
        s = d.shape[0] // STRIDE
        cover = (d > 0).reshape(s, STRIDE, s, STRIDE).mean(axis=(1, 3))
        out.append(cells(session, img)[:, cover >= 0.75].T)
    return np.concatenate(out).astype(np.float32)


def proposals(
    session: ort.InferenceSession,
    rgb: np.ndarray,
    bags: dict[int, tuple[np.ndarray, float]],
    surround: float,
    limit: int = 10,
) -> dict[int, list[tuple[float, float, float, float]]]:
    """Each object's best `limit` places in the frame: (score, u, v, window px), best first."""
    found: dict[int, list[tuple[float, float, float, float]]] = {o: [] for o in bags}
    for wpx in WINDOWS:
        s = RENDER_PX / wpx
        lw, lh = round(rgb.shape[1] * s), round(rgb.shape[0] * s)
        if min(lw, lh) < 2 * STRIDE:
            continue
        img = cv2.resize(rgb, (lw, lh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        f = cells(session, img)
        flat = f.reshape(len(f), -1).T
        sx, sy = lw / rgb.shape[1], lh / rgb.shape[0]
        for oid, (b, diameter) in bags.items():
            sim = flat @ b.T
            best = np.sort(sim, axis=1)[:, -5:].mean(axis=1).reshape(f.shape[1:]).astype(np.float32)
            r = max(1, round(0.35 * diameter / 200 * RENDER_PX / STRIDE))
            inner = cv2.blur(best, (2 * r + 1,) * 2, borderType=cv2.BORDER_REPLICATE)
            big = 2 * r + 1
            outer = cv2.blur(best, (2 * big + 1,) * 2, borderType=cv2.BORDER_REPLICATE)
            a, area = (2 * r + 1) ** 2, (2 * big + 1) ** 2
            score = inner - surround * (outer * area - inner * a) / (area - a)
            peak = score >= cv2.dilate(score, np.ones((3, 3), np.uint8))
            for i, j in zip(*np.nonzero(peak), strict=True):
                u = (STRIDE * j + (STRIDE - 1) / 2 + 0.5) / sx - 0.5
                v = (STRIDE * i + (STRIDE - 1) / 2 + 0.5) / sy - 0.5
                found[oid].append((float(score[i, j]), float(u), float(v), wpx))
    out = {}
    for oid, ps in found.items():
        kept: list[tuple[float, float, float, float]] = []
        for p in sorted(ps, key=lambda p: -p[0]):
            if all(np.hypot(p[1] - q[1], p[2] - q[2]) > 0.25 * max(p[3], q[3]) for q in kept):
                kept.append(p)
            if len(kept) >= limit:
                break
        out[oid] = kept
    return out


def hit(ps: Sequence[tuple[float, float, float, float]], u: float, v: float, window: float, c: float,
        scale: float | None) -> int | None:  # fmt: skip
    """The rank of the first place within `c` windows of (u, v) (and `scale` of its window), or None."""
    for rank, (_, pu, pv, pw) in enumerate(ps):
        if np.hypot(pu - u, pv - v) <= c * window and (scale is None or abs(pw / window - 1) <= scale):
            return rank
    return None


def main(argv: list[str] | None = None) -> int:
    from index.data.bop import BopDataset
    from index.geometry.pose import View
    from index.templates.render import Renderer
    from index.templates.viewpoints import hemisphere
    from training.objectness.recall import truth_of
    from training.splits import split_frames

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=Path("../shared/data/lmo"))
    p.add_argument("--objectness", type=Path, default=Path("models/posedesc-objectness.onnx"))
    p.add_argument("--split", choices=("val", "test"), default="val")
    p.add_argument("--surround", type=float, default=0.5, help="weight of the ring around the object")
    p.add_argument("--objects", default="", help="object ids, comma-separated (default all)")
    p.add_argument("--max-frames", type=int, default=0, help="the first n frames of the split (0: all)")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    for path in (args.data, args.objectness):
        if not path.exists():
            p.error(f"{path} does not exist")
    ds = BopDataset(args.data)
    ids = [int(x) for x in args.objects.split(",") if x] or sorted(ds.models_info)
    session = stride16(args.objectness)
    renderer = Renderer(size=RENDER_PX, window_mm=200.0)
    views = [View(float(a), float(e), float(r), 400.0) for a, e in hemisphere(1) for r in (0, 90, 180, 270)]
    bags = {}
    for oid in ids:
        t = renderer.render(ds.mesh(oid), views)
        bags[oid] = (bag(session, t.rgb, t.depth), float(ds.models_info[oid]["diameter"]))
    renderer.close()
    insts = list(ds.instances(2))
    split = split_frames(sorted({i.frame_id for i in insts}))
    frames: dict[int, list] = {}
    for inst in insts:
        if split[inst.frame_id] == args.split and inst.obj_id in bags:
            frames.setdefault(inst.frame_id, []).append(inst)
    chosen = sorted(frames)[: args.max_frames or None]
    ranks: dict[str, dict[int, list[int | None]]] = {k: {o: [] for o in ids} for k in TOLERANCES}
    t0 = time.perf_counter()
    for fid in chosen:
        group = frames[fid]
        found = proposals(session, group[0].load_rgb(), bags, args.surround)
        for inst in group:
            if inst.visib_fract < 0.5:
                continue
            t = truth_of(inst, float(ds.models_info[inst.obj_id]["diameter"]))
            for name, (c, scale) in TOLERANCES.items():
                ranks[name][inst.obj_id].append(hit(found[inst.obj_id], t.u, t.v, t.window_px, c, scale))
    seconds = (time.perf_counter() - t0) / max(len(chosen), 1)
    recall = {
        name: {
            "all": round(float(np.mean([r is not None for rs in by.values() for r in rs])), 4),
            **{str(o): round(float(np.mean([r is not None for r in rs])), 4) for o, rs in by.items() if rs},
        }
        for name, by in ranks.items()
    }
    out = {
        "split": args.split,
        "frames": len(chosen),
        "instances": sum(len(rs) for rs in ranks["w/8, any scale"].values()),
        "recall_in_own_top10": recall,
        "surround": args.surround,
        "seconds_per_frame": round(seconds, 3),
        "objects": ids,
        "command": shlex.join(["scripts/probe_appearance.py", *(argv if argv is not None else sys.argv[1:])]),
    }
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
