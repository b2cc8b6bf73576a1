"""Each object's patch window: a class of a fixed ladder chosen from its size at registration, so that every
object fills its patch about the same way, from 20 mm to 2 m.

A model is trained with one metric window (`index.features.embed.ModelInfo.window_mm`, 200 mm for the shipped ones)
on objects that filled it between about a half (LM-O's ape, 102 mm across) and 1.31 times (the driller,
262 mm).
An object's window is the model's times sqrt(2)^k, the k nearest 0 whose window the object fills between
`FILL_LOW` and `FILL_HIGH` of its side (diameter / window): the LM-O objects keep the model's window
(k = 0), a 25 mm part goes down four classes (50 mm, 0.5), a 1.5 m one up five (1131 mm, 1.33). The band
spans more than a step (2.8 against 1.41), so every size has a class.

The window is stored with the object's record (`extra["window_mm"]`, mm; its diameter as
`extra["diameter_mm"]`): its templates are rendered through it (at a distance scaled with it, so the
perspective is the same), its depth normalised by it, its relief's clip and surface offsets measured in it;
a query with a centre is cut once per class among the registered objects (`service.pipeline`). An object
registered before this has none and keeps the model's window. Everything in millimetres that assumed the
model's window (the depth normalisation, the relief clip, the depth-unit checks) scales with the class.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from index.store.records import ObjectRecord

#: an object record's `extra` keys: its window's side and its diameter, mm
WINDOW_KEY = "window_mm"
DIAMETER_KEY = "diameter_mm"

#: the ladder's step: neighbouring classes' windows differ by this factor
STEP = math.sqrt(2.0)
# The band an object's diameter is kept in, in windows. FILL_LOW: just under the ape's 0.51 (the smallest
# LM-O object, recognised 80-94 % like the rest at the 200 mm window). FILL_HIGH: over the driller's 1.31,
# measured (docs/windows.md): through its own 283 mm window the shipped rgb model, trained through 200 mm
# only, named it 68 % of the time on validation frames against 84 % through 200 mm (others' mean 84 %)
FILL_LOW, FILL_HIGH = 0.5, 1.4


def window_class(diameter_mm: float, model_window_mm: float) -> float:
    """The window (mm) of an object `diameter_mm` across: the model's times sqrt(2)^k for the k nearest 0
    (the model's own first) that the object fills between `FILL_LOW` and `FILL_HIGH` of."""
    fill = diameter_mm / model_window_mm
    if fill > FILL_HIGH:  # the fewest steps up that bring it under FILL_HIGH
        k = math.ceil(2 * math.log2(fill / FILL_HIGH) - 1e-9)
    elif fill < FILL_LOW:  # the fewest steps down that bring it over FILL_LOW
        k = -math.ceil(2 * math.log2(FILL_LOW / fill) - 1e-9)
    else:
        k = 0
    return window_of_step(k, model_window_mm)


def window_of_step(k: int, model_window_mm: float) -> float:
    """The model's window times sqrt(2)^k, to 0.01 mm (stored as JSON, compared as read back)."""
    return float(model_window_mm) if k == 0 else round(model_window_mm * STEP**k, 2)


def object_window(extra: Mapping[str, object], model_window_mm: float) -> float:
    """An object's window (mm): the one stored at its registration, the model's for an object without."""
    w = extra.get(WINDOW_KEY)
    return float(w) if isinstance(w, (int, float)) and w > 0 else float(model_window_mm)


def object_diameter(extra: Mapping[str, object]) -> float | None:
    """An object's diameter (mm) as stored at its registration; None for an object registered without."""
    d = extra.get(DIAMETER_KEY)
    return float(d) if isinstance(d, (int, float)) and d > 0 else None


def window_classes(
    objects: Mapping[int, ObjectRecord], model_window_mm: float
) -> dict[float, frozenset[int]]:
    """The objects by window, the model's window first, then the others nearest it (by ratio) first."""
    by: dict[float, set[int]] = {}
    for oid, rec in objects.items():
        by.setdefault(object_window(rec.extra, model_window_mm), set()).add(oid)
    order = sorted(by, key=lambda w: (abs(math.log(w / model_window_mm)), w))
    return {w: frozenset(by[w]) for w in order}


def size_classes(objects: Mapping[int, ObjectRecord], ratio: float = 1.25) -> dict[float, frozenset[int]]:
    """The objects with a stored diameter grouped so that each group's largest is at most `ratio` times its
    smallest, keyed by the group's geometric mean diameter (mm), smallest first."""
    sized = sorted((d, oid) for oid, rec in objects.items() if (d := object_diameter(rec.extra)) is not None)
    groups: list[list[tuple[float, int]]] = []
    for d, oid in sized:
        if groups and d <= groups[-1][0][0] * ratio:
            groups[-1].append((d, oid))
        else:
            groups.append([(d, oid)])
    return {round(math.sqrt(g[0][0] * g[-1][0]), 2): frozenset(oid for _, oid in g) for g in groups}
