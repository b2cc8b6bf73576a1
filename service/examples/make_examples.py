"""Writes the README's example images: the demo "robot" seen from azimuth 40, elevation 30 at 600 mm,
its origin at pixel (380, 250) of a Kinect-like 640 x 480 frame (LineMOD intrinsics), before a dark wall
at 1.5 m; the colour frame, the 16-bit depth (mm) and a 64 x 64 patch of the 200 mm window.

    .venv/bin/python service/examples/make_examples.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from index.patches import PatchSpec, crop
from index.pose import View, view_to_pose
from index.render import Renderer
from index.shapes import demo_shapes

HERE = Path(__file__).parent
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
VIEW, UV = View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0)


def main() -> None:
    renderer = Renderer()
    R, t = view_to_pose(VIEW, ray=np.linalg.inv(K) @ np.array([*UV, 1.0]))
    wall = trimesh.creation.box(extents=[8000, 8000, 10])
    wall.visual = trimesh.visual.ColorVisuals(
        wall, vertex_colors=np.tile([20, 20, 20, 255], (len(wall.vertices), 1))
    )
    scene = [(demo_shapes()["robot"], R, t), (wall, np.eye(3), np.array([0.0, 0.0, 1500.0]))]
    rgb, depth = renderer.render_frame(scene, K, 640, 480)
    Image.fromarray(rgb).save(HERE / "robot-rgb.png")
    Image.fromarray(np.round(depth).astype(np.uint16)).save(HERE / "robot-depth.png")
    patch, _ = crop(rgb, None, K, UV, VIEW.distance, PatchSpec())
    Image.fromarray(patch).save(HERE / "robot-patch.png")
    renderer.close()


if __name__ == "__main__":
    main()
