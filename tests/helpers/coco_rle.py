"""COCO's compressed RLE read back, written from pycocotools' `rleFrString` and `rleDecode` (the spec the
service's `service.detection.mask.rle` writes to): the tests read masks with it."""

from __future__ import annotations

import numpy as np


def decode(m: dict) -> np.ndarray:
    """COCO's compressed RLE -> boolean mask (H, W): pycocotools' `rleFrString`, then the runs."""
    s, counts = m["counts"], []
    p = 0
    while p < len(s):
        x, k, more = 0, 0, True
        while more:
            c = ord(s[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and c & 0x10:
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    h, w = m["size"]
    flat = np.zeros(h * w, bool)
    at, value = 0, False
    for n in counts:
        flat[at : at + n] = value
        at, value = at + n, not value
    assert at == h * w, "the runs cover the mask exactly"
    return flat.reshape(w, h).T
