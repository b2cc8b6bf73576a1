"""Contact sheets: every template of an object on one PNG a person can look at."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from index.templates.render import Templates


def depth_to_colour(depth: np.ndarray) -> np.ndarray:
    """Depth (H, W) mm -> (H, W, 3) uint8 RGB: near is warm, far is cool, empty is black."""
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if valid.any():
        lo, hi = np.percentile(depth[valid], [1, 99])
        t = np.clip((depth - lo) / max(hi - lo, 1e-3), 0, 1)
        col = cv2.applyColorMap((255 * (1 - t)).astype(np.uint8), cv2.COLORMAP_TURBO)
        out[valid] = col[valid][:, ::-1]
    return out


def contact_sheet(templates: Templates, path: str | Path, columns: int = 25, title: str = "") -> Path:
    """Writes a PNG: for each template its RGB above its depth, `columns` templates a row."""
    n, s = len(templates.views), templates.rgb.shape[1]
    rows = int(np.ceil(n / columns))
    head = 28 if title else 0
    sheet = np.full((head + rows * 2 * s, columns * s, 3), 40, np.uint8)
    for i in range(n):
        r, c = divmod(i, columns)
        y, x = head + r * 2 * s, c * s
        sheet[y : y + s, x : x + s] = templates.rgb[i]
        sheet[y + s : y + 2 * s, x : x + s] = depth_to_colour(templates.depth[i])
    if title:
        cv2.putText(sheet, title, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (230, 230, 230), 1, cv2.LINE_AA)
    path = Path(path)
    cv2.imwrite(str(path), sheet[..., ::-1])
    return path
