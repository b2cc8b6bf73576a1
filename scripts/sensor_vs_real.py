"""The sensor model (`index/geometry/sensor.py`) against a real Kinect depth frame.

The frame's depth is rendered from the ground-truth poses of its annotated objects standing on their table
(`index.data.bop.table_depth`), passed through `SensorModel`, and both it and the real depth are measured the
same way on the same pixels: missing depth overall, on object pixels and by distance from the render's
depth edges; the residual against the clean render on object pixels (median, MAD: calibration and pose
offsets), the colour/depth misregistration (the shift of the real depth that fits the render best);
noise as the std of the residual after a plane fit in 8 x 8 tiles, and its correlation between neighbours.

.venv/bin/python scripts/sensor_vs_real.py --data ../shared/data/lmo-depth \
    --json docs/results/sensor_vs_real.json --png docs/sensor_vs_real.png
.venv/bin/python scripts/sensor_vs_real.py --sensor edge_dropout=0.6,random_dropout=0.003 \
    --json docs/results/sensor_vs_real_before.json     # the parameters before this comparison
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from index.data.bop import BopDataset, Instance, table_depth
from index.geometry.sensor import SensorModel
from index.templates.render import Renderer

EDGE_BINS = ((0, 1), (2, 3), (4, 6))  # px from the render's depth edges; the sensor model drops at <= 1
TABLE_TOLERANCE_MM = 25.0  # a pixel shows the modelled table when its (filled) real depth is this close
TILE = 8  # px, the side of the tiles a plane is fitted in for the noise
NOISE_TILES = (4, 16)  # and the other sizes reported


def render_scene(ds: BopDataset, insts: list[Instance]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clean depth of the frame (objects in front of their table, mm), the table's depth alone, and
    per pixel the index of the instance seen there (-1: none). Shapes: (H, W)."""
    h, w = insts[0].load_depth().shape  # type: ignore[union-attr]
    meshes = [ds.mesh(i.obj_id) for i in insts]
    r = Renderer()
    try:
        per_object = [
            r.render_frame([(m, i.R, i.t)], i.K, w, h)[1] for m, i in zip(meshes, insts, strict=True)
        ]
    finally:
        r.close()
    stack = np.stack([np.where(d > 0, d, np.inf) for d in per_object])
    objects = stack.min(axis=0)
    label = np.where(np.isfinite(objects), stack.argmin(axis=0), -1)
    objects = np.where(label >= 0, objects, 0.0).astype(np.float32)
    table = table_depth(insts, meshes, w, h)
    return np.where(label >= 0, objects, table).astype(np.float32), table, label


def depth_edges(depth: np.ndarray, step_mm: float) -> np.ndarray:
    """The sensor model's own edge test: |4-neighbour Laplacian| above `step_mm`."""
    jumps = np.abs(cv2.Laplacian(depth, cv2.CV_32F, ksize=1)) > step_mm
    jumps[[0, -1], :] = jumps[:, [0, -1]] = False
    return jumps


def regions(real: np.ndarray, clean: np.ndarray, table: np.ndarray, label: np.ndarray, step_mm: float):
    """Pixels both depths are compared on. `scene`: the objects and the table where the real frame shows
    it (hole pixels judged by their nearest valid neighbour's depth), minus 6 px next to unmodelled
    clutter; `objects`; `edge_px`: distance (px) from the clean render's nearest depth edge."""
    idx = ndimage.distance_transform_edt(real <= 0, return_distances=False, return_indices=True)
    filled = real[idx[0], idx[1]]
    on_table = (label < 0) & (table > 0) & (np.abs(filled - table) < TABLE_TOLERANCE_MM)
    on_table = cv2.morphologyEx(on_table.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8)) > 0
    objects = label >= 0
    modelled = on_table | objects
    # pixels next to what the render does not hold (clutter, the room) would count its shadows as ours
    clutter = ndimage.distance_transform_edt(modelled) <= 6
    scene = objects | (on_table & ~clutter)
    scene[:, :8] = False  # the Kinect depth image's left margin holds no measurement at all
    edge_px = ndimage.distance_transform_edt(~depth_edges(clean, step_mm))
    # Around the objects: table or the nearest object's own depth (bleeding), not unmodelled clutter.
    out_px, near = ndimage.distance_transform_edt(~objects, return_indices=True)
    nearest_obj = clean[near[0], near[1]]
    ring = (
        ~objects
        & (out_px <= 8)
        & (table > 0)
        & (
            (np.abs(filled - table) < TABLE_TOLERANCE_MM)
            | (np.abs(filled - nearest_obj) < TABLE_TOLERANCE_MM)
        )
    )
    return {
        "scene": scene,
        "objects": objects,
        "edge_px": edge_px,
        "table_mm": table,
        "ring": ring,
        "out_px": out_px,
    }


def best_shift(
    real: np.ndarray, clean: np.ndarray, objects: np.ndarray, r: int = 6
) -> tuple[int, int, float]:
    """(dx, dy, median |residual|): how far right and down the real depth's content lies from the
    render's, to the pixel, by the median absolute residual on object pixels."""
    best = (0, 0, np.inf)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            moved = np.roll(real, (-dy, -dx), axis=(0, 1))
            ok = objects & (moved > 0)
            err = float(np.median(np.abs(moved[ok] - clean[ok])))
            if err < best[2]:
                best = (dx, dy, err)
    return best


def plane_noise(residual: np.ndarray, mask: np.ndarray, tile: int) -> tuple[float, float, int]:
    """Median over fully valid tile x tile squares of the std of `residual` after a least-squares plane
    fit, the mean correlation of the detrended residual between horizontal neighbours, number of tiles."""
    yy, xx = np.mgrid[0:tile, 0:tile].astype(float)
    A = np.stack([np.ones(tile * tile), xx.ravel(), yy.ravel()], axis=1)
    P = np.eye(tile * tile) - A @ np.linalg.pinv(A)  # residual of a plane fit, as one matrix
    h, w = residual.shape
    tiles = [
        residual[y : y + tile, x : x + tile].ravel()
        for y in range(0, h - tile + 1, tile)
        for x in range(0, w - tile + 1, tile)
        if mask[y : y + tile, x : x + tile].all()
    ]
    if not tiles:
        return float("nan"), float("nan"), 0
    e = np.stack(tiles) @ P.T
    stds = e.std(axis=1, ddof=3)
    g = e.reshape(-1, tile, tile)
    corr = (g[:, :, 1:] * g[:, :, :-1]).mean(axis=(1, 2)) / np.maximum((g**2).mean(axis=(1, 2)), 1e-9)
    return float(np.median(stds)), float(np.mean(corr)), len(tiles)


def measure(depth: np.ndarray, clean: np.ndarray, label: np.ndarray, reg: dict, step_mm: float) -> dict:
    """The same figures for the real depth or a synthetic one."""
    missing = depth <= 0
    scene, objects, edge_px = reg["scene"], reg["objects"], reg["edge_px"]
    out: dict = {
        "missing_frame": float(missing.mean()),
        "missing_scene": float(missing[scene].mean()),
        "missing_objects": float(missing[objects].mean()),
        "missing_interior": float(missing[scene & (edge_px > 6)].mean()),  # small holes, no edges near
    }
    for lo, hi in EDGE_BINS:
        band = scene & (edge_px >= lo) & (edge_px <= hi)
        out[f"missing_edge_{lo}_{hi}px"] = float(missing[band].mean())
    res = depth - clean
    ok = objects & ~missing
    med = float(np.median(res[ok]))
    out["residual_objects_median_mm"] = med
    out["residual_objects_mad_mm"] = float(np.median(np.abs(res[ok] - med)))
    inner = ok & (edge_px > 3)
    med_i = float(np.median(res[inner]))
    out["residual_objects_interior_median_mm"] = med_i
    out["residual_objects_interior_mad_mm"] = float(np.median(np.abs(res[inner] - med_i)))
    out["residual_per_object_median_mm"] = [
        float(np.median(res[ok & (label == k)])) if (ok & (label == k)).any() else None
        for k in range(int(label.max()) + 1)
    ]
    # Foreground bleeding: how far beyond an object's outline the depth still shows the object, summed
    # over 1-px rings around it (a sharp outline: 0). Moving the real depth by best_shift does not lower it.
    front = ~missing & (depth < reg["table_mm"] - 15.0)
    rings = [reg["ring"] & (np.round(reg["out_px"]) == k) for k in range(1, 9)]
    out["bleed_px"] = float(sum(front[r].mean() for r in rings))
    smooth = scene & ~missing & (edge_px > 3)
    out["noise_plane_std_mm"], out["noise_neighbour_corr"], out["noise_tiles"] = plane_noise(
        res, smooth, TILE
    )
    for tile in NOISE_TILES:  # white noise is the same at every size; the Kinect's is spatially correlated
        out[f"noise_plane_std_{tile}px_mm"] = plane_noise(res, smooth, tile)[0]
    z = clean[smooth]
    out["median_depth_mm"] = float(np.median(z))
    steps = np.diff(np.unique(np.round(depth[smooth & (np.abs(clean - np.median(z)) < 30)])))
    out["depth_step_mm"] = float(np.median(steps)) if steps.size else float("nan")  # quantisation near it
    return out


def picture(path: Path, real: np.ndarray, synth: np.ndarray, reg: dict, label: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = np.percentile(real[real > 0], [2, 98])
    ys, xs = np.nonzero(label >= 0)
    y0, y1 = max(ys.min() - 25, 0), min(ys.max() + 25, real.shape[0])
    x0, x1 = max(xs.min() - 25, 0), min(xs.max() + 25, real.shape[1])
    holes = np.full((*real.shape, 3), 0.35)
    holes[~reg["scene"]] = 0.15
    holes[(real <= 0) & (synth > 0)] = (0.95, 0.25, 0.2)
    holes[(synth <= 0) & (real > 0)] = (0.2, 0.75, 0.95)
    holes[(real <= 0) & (synth <= 0)] = (1.0, 1.0, 1.0)
    cmap = matplotlib.colormaps["turbo"].copy()
    cmap.set_bad("black")
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.6))
    for row, (ya, yb, xa, xb) in enumerate([(0, real.shape[0], 0, real.shape[1]), (y0, y1, x0, x1)]):
        crop = np.s_[ya:yb, xa:xb]
        for ax, d, title in (
            (axes[row, 0], real, "real Kinect depth"),
            (axes[row, 1], synth, "render + sensor model"),
        ):
            ax.imshow(np.where(d[crop] > 0, d[crop], np.nan), cmap=cmap, vmin=lo, vmax=hi)
            ax.set_title(title + (" (objects)" if row else ""))
        axes[row, 2].imshow(holes[crop])
        axes[row, 2].set_title("missing: real only (red), model only (blue), both (white)")
        for ax in axes[row]:
            ax.contour(label[crop] >= 0, [0.5], colors="w", linewidths=0.6)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(
        "LM-O scene 2 frame 3: real depth against its render through index/geometry/sensor.py (mm, near = blue; "
        "dark grey: pixels not compared)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def sensor_from(overrides: str) -> SensorModel:
    """SensorModel() with `name=value,...` changed (e.g. an earlier parameter set, to compare)."""
    kw = {}
    for item in filter(None, overrides.split(",")):
        name, value = item.split("=")
        if name not in SensorModel.__dataclass_fields__:
            raise SystemExit(f"--sensor: SensorModel has no parameter {name!r}")
        kw[name] = float(value)
    return replace(SensorModel(), **kw)


def average(draws: list[dict]) -> tuple[dict, dict]:
    """Mean and standard deviation over the sensor-model draws, figure by figure (lists: mean only)."""
    mean, sd = {}, {}
    for k, v in draws[0].items():
        if isinstance(v, list):
            mean[k] = [float(np.mean([d[k][i] for d in draws])) for i in range(len(v))]
        else:
            mean[k], sd[k] = float(np.mean([d[k] for d in draws])), float(np.std([d[k] for d in draws]))
    return mean, sd


def format_table(real: dict, synth: dict, sd: dict) -> str:
    lines = [f"{'':36s} {'real':>9s} {'render+sensor':>13s}"]
    for k, v in real.items():
        if isinstance(v, list):
            continue
        if k.startswith("missing"):
            lines.append(f"{k:36s} {100 * v:8.2f}% {100 * synth[k]:8.2f}% ±{100 * sd[k]:.2f}")
        else:
            lines.append(f"{k:36s} {v:9.2f} {synth[k]:9.2f} ±{sd[k]:.2f}")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--data", type=Path, default=Path("../shared/data/lmo-depth"), help="BOP dir with real depth"
    )
    p.add_argument("--scene", type=int, default=2)
    p.add_argument("--seeds", type=int, default=5, help="sensor-model draws averaged")
    p.add_argument("--sensor", default="", help="change SensorModel parameters: name=value,...")
    p.add_argument("--json", type=Path, default=Path("docs/results/sensor_vs_real.json"))
    p.add_argument("--png", type=Path, default=None, help="the picture (none by default)")
    args = p.parse_args()
    t0 = time.perf_counter()
    ds = BopDataset(args.data)
    by_frame: dict[int, list[Instance]] = {}
    for inst in ds.instances(args.scene):
        if inst.depth_path is not None:
            by_frame.setdefault(inst.frame_id, []).append(inst)
    if not by_frame:
        raise SystemExit(f"{args.data}: no frame of scene {args.scene} has depth")
    frame_id, insts = next(iter(by_frame.items()))
    real = insts[0].load_depth()
    assert real is not None
    clean, table_mm, label = render_scene(ds, insts)
    sensor = sensor_from(args.sensor)
    reg = regions(real, clean, table_mm, label, sensor.edge_step_mm)
    dx, dy, err = best_shift(real, clean, reg["objects"])
    unmoved = float(np.median(np.abs((real - clean)[reg["objects"] & (real > 0)])))

    real_stats = measure(real, clean, label, reg, sensor.edge_step_mm)
    synths = [sensor.apply(None, clean, np.random.default_rng(seed))[1] for seed in range(args.seeds)]
    synth_stats, synth_sd = average([measure(d, clean, label, reg, sensor.edge_step_mm) for d in synths])  # type: ignore[arg-type]

    print(
        f"{args.data} scene {args.scene} frame {frame_id}: {len(insts)} instances, "
        f"{int(reg['scene'].sum())} px compared, {int(reg['objects'].sum())} on objects; "
        f"sensor model {args.sensor or 'as in index/geometry/sensor.py'}, {args.seeds} draws"
    )
    print(format_table(real_stats, synth_stats, synth_sd))
    per_object = dict(
        zip([i.obj_id for i in insts], real_stats["residual_per_object_median_mm"], strict=True)
    )
    print(
        "real residual median per object (mm):",
        {k: round(v, 1) for k, v in per_object.items() if v is not None},
    )
    print(
        f"misregistration: the real depth fits the render best moved by dx = {dx} px, dy = {dy} px "
        f"(median |residual| on objects {err:.2f} mm, unmoved {unmoved:.2f} mm)"
    )
    result = {
        "command": " ".join(
            ["scripts/sensor_vs_real.py", "--data", str(args.data), "--scene", str(args.scene)]
            + ["--seeds", str(args.seeds), "--json", str(args.json)]
            + (["--sensor", args.sensor] if args.sensor else [])
            + (["--png", str(args.png)] if args.png else [])
        ),
        "data": str(args.data),
        "scene": args.scene,
        "frame": frame_id,
        "objects": [i.obj_id for i in insts],
        "sensor_model": {k: getattr(sensor, k) for k in SensorModel.__dataclass_fields__},
        "pixels_compared": {"scene": int(reg["scene"].sum()), "objects": int(reg["objects"].sum())},
        "misregistration_px": {"dx": dx, "dy": dy, "median_abs_residual_mm": err, "unmoved_mm": unmoved},
        "real": real_stats,
        "synthetic_mean": synth_stats,
        "synthetic_sd": synth_sd,
        "seeds": args.seeds,
        "seconds": round(time.perf_counter() - t0, 1),
        "notes": "missing_* are fractions; missing_frame is the whole frame, of which the render holds only "
        "the objects and a table plane (so no large holes for the synthetic one); edge bins are px from the clean render's depth edges (|Laplacian| > "
        f"{sensor.edge_step_mm:g} mm); scene = objects + the table where the real frame shows it, 6 px clear of "
        "unmodelled clutter; residual = depth - clean render; noise = median over 8x8 tiles (4, 16: the "
        "other sizes) of the residual's std after a plane fit, away from edges",
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    if args.png:
        picture(args.png, real, synths[0], reg, label)  # type: ignore[arg-type]
    print("wrote", args.json, *([args.png] if args.png else []))


if __name__ == "__main__":
    main()
