"""What a template store holds and answers, whatever the backend: an object's record, a model's templates
of it, a search's match, and the store's errors (`index.store` is the interface, two backends:
`index.store.embedded` and `index.store.milvus`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ObjectRecord:
    """One registered object. `templates` counts its templates per model."""

    object_id: int
    name: str
    symmetry: str
    faces: int
    created: float
    templates: Mapping[str, int]
    extra: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Match:
    """A template found for a query: its object, its pose (degrees) and the descriptor distance (L2)."""

    object_id: int
    name: str
    azimuth: float
    elevation: float
    inplane: float
    distance: float


@dataclass(frozen=True)
class TemplateSet:
    """What one model adds for an object. poses: (N, 3) azimuth, elevation, in-plane; descriptors: (N, D).
    A model with local features (`index.features.embed.LOCAL_NAME`) also gives them for some templates (its
    upright ones): `local_rows` (L,) indices into poses, `local` (L, F) float16."""

    poses: np.ndarray
    descriptors: np.ndarray
    local_rows: np.ndarray | None = None
    local: np.ndarray | None = None


def local_key(object_id: int, azimuth: float, elevation: float) -> tuple[int, float, float]:
    """How a viewpoint's local features are found: object and viewpoint, to 1e-3 degrees."""
    return int(object_id), round(float(azimuth), 3), round(float(elevation), 3)


def check_set(model: str, dims: Mapping[str, int], ts: TemplateSet) -> None:
    """Raises KeyError for a model the store does not hold, ValueError for descriptors it cannot take."""
    if model not in dims:
        raise KeyError(f"unknown model {model!r}")
    d = np.asarray(ts.descriptors)
    if d.ndim != 2 or d.shape[1] != dims[model] or len(d) != len(ts.poses) or len(d) == 0:
        raise ValueError(
            f"{model}: expected (N, {dims[model]}) descriptors and N poses, got {d.shape} and {np.shape(ts.poses)}"
        )
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{model}: descriptors contain NaN or infinity")


class StoreError(RuntimeError):
    """The store cannot be used (a one-line reason)."""


class StoreUnavailable(StoreError):
    """The store's server does not answer now (down, restarting, overloaded): retry later. The service
    answers 503 with this message."""


class NameTaken(ValueError):
    """An object of this name is stored already; `object_id` is its id."""

    def __init__(self, name: str, object_id: int):
        super().__init__(f"an object named {name!r} exists already (object_id {object_id})")
        self.name, self.object_id = name, object_id
