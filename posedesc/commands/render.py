"""Render a mesh's templates: templates.json, a contact sheet.

From the paper's viewpoints (icosphere level 3: 301), optionally with in-plane variants and through the
sensor model. A mesh whose units make the object too small or too large for the patch window is refused,
as POST /objects refuses it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from posedesc.cli import UserError


def add_arguments(p: argparse.ArgumentParser) -> None:
    from index.mesh import FORMATS_TEXT
    from index.units import UNITS

    p.add_argument("mesh", type=Path, help=f"the mesh: {FORMATS_TEXT}")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--level", type=int, default=3, help="icosphere subdivisions: 3 = 301 views, 4 = 1241")
    p.add_argument("--distance-mm", type=float, default=400.0, help="camera distance, mm (LineMOD's)")
    p.add_argument("--units", choices=UNITS, default="mm", help="units of the mesh file")
    p.add_argument("--window-mm", type=float, default=200.0, help="side of the metric patch window")
    p.add_argument("--inplane-step", type=float, default=0.0, help="in-plane step, degrees (0: none)")
    p.add_argument("--inplane-max", type=float, default=45.0, help="in-plane range +-, degrees")
    p.add_argument("--noisy", action="store_true", help="pass the templates through the sensor model")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor model")


def run(args: argparse.Namespace) -> int:
    from index.mesh import MeshError, load_mesh
    from index.render import INVISIBLE, Renderer
    from index.sheet import contact_sheet
    from index.viewpoints import inplane_steps, sphere_views

    if not 0 <= args.level <= 5:
        raise UserError("--level must be between 0 and 5")
    if args.distance_mm <= 0 or args.window_mm <= 0:
        raise UserError("--distance-mm and --window-mm must be positive")
    try:  # the check of POST /objects: a mesh whose units make it too small or large to show is refused
        mesh = load_mesh(args.mesh, units=args.units, window_mm=args.window_mm)
    except MeshError as e:
        raise UserError(f"{args.mesh}: {e}") from None
    views = sphere_views(args.level, inplane_steps(args.inplane_step, args.inplane_max), args.distance_mm)
    renderer = Renderer(window_mm=args.window_mm)
    t0 = time.perf_counter()
    with tqdm(total=len(views), desc="render", unit="view", disable=None) as bar:
        templates = renderer.render(mesh, views, progress=bar.update)
    seconds = time.perf_counter() - t0
    if not templates.visible:  # e.g. an object far from its origin, where the camera looks
        raise UserError(f"{args.mesh}: {INVISIBLE}")
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
