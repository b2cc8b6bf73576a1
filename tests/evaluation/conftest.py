"""A tiny BOP dataset written by the tests: two coloured shapes in a few rendered frames (RGB only, so
depth and RGB-D are evaluated on synthetic scenes), and untrained ONNX models for the plumbing."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from index.geometry.pose import View, view_to_pose

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
N_FRAMES = 6


def coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(
        mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1))
    )
    return mesh


def make_mug() -> trimesh.Trimesh:
    """A second asymmetric object: a yellow cylinder with a purple handle and a grey lid."""
    body = coloured(trimesh.creation.cylinder(radius=35, height=90, sections=24), (220, 190, 40))
    handle = coloured(trimesh.creation.box(extents=[40, 14, 55]), (120, 40, 160))
    handle.apply_translation([50, 0, 0])
    lid = coloured(trimesh.creation.box(extents=[30, 60, 12]), (90, 90, 90))
    lid.apply_translation([0, 0, 51])
    m = trimesh.util.concatenate([body, handle, lid])
    m.apply_translation(-m.bounding_box.centroid)
    return m


@pytest.fixture(scope="session")
def tiny_bop(tmp_path_factory, renderer, l_shape) -> Path:
    """Objects 1 (L shape) and 2 (mug) side by side in N_FRAMES frames at random views, scene 2."""
    root = tmp_path_factory.mktemp("tiny_bop")
    meshes = {1: l_shape.copy(), 2: make_mug()}
    (root / "models").mkdir()
    info = {}
    for obj_id, mesh in meshes.items():
        mesh.export(root / "models" / f"obj_{obj_id:06d}.ply")
        info[str(obj_id)] = {"diameter": float(np.linalg.norm(mesh.extents))}
    (root / "models" / "models_info.json").write_text(json.dumps(info))
    scene = root / "test" / "000002"
    (scene / "rgb").mkdir(parents=True)
    rng = np.random.default_rng(1)
    gt, cams = {}, {}
    for f in range(N_FRAMES):
        placed, anns = [], []
        for obj_id, side in ((1, -0.12), (2, 0.12)):
            view = View(rng.uniform(0, 360), rng.uniform(15, 75), rng.uniform(-30, 30), rng.uniform(550, 750))
            R, t = view_to_pose(view, ray=[side, rng.uniform(-0.05, 0.05), 1.0])
            placed.append((meshes[obj_id], R, t))
            anns.append({"obj_id": obj_id, "cam_R_m2c": R.ravel().tolist(), "cam_t_m2c": t.tolist()})
        rgb, _ = renderer.render_frame(placed, K, 640, 480)
        background = np.full_like(rgb, 70)
        rgb = np.where(rgb.any(axis=2, keepdims=True), rgb, background)
        cv2.imwrite(str(scene / "rgb" / f"{f:06d}.png"), rgb[..., ::-1])
        gt[str(f)], cams[str(f)] = anns, {"cam_K": K.ravel().tolist(), "depth_scale": 1.0}
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    (scene / "scene_camera.json").write_text(json.dumps(cams))
    return root


@pytest.fixture(scope="session")
def untrained_models(tmp_path_factory) -> dict[str, Path]:
    """Untrained ONNX models: rgb, depth, and a 3-dimensional rgb one ("rgb3")."""
    torch = pytest.importorskip("torch")
    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("models")
    out = {}
    for name, modality, dim in (
        ("rgb", "rgb", 16),
        ("depth", "depth", 16),
        ("rgb3", "rgb", 3),
    ):
        net = DescriptorNet(NetConfig(modality=modality, descriptor_dim=dim))
        out[name] = export_onnx(net, folder / f"{name}.onnx", 200.0, {"note": "untrained, for tests"})
    return out
