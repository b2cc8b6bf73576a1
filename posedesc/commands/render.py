"""Render a mesh's templates, or query files to send.

From the paper's viewpoints (icosphere level 3: 301), optionally with in-plane variants and through the
sensor model. A mesh whose units make the object too small or too large to register is refused,
as POST /objects refuses it.

`--patches DIR` writes what a user can send to `POST /recognize` as it is, from a few views of the mesh
(`QUERY_VIEWS`) before a plain wall, in a Kinect-like camera (LineMOD's intrinsics, 640 x 480), for each
view NN: `query-NN-rgb.png` and `query-NN-depth.png` (16-bit, mm), the whole frame; `query-NN-patch-rgb.png`
and `query-NN-patch-depth.png`, the patch the service cuts from that frame (`index.features.patches.crops`)
through the window the service registers the mesh with (`index.templates.windows.window_class` of its
diameter: 200 mm for objects of 100-280 mm, sqrt(2) steps beyond), the views' distances scaled with it; and
`query-NN.json`: `form`, the frame's form fields (fx, fy, cx, cy, u, v, distance_mm), `pose`, the truth
(azimuth, elevation, inplane, and BOP's R, t in the frame's camera), `files`, and `patch` (its size, window
and the distance it was cut at, and `form`: the fields to send with the patch, its `window_mm` among them;
its pose is the same view on the patch camera's optical axis).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from posedesc.cli import UserError

if TYPE_CHECKING:
    import trimesh

    from index.templates.render import Renderer

#: the query frames' camera: LineMOD's Kinect intrinsics, as the README's example frame
FRAME_K = ((572.4, 0.0, 325.3), (0.0, 573.6, 242.0), (0.0, 0.0, 1.0))
FRAME_SIZE = (640, 480)
#: (azimuth, elevation, in-plane degrees, distance mm, u, v px): around the object, rolled twice, off the
#: optical axis, at a Kinect's working distances
QUERY_VIEWS = (
    (40.0, 30.0, 0.0, 600.0, 380.0, 250.0),
    (130.0, 50.0, 30.0, 700.0, 260.0, 200.0),
    (220.0, 20.0, -45.0, 550.0, 330.0, 300.0),
    (310.0, 65.0, 0.0, 800.0, 420.0, 180.0),
)
#: a plain wall behind the object (mm from the camera; a dark grey), so the depth has a background
WALL_MM, WALL_RGB = 1500.0, (60, 60, 60)
#: the shipped models' window: the views' distances and the wall are for an object of its class, and
#: scaled with the object's window for others
MODEL_WINDOW_MM = 200.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    from index.geometry.units import UNITS
    from index.templates.mesh import FORMATS_TEXT

    p.add_argument("mesh", type=Path, help=f"the mesh: {FORMATS_TEXT}")
    p.add_argument("--out", type=Path, help="output folder of the templates and their contact sheet")
    p.add_argument(
        "--patches", type=Path, help="output folder of query files to send to POST /recognize (see above)"
    )
    p.add_argument("--level", type=int, default=3, help="icosphere subdivisions: 3 = 301 views, 4 = 1241")
    p.add_argument("--distance-mm", type=float, default=400.0, help="camera distance, mm (LineMOD's)")
    p.add_argument("--units", choices=UNITS, default="mm", help="units of the mesh file")
    p.add_argument(
        "--window-mm",
        type=float,
        help="side of the metric window, mm (default: the templates' 200; the query patches' the one the "
        "service registers the mesh with)",
    )
    p.add_argument("--inplane-step", type=float, default=0.0, help="in-plane step, degrees (0: none)")
    p.add_argument("--inplane-max", type=float, default=45.0, help="in-plane range +-, degrees")
    p.add_argument("--noisy", action="store_true", help="pass the templates through the sensor model")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor model")


def run(args: argparse.Namespace) -> int:
    from index.templates.mesh import MeshError, load_mesh
    from index.templates.render import Renderer

    if args.out is None and args.patches is None:
        raise UserError("say where to write: --out DIR (templates), --patches DIR (query files), or both")
    if not 0 <= args.level <= 5:
        raise UserError("--level must be between 0 and 5")
    if args.distance_mm <= 0 or (args.window_mm is not None and args.window_mm <= 0):
        raise UserError("--distance-mm and --window-mm must be positive")
    try:  # the check of POST /objects: a mesh whose units make it too small or large to show is refused
        mesh = load_mesh(args.mesh, units=args.units, check_size=True)
    except MeshError as e:
        raise UserError(f"{args.mesh}: {e}") from None
    if args.patches is not None:
        from index.templates.mesh import diameter
        from index.templates.windows import window_class

        window = args.window_mm or window_class(diameter(mesh), MODEL_WINDOW_MM)
        queries = Renderer(window_mm=window)
        try:
            write_queries(queries, mesh, args.patches, args.mesh.name)
        finally:
            queries.close()
        print(
            f"{len(QUERY_VIEWS)} queries of {args.mesh.name} -> {args.patches} (patches: window_mm {window:g})"
        )
    if args.out is not None:
        args.window_mm = args.window_mm or MODEL_WINDOW_MM
        renderer = Renderer(window_mm=args.window_mm)
        try:
            write_templates(renderer, mesh, args)
        finally:
            renderer.close()
    return 0


def write_templates(renderer: Renderer, mesh: trimesh.Trimesh, args: argparse.Namespace) -> None:
    """templates.json and sheet.png of the mesh's template views."""
    from index.templates.render import INVISIBLE
    from index.templates.sheet import contact_sheet
    from index.templates.viewpoints import inplane_steps, sphere_views

    views = sphere_views(args.level, inplane_steps(args.inplane_step, args.inplane_max), args.distance_mm)
    t0 = time.perf_counter()
    with tqdm(total=len(views), desc="render", unit="view", disable=None) as bar:
        templates = renderer.render(mesh, views, progress=bar.update)
    seconds = time.perf_counter() - t0
    if not templates.visible:  # e.g. an object far from its origin, where the camera looks
        raise UserError(f"{args.mesh}: {INVISIBLE}")
    if args.noisy:
        from index.geometry.sensor import SensorModel, random_background

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


def write_queries(renderer: Renderer, mesh: trimesh.Trimesh, out: Path, mesh_name: str) -> None:
    """The query files of `QUERY_VIEWS` (module docstring), the patch cut with the renderer's window, the
    views' distances and the wall's scaled with it."""
    import cv2
    import trimesh

    from index.features.patches import PatchSpec, crops
    from index.geometry.pose import View, view_to_pose
    from index.templates.render import INVISIBLE

    K = np.array(FRAME_K)
    spec = PatchSpec(renderer.size, renderer.window_mm)
    wall = trimesh.creation.box(extents=[8000, 8000, 10])
    wall.visual = trimesh.visual.ColorVisuals(
        wall, vertex_colors=np.tile([*WALL_RGB, 255], (len(wall.vertices), 1))
    )
    scale = spec.window_mm / MODEL_WINDOW_MM
    views = [(az, el, roll, round(dist * scale, 1), u, v) for az, el, roll, dist, u, v in QUERY_VIEWS]
    wall_mm = WALL_MM * scale
    frames = []
    for az, el, roll, dist, u, v in views:
        R, t = view_to_pose(View(az, el, roll, dist), ray=np.linalg.inv(K) @ np.array([u, v, 1.0]))
        scene = [(mesh, R, t), (wall, np.eye(3), np.array([0.0, 0.0, wall_mm + 5.0]))]  # its face at wall_mm
        rgb, depth = renderer.render_frame(scene, K, *FRAME_SIZE)
        if not (depth[depth > 0] < wall_mm - 1.0).any():
            raise UserError(f"{mesh_name}: {INVISIBLE}")
        frames.append((rgb, depth, R, t))
    out.mkdir(parents=True, exist_ok=True)
    for i, ((az, el, roll, dist, u, v), (rgb, depth, R, t)) in enumerate(zip(views, frames, strict=True)):
        stem = f"query-{i:02d}"
        patch_rgb, patch_depth = crops(rgb, depth, K, (u, v), dist, spec, (0.0,))
        assert patch_rgb is not None and patch_depth is not None  # both were given
        files = {
            "rgb": f"{stem}-rgb.png",
            "depth": f"{stem}-depth.png",
            "patch_rgb": f"{stem}-patch-rgb.png",
            "patch_depth": f"{stem}-patch-depth.png",
        }
        for key, image in (
            ("rgb", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)),
            ("depth", _mm16(depth)),
            ("patch_rgb", cv2.cvtColor(patch_rgb[0], cv2.COLOR_RGB2BGR)),
            ("patch_depth", _mm16(patch_depth[0])),
        ):
            cv2.imwrite(str(out / files[key]), image)
        form = {
            "fx": K[0, 0],
            "fy": K[1, 1],
            "cx": K[0, 2],
            "cy": K[1, 2],
            "u": u,
            "v": v,
            "distance_mm": dist,
        }
        pose = {
            "azimuth": az,
            "elevation": el,
            "inplane": roll,
            "R": [round(float(x), 6) for x in R.ravel()],
            "t": [round(float(x), 3) for x in t],
        }
        patch = {
            "size": spec.size,
            "window_mm": spec.window_mm,
            "distance_mm": dist,
            "form": {"window_mm": spec.window_mm, "distance_mm": dist},  # what to send with the patch
        }
        body = {"mesh": mesh_name, "form": form, "pose": pose, "files": files, "patch": patch}
        (out / f"{stem}.json").write_text(json.dumps(body, indent=1))


def _mm16(depth_mm: np.ndarray) -> np.ndarray:
    """Depth in mm as a 16-bit PNG holds it (0: nothing measured)."""
    return np.round(np.clip(depth_mm, 0, np.iinfo(np.uint16).max)).astype(np.uint16)
