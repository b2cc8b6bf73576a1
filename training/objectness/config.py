"""The objectness network's training settings (`ObjectnessConfig`) and the constants its data and model share."""

from __future__ import annotations

from dataclasses import dataclass

from index.features.objectness import WINDOW_MM

IMAGENET_MEAN = (0.485, 0.456, 0.406)


IMAGENET_STD = (0.229, 0.224, 0.225)


STRIDE = 8


RENDER_SIZE = 128  # shape renders: 128 px over 400 mm, so the 200 mm window spans RENDER_WINDOW px


RENDER_WINDOW_MM = 400.0


RENDER_WINDOW = RENDER_SIZE * WINDOW_MM / RENDER_WINDOW_MM


RENDER_DISTANCE = 1000.0  # mm: LM-O's objects stand 0.35-1.5 m from the camera (median 1.0 m)


@dataclass
class ObjectnessConfig:
    reference_px: float = 64.0  # the window (px at a level) the head is centred on
    positive_px: tuple[float, float] = (40.0, 100.0)  # windows trained as targets (a level's range)
    ignore_px: tuple[float, float] = (30.0, 135.0)  # between these and positive_px: neither
    sample_px: tuple[float, float] = (26.0, 150.0)  # a sample's focus object is scaled into this range
    levels: tuple[float, ...] = (1.0, 0.7071, 0.5, 0.3536, 0.25)  # half-octaves: windows 40-400 px
    min_visib: float = 0.4  # less visible annotated objects are neither target nor background
    sigma: float = 0.8  # the heatmap's Gaussian, cells, for a reference_px window (scales with it)
    crop: int = 192  # training crop side (px at the level)
    batch: int = 16
    width: int = 64  # head channels
    lr: float = 2e-3  # AdamW, cosine decay to lr_end * lr over the budget
    lr_end: float = 0.05
    minutes: float = 35.0  # the optimisation's wall-clock budget
    val_every: int = 400  # steps between validations (and checkpoints)
    shapes: int = 240  # procedural shapes rendered for pasting (~10 a second)
    shape_views: int = 16  # renders of each, random poses and lights
    paste: tuple[int, int] = (0, 4)  # shapes pasted into a sample (uniform, inclusive)
    paste_px: tuple[float, float] = (30.0, 120.0)  # their windows at the crop's scale
    scale_weight: float = 2.0  # of the log window's L1, against the offset's
    seed: int = 0
    #: what the real frames' cells outside their annotated objects teach: "negative" (background: every
    #: object nobody annotated, too) or "ignore" (nothing: only the annotated and pasted objects and their
    #: surroundings are scored there; background is taught by `scrambled` crops)
    background: str = "negative"
    scrambled: float = (
        0.0  # share of crops whose real content is shuffled in tiles: background, every cell scored
    )
    #: objects treated as never seen: their annotations removed and their pixels neither target nor background
    holdout: tuple[int, ...] = ()
    #: what is pasted: "shapes" (`cfg.shapes` procedural shapes) or "catalogue" (pybullet's 1,000
    #: `random_urdfs`, then procedural shapes up to `cfg.shapes` objects: `training/objectness/catalogue.py`)
    objects: str = "shapes"
    #: the frames' annotated objects: "target" (learned as objects) or "held" (every one neither target nor
    #: background, as `holdout` for all: the network never learns the dataset's objects)
    real_objects: str = "target"
    #: share of pastes that are background: a render's silhouette filled with another part of the crop
    #: (a pasted outline alone is not an object)
    negative_paste: float = 0.0
    #: share of catalogue objects coloured from a photograph (the train frames outside their annotated
    #: objects' boxes) instead of painted
    photo_share: float = 0.0
    #: share of pastes whose colours are pulled part of the way (up to 40 %) to the mean of what they cover
    harmonise: float = 0.0
    #: what picks the checkpoint: "window" (the recall with the window read from the network) or "extent"
    #: (the window read from the extent and the object's true diameter, as the service reads it)
    select_by: str = "window"
