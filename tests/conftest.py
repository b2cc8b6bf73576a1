"""Shared fixtures: small meshes the tests make themselves, one renderer, the real data when present. The
helpers the tests share (a real server, a browser) are modules of tests/helpers/, put on the path here."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

SHARED_LMO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lmo"
sys.path.insert(0, str(Path(__file__).parent / "helpers"))


def coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(
        mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1))
    )
    return mesh


def make_l_shape() -> trimesh.Trimesh:
    """An asymmetric, three-coloured object about 120 mm across, origin at its middle."""
    a = coloured(trimesh.creation.box(extents=[120, 30, 30]), (200, 40, 40))
    b = coloured(trimesh.creation.box(extents=[30, 80, 30]), (40, 180, 60))
    b.apply_translation([45, 55, 0])
    c = coloured(trimesh.creation.cylinder(radius=12, height=70), (40, 60, 200))
    c.apply_translation([-45, 0, 50])
    m = trimesh.util.concatenate([a, b, c])
    m.apply_translation(-m.bounding_box.centroid)
    return m


@pytest.fixture(scope="session")
def l_shape() -> trimesh.Trimesh:
    return make_l_shape()


@pytest.fixture(scope="session")
def t_shape() -> trimesh.Trimesh:
    from service_helpers import make_t_shape

    return make_t_shape()


@pytest.fixture(scope="session")
def renderer():
    from index.templates.render import Renderer

    r = Renderer()
    yield r
    r.close()


@pytest.fixture(scope="session")
def lmo() -> Path:
    if not (SHARED_LMO / "models" / "models_info.json").is_file():
        pytest.skip(f"real data not present at {SHARED_LMO}")
    return SHARED_LMO


@pytest.fixture(scope="session")
def posedesc_models(tmp_path_factory) -> Path:
    """A models folder as the service expects it: untrained posedesc-{rgb,depth,rgbd}.onnx (16-d)."""
    torch = pytest.importorskip("torch")
    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("posedesc-models")
    for modality in ("rgb", "depth", "rgbd"):
        net = DescriptorNet(NetConfig(modality=modality))
        export_onnx(net, folder / f"posedesc-{modality}.onnx", 200.0, {"note": "untrained, for tests"})
    return folder


@pytest.fixture(scope="session")
def render_worker():
    """One render thread for the whole session (EGL: one context per thread)."""
    from index.templates.render import RenderWorker

    worker = RenderWorker()
    yield worker
    worker.close()


@pytest.fixture(scope="session")
def milvus(tmp_path_factory):
    """The real standalone Milvus server (PyPI `milvus` 2.3.5), started once per session of tests on free
    loopback ports in a temporary directory, stopped at the end. Tests keep apart by collection prefix."""
    pytest.importorskip("milvus")
    from benchmarks.stores.milvus_server import LocalMilvus

    server = LocalMilvus(tmp_path_factory.mktemp("milvus"))
    server.start()
    yield server
    server.stop()
