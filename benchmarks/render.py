"""How fast templates are rendered: all 301 viewpoints of a 20k-face mesh, with the renderer's level of
detail (decimation to the faces a 64 px patch can show) and without it, median of repeats.

    .venv/bin/python benchmarks/render.py [--mesh PLY] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import trimesh

from index.templates.mesh import load_mesh
from index.templates.render import Renderer
from index.templates.viewpoints import sphere_views


def mesh_20k(path: str | None) -> trimesh.Trimesh:
    if path:
        return load_mesh(path, max_faces=20_000)
    m = trimesh.creation.icosphere(subdivisions=5, radius=70)  # 20,480 faces
    m.vertices[:, 2] *= 1.6
    rng = np.random.default_rng(0)
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=rng.integers(0, 255, (len(m.vertices), 4)))
    return m


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument(
        "--mesh", help="a mesh (decimated to 20k faces); default: a generated 20,480-face ellipsoid"
    )
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    mesh = mesh_20k(args.mesh)
    views = sphere_views(3)
    results = {}
    for name, max_faces in (("lod", 6000), ("full", 10**9)):
        r = Renderer(max_faces=max_faces)
        r.render(mesh, views[:5])  # warm-up: shader compilation
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            r.render(mesh, views)
            times.append(time.perf_counter() - t0)
        r.close()
        results[name] = statistics.median(times)
    print(json.dumps({"faces": len(mesh.faces), "views": len(views), "median_s": results}, indent=1))
    print(
        f"301 views of a {len(mesh.faces)}-face mesh: {results['lod']:.2f} s with LOD, {results['full']:.2f} s "
        f"without ({results['full'] / results['lod']:.1f}x)"
    )


if __name__ == "__main__":
    main()
