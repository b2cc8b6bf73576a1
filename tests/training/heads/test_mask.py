"""The foreground mask: the samples' masks are their centred object's pixels, and the head learns them."""

import json

import numpy as np
import pytest
import torch

from training import augment
from training.augment import soft_edges
from training.data import DataConfig, TrainingData
from training.heads import mask as mask_module
from training.heads.mask import (
    MaskConfig,
    MaskNet,
    load_mask,
    mask_iou,
    mask_loss,
    outline_band,
    predict,
    train_mask,
)
from training.render_cache import build

pytestmark = pytest.mark.xdist_group("heads-mask")  # the module's fixture made once, on one worker;
# every test of the rendered shapes (a render cache, short trainings) is `slow`: `make test`, not `make check`


@pytest.fixture(scope="module")
def shapes() -> TrainingData:
    return build([], DataConfig(shapes=3, shape_views=20, template_inplane_step=90.0, seed=2))


@pytest.mark.slow
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


def test_soft_edges_blend_the_outline_only():
    """The blend runs the object's colour into the background along the outline and leaves what lies
    farther from it than the blur and the shift reach (6 px) as a hard composite has it."""
    rgb, background = np.full((64, 64, 3), 200, np.uint8), np.zeros((64, 64, 3), np.uint8)
    mask = np.zeros((64, 64), bool)
    mask[16:48, 20:44] = True
    hard = np.where(mask[..., None], rgb, background).astype(np.float32)
    out = soft_edges(rgb, background, mask, np.random.default_rng(0))
    band = lambda px: outline_band(torch.from_numpy(mask[None, None]).float(), px)[0, 0].numpy() > 0  # noqa: E731
    assert out.shape == hard.shape and np.abs(out - hard)[~band(6)].max() < 0.5
    assert np.abs(out - hard)[band(1)].mean() > 20.0  # of 200: the edge is smeared, not a step


@pytest.mark.slow
def test_synthetic_samples_go_through_the_soft_edges_with_their_chance(shapes, monkeypatch):
    """`soft_edges` 1: every synthetic sample is blended, 0: none; the mask is the same either way (the
    object's pixels, not how its edge looks)."""
    data, calls = shapes, []
    monkeypatch.setattr("training.data.soft_edges", lambda *a: (calls.append(1), augment.soft_edges(*a))[1])
    data.cfg.occlude, data.cfg.clutter = 0.0, 1.0
    masks: dict[float, list[np.ndarray]] = {}
    for p in (0.0, 1.0):
        data.cfg.soft_edges, before, masks[p] = p, len(calls), []
        for seed in range(4):
            sample, _ = data.draw(seed % 3, np.random.default_rng(seed), "rgb", 0.0)
            masks[p].append(data.sample_with_mask(sample, "rgb", np.random.default_rng(100 + seed))[1])
        assert len(calls) - before == (4 if p else 0)
    assert all(np.array_equal(a, b) for a, b in zip(masks[0.0], masks[1.0], strict=True))
    data.cfg.soft_edges = 0.0


def test_the_outline_weight_counts_the_outline_s_errors_more():
    """An error on the outline costs 1 + W times what it costs without the weight; one away from it the
    same. The band is 2 px either side of the outline."""
    m = torch.zeros(1, 1, 16, 16)
    m[..., 4:12, 4:12] = 1
    band = outline_band(m)
    assert band[0, 0, 8].tolist() == [0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1, 0, 0]
    right = torch.where(m > 0, 8.0, -8.0)
    on_outline, inside = right.clone(), right.clone()
    on_outline[0, 0, 8, 4] = -8.0  # a pixel of the object's outline called background
    inside[0, 0, 8, 8] = -8.0  # one well inside it
    extra = {w: (mask_loss(on_outline, m, w) - mask_loss(right, m, w)).item() for w in (0.0, 3.0)}
    assert extra[3.0] > 3.0 * extra[0.0] > 0
    away = [(mask_loss(inside, m, w) - mask_loss(right, m, w)).item() for w in (0.0, 3.0)]
    assert away[1] == pytest.approx(away[0], rel=1e-4) and away[0] > 0


@pytest.mark.slow
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
    learnt = mask_iou(predict(net, x), m).mean()
    everything = mask_iou(np.ones(m.shape), m).mean()
    assert learnt > everything + 0.15, (learnt, everything)


def test_iou_of_known_masks():
    m = np.zeros((2, 4, 4), bool)
    m[0, :2] = True
    m[1, :, :1] = True
    logits = np.where(m, 1.0, -1.0)
    logits[1, 0, 1] = 1.0  # one extra pixel: 4 / 5
    assert np.allclose(mask_iou(logits, m), [1.0, 0.8])
    assert MaskNet(pretrained=False)(torch.zeros(1, 3, 64, 64)).shape == (1, 1, 64, 64)


@pytest.mark.slow
def test_a_mask_run_interrupted_and_resumed_ends_as_an_uninterrupted_one(shapes, tmp_path, monkeypatch):
    """Ctrl-C once the first checkpoint (step 3 of 7) is written; resumed, the run ends with the head, log
    and checkpoints of the run nobody stopped, bit for bit (one thread, the schedule over steps: the
    budget is far off). The last checkpoint is step 7, not a multiple of 3: the run's end. mask-best.pt
    stays step 3 (no validation frames: every IoU is 0), which it would not were the best score lost."""
    data = shapes
    data.cfg.occlude, data.cfg.clutter = 0.3, 0.6
    cfg = MaskConfig(minutes=600.0, max_steps=7, batch=4, steps_per_epoch=3, threads=1)
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    net = train_mask(cfg, data, whole)

    # Ctrl-C as step 4 asks for its batch: deterministic, where a timer thread raced the run's end (a
    # quiet machine finished the 7 tiny steps before the interrupt arrived)
    draw, calls = mask_module._batch, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return draw(*args, **kwargs)

    monkeypatch.setattr(mask_module, "_batch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_mask(cfg, data, stopped)
    monkeypatch.setattr(mask_module, "_batch", draw)
    assert load_mask(stopped, "last")[1]["step"] == 3
    again = train_mask(cfg, data, stopped, resume=True)

    for k, v in net.head.state_dict().items():
        assert torch.equal(v, again.head.state_dict()[k]), k

    def lines(run) -> list[dict]:
        return [
            {k: v for k, v in json.loads(s).items() if k != "minutes"} for s in open(run / "mask-log.jsonl")
        ]

    assert lines(stopped) == lines(whole) and [r["step"] for r in lines(whole)] == [3, 6, 7]
    for run in (whole, stopped):
        assert (load_mask(run, "last")[1]["step"], load_mask(run, "best")[1]["step"]) == (7, 3)
    with pytest.raises(ValueError, match="whole budget"):
        train_mask(cfg, data, stopped, resume=True)
    with pytest.raises(ValueError, match="batch: was 4, now 8"):
        train_mask(MaskConfig(**{**cfg.__dict__, "batch": 8, "max_steps": 9}), data, stopped, resume=True)


@pytest.mark.slow
def test_a_fine_tuned_mask_head_trains_and_keeps_its_own_trunk(shapes, tmp_path):
    """`finetune` > 0: the head's trunk copy and later stages move (at the scaled rate), the checkpoint
    keeps the copy and `load_mask` gives it back; frozen (0), the trunk stays ImageNet's."""
    data = shapes
    cfg = MaskConfig(minutes=600.0, max_steps=2, batch=4, steps_per_epoch=2, threads=1, finetune=0.1)
    net = train_mask(cfg, data, tmp_path / "ft")
    imagenet = MaskNet()
    moved = [k for k, v in net.stem.state_dict().items() if not torch.equal(v, imagenet.stem.state_dict()[k])]
    assert moved and net.own_stem
    back, state = load_mask(tmp_path / "ft", "last")
    assert back.own_stem and "stem" in state
    for k, v in net.stem.state_dict().items():
        assert torch.equal(v, back.stem.state_dict()[k]), k
    frozen = train_mask(MaskConfig(**{**cfg.__dict__, "finetune": 0.0}), data, tmp_path / "frozen")
    for k, v in frozen.stem.state_dict().items():
        assert torch.equal(v, imagenet.stem.state_dict()[k]), k
    assert "stem" not in load_mask(tmp_path / "frozen", "last")[1]
