"""Writes the README's example files: the demo "robot" seen from azimuth 40, elevation 30 at 600 mm,
its origin at pixel (380, 250) of a Kinect-like 640 x 480 frame (LineMOD intrinsics), before a dark wall
at 1.5 m (the colour frame, the 16-bit depth (mm) and a 64 x 64 patch of the 200 mm window); and
`part.ply`, a mesh to register: an angle bracket with a boss and a rib, in mm, vertex colours.

    .venv/bin/python service/examples/make_examples.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from index.features.patches import PatchSpec, crop
from index.geometry.pose import View, view_to_pose
from index.geometry.units import fits
from index.templates.mesh import diameter
from index.templates.render import Renderer
from index.templates.shapes import demo_shapes

HERE = Path(__file__).parent
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
VIEW, UV = View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0)


def part() -> trimesh.Trimesh:
    """An angle bracket, 150 mm across, origin at its bounding box's centre; no symmetry."""

    def piece(mesh: trimesh.Trimesh, at: list[float], rgb: tuple[int, int, int]) -> trimesh.Trimesh:
        mesh.apply_translation(at)
        mesh.visual = trimesh.visual.ColorVisuals(
            mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)).astype(np.uint8)
        )
        return mesh

    pieces = [
        piece(trimesh.creation.box(extents=[110, 70, 10]), [0, 0, 5], (70, 90, 120)),  # base plate
        piece(trimesh.creation.box(extents=[10, 70, 60]), [-50, 0, 40], (210, 120, 40)),  # upright
        piece(trimesh.creation.cylinder(radius=14, height=30, sections=48), [30, 15, 25], (190, 190, 200)),
        piece(trimesh.creation.box(extents=[50, 8, 8]), [-20, -25, 14], (180, 40, 40)),  # rib
        piece(trimesh.creation.icosphere(subdivisions=3, radius=9), [-50, -20, 75], (40, 160, 80)),  # knob
    ]
    mesh = trimesh.util.concatenate(pieces)
    assert isinstance(mesh, trimesh.Trimesh)  # meshes concatenate to a mesh
    mesh.apply_translation(-mesh.bounding_box.centroid)
    return mesh


def write_part(path: Path = HERE / "part.ply") -> None:
    mesh = part()
    assert fits(diameter(mesh))  # what POST /objects accepts in mm
    data = mesh.export(file_type="ply")
    assert isinstance(data, bytes)  # binary PLY
    path.write_bytes(data)


def main() -> None:
    write_part()
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
