"""What the service costs: registering a 20k-face mesh (render / embed / store, per in-plane step) and
recognising a full frame in-process (TestClient, every modality), medians of repeats. Prints numbers;
never fails on time. `posedesc bench` measures the same over HTTP (and imports `mesh_20k`, `demo_frame`).

    .venv/bin/python benchmarks/serving/costs.py [--models models] [--repeats 3] [--queries 50]
"""

from __future__ import annotations

import argparse
import io
import statistics
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from index.features.embed import load_models, store_keys
from index.geometry.pose import View, view_to_pose
from index.store import Store
from index.templates.register import TemplateConfig, register
from index.templates.render import RenderWorker
from index.templates.shapes import demo_shapes

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])


def mesh_20k() -> trimesh.Trimesh:
    """A demo shape plus a 20,480-face ellipsoid: ~20k faces, coloured."""
    m = trimesh.creation.icosphere(subdivisions=5, radius=50)
    m.vertices[:, 2] *= 1.6
    rng = np.random.default_rng(0)
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=rng.integers(0, 255, (len(m.vertices), 4)))
    mesh = trimesh.util.concatenate([m, demo_shapes()["robot"]])
    assert isinstance(mesh, trimesh.Trimesh)  # meshes concatenate to a mesh
    return mesh


def png(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG")
    return buf.getvalue()


def demo_frame(worker: RenderWorker) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """The demo robot at azimuth 40, elevation 30, 600 mm, before a wall, in a 640x480 frame: rgb, depth
    (mm) and the camera fields of a `/recognize` request for it."""
    view, uv = View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0)
    R, t = view_to_pose(view, ray=np.linalg.inv(K) @ np.array([*uv, 1.0]))
    wall = trimesh.creation.box(extents=[8000, 8000, 10])
    scene = [(demo_shapes()["robot"], R, t), (wall, np.eye(3), np.array([0.0, 0.0, 1500.0]))]
    rgb, depth = worker.submit(lambda r: r.render_frame(scene, K, 640, 480)).result()
    fields = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "u": uv[0], "v": uv[1]}
    return rgb, depth, {k: float(v) for k, v in fields.items()}


def bench_registration(models: Path, repeats: int) -> None:
    embedders = load_models(models)
    worker = RenderWorker()
    mesh = mesh_20k()
    print(f"registration of a {len(mesh.faces)}-face mesh, models {sorted(embedders)} (median of {repeats})")
    with tempfile.TemporaryDirectory() as d, ThreadPoolExecutor(2) as pool:
        store = Store(d, store_keys(embedders))
        for step in (0.0, 45.0, 15.0):
            cfg = TemplateConfig(inplane_step=step)
            runs = [
                register(  # one name per object: the store refuses a second object of a name
                    mesh,
                    f"x{step:g}-{i}",
                    "none",
                    worker=worker,
                    embedders=embedders,
                    store=store,
                    cfg=cfg,
                    pool=pool,
                )
                for i in range(repeats)
            ]
            med = {k: statistics.median(r.timings[k] for r in runs) for k in runs[0].timings}
            n = max(runs[0].record.templates.values())
            print(
                f"  in-plane step {step:4.0f}: {n:5d} templates/model  "
                + "  ".join(f"{k} {v:.2f} s" for k, v in med.items())
            )
    worker.close()


def bench_recognition(models: Path, queries: int) -> None:
    from fastapi.testclient import TestClient

    from service.main import create_app
    from service.settings import Settings

    with tempfile.TemporaryDirectory() as d:
        settings = Settings(data_dir=Path(d), models_dir=models, sync_seconds=120.0)
        with TestClient(create_app(settings)) as c:
            while c.get("/readyz").status_code != 200:  # the four demo objects, registered at start-up
                time.sleep(0.2)
            worker = RenderWorker()
            rgb, depth, fields = demo_frame(worker)
            worker.close()
            sent = {
                "rgb": ({"rgb": png(rgb)}, {**fields, "distance_mm": 600}),
                "depth": ({"depth": png(np.round(depth).astype(np.uint16))}, fields),
                "rgbd": ({"rgb": png(rgb), "depth": png(np.round(depth).astype(np.uint16))}, fields),
            }
            print(f"recognition of a 640x480 frame in-process, 4 demo objects (median / p90 of {queries})")
            for modality, (files, data) in sent.items():
                if modality not in settings_models(models):
                    continue
                wall_ms, inner = [], []
                for _ in range(queries):
                    t0 = time.perf_counter()
                    r = c.post(
                        "/recognize",
                        files={k: (f"{k}.png", v) for k, v in files.items()},
                        data={k: str(v) for k, v in data.items()},
                    )
                    wall_ms.append((time.perf_counter() - t0) * 1000)
                    inner.append(r.json()["timings_ms"])
                best = r.json()["best"]
                stages = {k: statistics.median(i[k] for i in inner) for k in inner[0]}
                print(
                    f"  {modality:5s}: request {statistics.median(wall_ms):6.1f} / {np.percentile(wall_ms, 90):6.1f} ms;"
                    + " ".join(f" {k} {v:.1f}" for k, v in stages.items())
                    + f" ms; best {best['name']} az {best['azimuth']:.0f} el {best['elevation']:.0f}"
                )


def settings_models(models: Path) -> set[str]:
    return set(load_models(models))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--models", type=Path, default=Path("models"))
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--queries", type=int, default=50)
    args = p.parse_args()
    bench_registration(args.models, args.repeats)
    bench_recognition(args.models, args.queries)


if __name__ == "__main__":
    main()
