"""training/objectness/catalogue.py and the samples made of it: pybullet's random_urdfs loaded, painted and
sized; with every real object held, a crop's targets are its pasted objects only, and a decoy (an outline
filled with the crop itself) is scored as background."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet_data")

from index.templates.mesh import diameter  # noqa: E402
from training.objectness.catalogue import catalogue, catalogue_object  # noqa: E402
from training.objectness.config import RENDER_SIZE, ObjectnessConfig  # noqa: E402
from training.objectness.samples import HELD, Frame, make_sample  # noqa: E402


def test_the_catalogue_is_the_thousand_random_urdfs_then_procedural_shapes() -> None:
    paths = catalogue()
    assert len(paths) == 1000 and all(p.suffix == ".obj" for p in paths)
    rng = np.random.default_rng(0)
    for i in (0, 500, 999):
        mesh = catalogue_object(paths, i, rng, diameter_mm=(50.0, 60.0))
        assert 49.0 < diameter(mesh) < 61.0 and np.abs(mesh.bounding_box.centroid).max() < 1e-6 * 60
        colours = mesh.visual.vertex_colors[:, :3]
        assert len(mesh.faces) >= 400 and colours.std() > 0  # painted, not the default grey
    past = catalogue_object(paths, 1000, rng, diameter_mm=(50.0, 60.0))  # past the end: a shape
    assert 49.0 < diameter(past) < 61.0
    assert catalogue_object(paths[:0], 0, rng).faces.shape[0] > 0


def test_with_every_real_object_held_only_pastes_are_targets_and_decoys_are_background() -> None:
    rng = np.random.default_rng(3)
    s = RENDER_SIZE
    mask = np.zeros((1, s, s), bool)
    mask[0, s // 4 : 3 * s // 4, s // 4 : 3 * s // 4] = True
    shapes = {
        "rgb": np.full((1, s, s, 3), 200, np.uint8),
        "mask": mask,
        "extent": np.array([40.0], np.float32),
    }
    rgb = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    # one real object, fully visible, at the frame's centre: held, never a target
    frame = Frame(1, rgb, np.array([[320.0, 240.0, 64.0, 50.0, 1.0]]), np.array([100.0]), np.array([1]))
    real_only = ObjectnessConfig(real_objects="held", paste=(0, 0), background="ignore")
    for _ in range(10):
        sample = make_sample([frame], shapes, real_only, rng)
        assert sample.heat.max() == 0  # nothing is learned of the real object
    pasted = ObjectnessConfig(real_objects="held", paste=(3, 3), negative_paste=0.0, background="ignore")
    decoys = ObjectnessConfig(real_objects="held", paste=(3, 3), negative_paste=1.0, background="ignore")
    assert any(make_sample([frame], shapes, pasted, rng).heat.max() == 1.0 for _ in range(10))
    for _ in range(10):
        sample = make_sample([frame], shapes, decoys, rng)
        assert sample.heat.max() == 0  # a decoy is no object
    # yet its cells are scored (background), where the unlabelled real frame is not
    scored = [make_sample([frame], shapes, decoys, rng).weight.sum() for _ in range(10)]
    unscored = [make_sample([frame], shapes, real_only, rng).weight.sum() for _ in range(10)]
    assert np.mean(scored) > np.mean(unscored)
    assert HELD == 2 and Path(catalogue()[0]).is_file()
