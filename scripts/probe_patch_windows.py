"""What a new user meets sending `posedesc render --patches` queries: meshes of every size registered beside the
demo objects, each one's query files sent as `render --patches` writes them, and every answer counted.

    scripts/probe_patch_windows.py --sizes 22,35,50,70,100,150,200,300 --json docs/results/patch-windows.json

For each size, a procedural shape of that diameter (`index.templates.shapes.random_shape`, seeded) is
registered in a fresh data dir holding the four demo objects (the service in this process, the shipped models);
its query files are rendered (`posedesc.commands.render.write_queries` through the window the service gives it)
and each view is sent five ways: the colour patch, the depth patch and both (with the JSON's `patch.form`),
and the whole frame with its centre, colour and RGB-D (with `form`). An answer is *right* (the mesh named), *unknown* (rejected),
*wrong* (another object named) and *confidently wrong* (another object named with confidence >= 0.5).
The target of issue 53: no confidently wrong answer."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="22,35,50,70,100,150,200,300", help="diameters, mm, comma-separated")
    p.add_argument("--models", type=Path, default=ROOT / "models")
    p.add_argument("--level", type=int, default=3, help="template viewpoints (3: the service's 301)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    sizes = [float(s) for s in args.sizes.split(",")]

    from fastapi.testclient import TestClient

    from index.templates.render import Renderer
    from index.templates.shapes import random_shape
    from posedesc.commands.render import write_queries
    from service.main import create_app
    from service.settings import Settings

    rows, t0 = [], time.perf_counter()
    for i, size in enumerate(sizes):
        mesh = random_shape(np.random.default_rng(args.seed + i), diameter_mm=(size, size))
        with tempfile.TemporaryDirectory() as tmp:
            settings = Settings(data_dir=Path(tmp) / "data", models_dir=args.models, level=args.level)
            with TestClient(create_app(settings)) as c:
                _ready(c)
                r = c.post(
                    "/objects",
                    files={"mesh": ("shape.ply", mesh.export(file_type="ply"))},
                    data={"name": "shape", "units": "mm", "symmetry": "none"},
                )
                obj = _created(c, r)
                window = float(obj["window_mm"])
                renderer = Renderer(window_mm=window)
                try:
                    write_queries(renderer, mesh, Path(tmp) / "q", "shape.ply")
                finally:
                    renderer.close()
                for j in range(4):
                    q = json.loads((Path(tmp) / "q" / f"query-{j:02d}.json").read_text())
                    for kind, names, form in _queries(q):
                        files = {
                            k: (f"{k}.png", (Path(tmp) / "q" / f).read_bytes()) for k, f in names.items()
                        }
                        r = c.post("/recognize", files=files, data={k: str(v) for k, v in form.items()})
                        rows.append(_row(size, window, j, kind, r))
        print(f"{size:g} mm (window {window:g}): {_summary([x for x in rows if x['size_mm'] == size])}")
    result = {
        "sizes_mm": sizes,
        "rows": rows,
        "by_kind": {
            k: _summary([x for x in rows if x["kind"] == k]) for k in sorted({x["kind"] for x in rows})
        },
        "all": _summary(rows),
        "registered": "the mesh and the four demo objects (demo-mug, demo-lamp, demo-robot, demo-duck)",
        "seconds": round(time.perf_counter() - t0, 1),
        "command": shlex.join(
            ["scripts/probe_patch_windows.py", *(argv if argv is not None else sys.argv[1:])]
        ),
    }
    print(json.dumps(result["all"]))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


def _queries(q: dict) -> list[tuple[str, dict[str, str], dict]]:
    """The five ways a view is sent: (kind, form file field -> query file, form fields)."""
    f, patch = q["files"], q["patch"]["form"]
    return [
        ("patch-rgb", {"rgb": f["patch_rgb"]}, patch),
        ("patch-depth", {"depth": f["patch_depth"]}, patch),
        ("patch-rgbd", {"rgb": f["patch_rgb"], "depth": f["patch_depth"]}, patch),
        ("frame-rgb", {"rgb": f["rgb"]}, q["form"]),
        ("frame-rgbd", {"rgb": f["rgb"], "depth": f["depth"]}, q["form"]),
    ]


def _row(size: float, window: float, view: int, kind: str, r) -> dict:
    body = r.json()
    best = body.get("best") if r.status_code == 200 else None
    name = best["name"] if best else None
    conf = best.get("confidence") if best else None
    verdict = (
        "refused"
        if r.status_code != 200
        else "unknown"
        if best is None
        else "right"
        if name == "shape"
        else "confidently wrong"
        if (conf or 0.0) >= 0.5
        else "wrong"
    )
    return {
        "size_mm": size,
        "window_mm": window,
        "view": view,
        "kind": kind,
        "status": r.status_code,
        "named": name,
        "confidence": conf,
        "verdict": verdict,
        "detail": body.get("detail") if r.status_code != 200 else None,
    }


def _summary(rows: list[dict]) -> dict:
    out: dict = {"n": len(rows)}
    for v in ("right", "unknown", "wrong", "confidently wrong", "refused"):
        out[v] = sum(x["verdict"] == v for x in rows)
    return out


def _ready(client, timeout: float = 300.0) -> None:
    t = time.monotonic()
    while time.monotonic() - t < timeout:
        if client.get("/readyz").status_code == 200:
            return
        time.sleep(0.2)
    raise SystemExit("the service did not get ready")


def _created(client, r, timeout: float = 300.0) -> dict:
    if r.status_code == 201:
        return r.json()
    if r.status_code != 202:
        raise SystemExit(f"registration refused: {r.status_code} {r.text}")
    job = r.json()["job_id"]
    t = time.monotonic()
    while time.monotonic() - t < timeout:
        j = client.get(f"/jobs/{job}").json()
        if j["status"] == "done":
            return client.get(f"/objects/{j['object_id'] or j['result']['object_id']}").json()
        if j["status"] == "failed":
            raise SystemExit(f"registration failed: {j}")
        time.sleep(0.2)
    raise SystemExit("registration timed out")


if __name__ == "__main__":
    sys.exit(main())
