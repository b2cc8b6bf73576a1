"""The foreground mask: the samples' masks are their centred object's pixels, and the head learns them."""

import numpy as np
import pytest
import torch

from training.data import DataConfig, TrainingData
from training.mask import MaskConfig, MaskNet, iou, predict, train_mask
from training.render_cache import build


@pytest.fixture(scope="module")
def shapes() -> TrainingData:
    return build([], DataConfig(shapes=3, shape_views=20, template_inplane_step=90.0, seed=2))


def test_a_synthetic_sample_masks_its_own_object_only(shapes):
    """The mask is the sample's render less what an occluder hides: inside the object's silhouette,
    never the background, clutter or occluder that the composite adds around it."""
    data, rng = shapes, np.random.default_rng(0)
    data.cfg.occlude, data.cfg.clutter = 1.0, 1.0
    hidden = 0
    for _ in range(20):
        sample, _ = data.draw(0, rng, "rgb", 0.0)
        x, mask = data.sample_with_mask(sample, "rgb", rng)
        silhouette = data.s_depth[sample[1]] > 0
        assert x.shape == (3, 64, 64) and mask.shape == (64, 64) and mask.dtype == bool
        assert mask.any() and not (mask & ~silhouette).any()
        hidden += int((silhouette & ~mask).sum())
    assert hidden > 0  # occluders hid some of the object in some samples


def test_the_head_learns_masks_and_iou_measures_them(shapes, tmp_path):
    """A few minutes' budget cut to 60 steps: the validation-free run still writes its checkpoint, and
    the head's masks on fresh samples overlap the true ones far better than an all-object guess."""
    data, rng = shapes, np.random.default_rng(1)
    data.cfg.occlude, data.cfg.clutter = 0.3, 0.6
    net = train_mask(MaskConfig(max_steps=60, batch=32, steps_per_epoch=60, threads=1), data, tmp_path)
    assert (tmp_path / "mask.pt").is_file()
    xs, ms = zip(
        *(data.sample_with_mask(data.draw(o % 3, rng, "rgb", 0.0)[0], "rgb", rng) for o in range(48)),
        strict=True,
    )
    x, m = np.stack(xs), np.stack(ms)
    learnt = iou(predict(net, x), m).mean()
    everything = iou(np.ones(m.shape), m).mean()
    assert learnt > everything + 0.15, (learnt, everything)


def test_iou_of_known_masks():
    m = np.zeros((2, 4, 4), bool)
    m[0, :2] = True
    m[1, :, :1] = True
    logits = np.where(m, 1.0, -1.0)
    logits[1, 0, 1] = 1.0  # one extra pixel: 4 / 5
    assert np.allclose(iou(logits, m), [1.0, 0.8])
    assert MaskNet(pretrained=False)(torch.zeros(1, 3, 64, 64)).shape == (1, 1, 64, 64)
