"""Render templates of a mesh from the paper's viewpoints: templates.json and a contact sheet."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from posedesc.cli import UserError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mesh", type=Path, help="PLY, OBJ, STL, GLB or OFF file")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--level", type=int, default=3, help="icosphere subdivisions: 3 = 301 views, 4 = 1241")
    p.add_argument("--distance-mm", type=float, default=400.0, help="camera distance (LineMOD: 400)")
    p.add_argument("--units", choices=("mm", "m"), default="mm", help="units of the mesh file")
    p.add_argument("--window-mm", type=float, default=200.0, help="side of the metric patch window")
    p.add_argument("--inplane-step", type=float, default=0.0, help="in-plane step, degrees (0: none)")
    p.add_argument("--inplane-max", type=float, default=45.0, help="in-plane range +-, degrees")
    p.add_argument("--noisy", action="store_true", help="pass the templates through the sensor model")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor model")


def run(args: argparse.Namespace) -> int:
    from index.mesh import MeshError, load_mesh, scale_warning
    from index.render import Renderer
    from index.sheet import contact_sheet
    from index.viewpoints import inplane_steps, sphere_views

    if not 0 <= args.level <= 5:
        raise UserError("--level must be between 0 and 5")
    if args.distance_mm <= 0 or args.window_mm <= 0:
        raise UserError("--distance-mm and --window-mm must be positive")
    try:
        mesh = load_mesh(args.mesh, units=args.units)
    except MeshError as e:
        raise UserError(f"{args.mesh}: {e}") from None
    if warning := scale_warning(mesh, args.window_mm):
        print(f"posedesc render: warning: {warning}", file=sys.stderr)
    views = sphere_views(args.level, inplane_steps(args.inplane_step, args.inplane_max), args.distance_mm)
    renderer = Renderer(window_mm=args.window_mm)
    t0 = time.perf_counter()
    with tqdm(total=len(views), desc="render", unit="view", disable=None) as bar:
        templates = renderer.render(mesh, views, progress=bar.update)
    seconds = time.perf_counter() - t0
    if args.noisy:
        from index.sensor import SensorModel, random_background

        rng = np.random.default_rng(args.seed)
        sensor = SensorModel()
        for i, v in enumerate(views):
            bg_rgb, bg_depth = random_background(templates.depth[i].shape, rng, v.distance)
            templates.rgb[i], templates.depth[i] = sensor.apply(
                templates.rgb[i], templates.depth[i], rng, bg_rgb, bg_depth
            )
    args.out.mkdir(parents=True, exist_ok=True)
    entries = [
        {"azimuth": round(v.azimuth, 4), "elevation": round(v.elevation, 4), "inplane": v.inplane}
        for v in views
    ]
    (args.out / "templates.json").write_text(json.dumps(entries, indent=1))
    title = (
        f"{args.mesh.name}: {len(views)} templates, {args.distance_mm:.0f} mm, window {args.window_mm:.0f} mm"
    )
    contact_sheet(templates, args.out / "sheet.png", title=title + (" (sensor model)" if args.noisy else ""))
    print(
        f"{len(views)} templates of {args.mesh.name} ({len(mesh.faces)} faces) in {seconds:.2f} s -> {args.out}"
    )
    return 0
