"""Pictures for the README: a contact sheet excerpt and real LM-O patches beside their templates.

.venv/bin/python scripts/docs_pictures.py --lmo ../shared/data/lmo --out docs
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from index.data.bop import BopDataset, instance_patch
from index.geometry.sensor import SensorModel, random_background
from index.templates.render import Renderer
from index.templates.viewpoints import sphere_views


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--lmo", type=Path, default=Path("../shared/data/lmo"))
    p.add_argument("--out", type=Path, default=Path("docs"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    ds = BopDataset(args.lmo)
    r = Renderer()
    meshes = {o: ds.mesh(o) for o in ds.obj_ids}

    # 1. real patches (cropped at the true centre, rectified) above their templates and a sensor-model render
    rng = np.random.default_rng(0)
    seen, cols = set(), []
    sensor = SensorModel()
    for inst in ds.instances(2, min_visib=0.9):
        if inst.obj_id in seen:
            continue
        seen.add(inst.obj_id)
        real, _, view = instance_patch(inst)
        t = r.render(meshes[inst.obj_id], [view])
        bg = random_background((64, 64), rng, view.distance)
        noisy, _ = sensor.apply(t.rgb[0], t.depth[0], rng, *bg)
        cols.append(np.concatenate([real, t.rgb[0], noisy], axis=0))
    grid = cv2.resize(np.concatenate(cols, axis=1), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(args.out / "real_vs_template.png"), grid[..., ::-1])

    # 2. one object from every 8th template viewpoint, rgb above depth
    obj = ds.obj_ids[len(ds.obj_ids) // 2]
    t = r.render(meshes[obj], sphere_views(3)[::8])
    from index.templates.sheet import depth_to_colour

    rgb = np.concatenate(list(t.rgb[:19]), axis=1)
    dep = np.concatenate([depth_to_colour(d) for d in t.depth[:19]], axis=1)
    cv2.imwrite(str(args.out / "templates.png"), np.concatenate([rgb, dep], axis=0)[..., ::-1])
    print("wrote", args.out / "real_vs_template.png", args.out / "templates.png")


if __name__ == "__main__":
    main()
