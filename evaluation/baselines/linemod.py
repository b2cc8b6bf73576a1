"""LineMOD baseline: OpenCV's `cv2.linemod` (Hinterstoisser et al.), colour gradients and, with depth,
surface normals from depth, on the same template renders and test patches as our descriptor.

Settings for 64x64 patches (LineMOD's defaults are for 640x480 frames):
- two pyramid levels with T = 4 and 8 px (defaults 5 and 8): a 64 px patch holds about 16 x 16 cells of 4;
- 32 colour-gradient features (weak/strong magnitude thresholds 10 / 55) and 24 depth-normal features
  (difference threshold 50 mm, extraction distance 2 px; depth shifted, see `depth_ref_mm`) instead of
  LineMOD's 63 each: an object fills a quarter to a half of a 64 px patch, and with 63 features LineMOD
  found too few candidates on 4% (colour) and 25% (depth) of the LM-O ape and eggbox templates
  (with 32 / 24: none and 1%);
- every image is padded to 160 x 160 (centred): OpenCV needs sides divisible by T at every level and its
  SIMD spreading crashes unless the row width at every pyramid level is a multiple of 16 bytes
  (opencv/opencv#29559), so 80 x 80 is not enough.

A test patch is cut at the object's true centre, as every template is, so a template is scored where it
sits in its own image: its similarity to a patch is the best LineMOD score (percent, above `threshold`)
at positions within one grid step (T = 4 px) of that place, and templates that match only elsewhere are
not retrieved. Scored anywhere in the padded image, a few of a template's 24 normals fit some other part
of almost any patch: on synthetic LM-O depth patches a median of 34 templates tied at the top score, and
the first retrieved template was of the right object for 28% of the patches; scored in place, 69% (colour
on real held-out frames: 30% and 60%). Ties between equal scores go to the template matched nearer its
own place (0.01 is taken off per pixel away, less than one step of LineMOD's score). Every template is
its own LineMOD class: `Detector.match` drops matches of one class at the same position and score as
duplicates (`Match ==` ignores the template id), which silently lost templates of the same object that
tied. A template from which LineMOD cannot extract enough features (a nearly featureless view) is not
added; `skipped` counts them. `rank` is the method's adapter."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import cv2
import numpy as np

from evaluation.paper.neighbours import Ranking

if TYPE_CHECKING:
    from evaluation.paper.samples import Samples
    from evaluation.paper.templates import RenderedTemplates
    from index.features.embed import Embedder


PAD = 160
T_PYRAMID = (4, 8)
COLOUR_FEATURES = 32
DEPTH_FEATURES = 24
LINEMOD_FOCAL_PX = 1150.0  # the focal length hard-coded in cv2.linemod's normals ("magic number 1150")
TIE_BREAK_PER_PX = 0.01  # similarity taken off per pixel between a match and the template's own place


def _pad(img: np.ndarray) -> np.ndarray:
    out = np.zeros((PAD, PAD, *img.shape[2:]), img.dtype)
    o = (PAD - img.shape[0]) // 2
    out[o : o + img.shape[0], o : o + img.shape[1]] = img
    return out


class LineModIndex:
    """Templates of several objects in one LineMOD detector; `search` ranks them for a test patch."""

    def __init__(
        self,
        modality: str,
        window_mm: float,
        size: int = 64,
        threshold: float = 50.0,
        features: tuple[int, int] = (COLOUR_FEATURES, DEPTH_FEATURES),
    ):
        """`features`: how many colour-gradient and depth-normal features a template has."""
        self.modality = modality
        self.threshold = threshold
        mods: list[cv2.linemod.Modality] = []
        if modality in ("rgb", "rgbd"):
            mods.append(cv2.linemod.ColorGradient.create(10.0, features[0], 55.0))
        if modality in ("depth", "rgbd"):
            mods.append(cv2.linemod.DepthNormal.create(10_000, 50, features[1], 2))
        self.detector = cv2.linemod.Detector(mods, list(T_PYRAMID))
        # LineMOD computes normals from depth with a fixed focal length in mind, but a patch's pixel spans
        # window/size mm whatever the object's distance. Shifting every patch's depth so the object
        # sits at focal * window / size makes LineMOD's idea of a pixel's width the true one, the same
        # for templates (400 mm) and test patches (any distance).
        self.depth_ref_mm = LINEMOD_FOCAL_PX * window_mm / size
        self._index: dict[str, int] = {}  # LineMOD class id (one per template) -> our index
        self._place: dict[str, tuple[int, int]] = {}  # class id -> the template's top-left in its image
        self._count = 0  # templates offered so far: indices continue across calls to `add`
        self.skipped = 0

    def _sources(
        self, rgb: np.ndarray | None, depth: np.ndarray | None, nominal_mm: float
    ) -> list[np.ndarray]:
        sources = []
        if self.modality in ("rgb", "rgbd"):
            sources.append(_pad(np.ascontiguousarray(rgb[..., ::-1])))  # type: ignore[index]  # BGR
        if self.modality in ("depth", "rgbd"):
            d = np.where(depth > 0, depth - nominal_mm + self.depth_ref_mm, 0.0)  # type: ignore[operator]
            sources.append(_pad(np.clip(d, 0, 65535).astype(np.uint16)))
        return sources

    def add(
        self,
        obj_ids: np.ndarray,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        mask: np.ndarray,
        nominal_mm: float | np.ndarray,
        progress: Callable[[int], object] | None = None,
    ) -> None:
        """Adds T templates: rgb (T, S, S, 3), depth (T, S, S) mm, mask (T, S, S); `nominal_mm`: their
        render distance. Our indices are 0..T-1 on the first call and continue from there on later ones."""
        nominal = np.broadcast_to(np.asarray(nominal_mm, dtype=float), (len(obj_ids),))
        for i in range(len(obj_ids)):
            class_id = f"obj_{int(obj_ids[i])}/{self._count + i}"
            sources = self._sources(
                None if rgb is None else rgb[i], None if depth is None else depth[i], float(nominal[i])
            )
            tid, box = self.detector.addTemplate(sources, class_id, _pad(mask[i].astype(np.uint8) * 255))
            if tid < 0:
                self.skipped += 1
            else:
                self._index[class_id] = self._count + i
                self._place[class_id] = (box[0], box[1])
            if progress and (i + 1) % 100 == 0:
                progress(100)
        self._count += len(obj_ids)
        if progress:
            progress(len(obj_ids) % 100)

    def placed(self, class_id: str) -> tuple[int, tuple[int, int]]:
        """A LineMOD class's template: our index, and the top-left of its features in its padded image
        (where a match's x, y lands: the padded image's centre is the template's centre)."""
        return self._index[class_id], self._place[class_id]

    def similarities(
        self, rgb: np.ndarray | None, depth: np.ndarray | None, nominal_mm: float
    ) -> dict[int, float]:
        """Best similarity (percent) of every template that matches above the threshold in its own place
        (see the module's docstring), less the tie-break, by our index. `nominal_mm`: the object's
        distance (the patch's depth is shifted, see `depth_ref_mm`)."""
        matches, _ = self.detector.match(self._sources(rgb, depth, nominal_mm), self.threshold)
        best: dict[int, float] = {}
        for m in matches:
            x, y = self._place[m.class_id]
            dx, dy = abs(m.x - x), abs(m.y - y)
            if max(dx, dy) > T_PYRAMID[0]:
                continue
            i = self._index[m.class_id]
            best[i] = max(best.get(i, -1.0), m.similarity - TIE_BREAK_PER_PX * (dx + dy))
        return best


def top_k(similarities: dict[int, float], k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k most similar templates: (indices (k,), -1 = none; similarities (k,) percent, 0 = none)."""
    ranked = sorted(similarities.items(), key=lambda kv: -kv[1])[:k]
    idx, sim = np.full(k, -1, int), np.zeros(k)
    for j, (i, s) in enumerate(ranked):
        idx[j], sim[j] = i, s
    return idx, sim


def rank(
    embedder: Embedder,
    templates: RenderedTemplates,
    samples: Samples,
    n: int,
    threshold: float = 50.0,
    progress: Callable[[int], object] | None = None,
) -> Ranking:
    """The n most similar templates of every test patch by LineMOD; scores are 100 - similarity.
    `progress` counts templates added, then patches matched."""
    t, s, spec = templates, samples, embedder.info.spec
    index = LineModIndex(embedder.modality, spec.window_mm, spec.size, threshold)
    index.add(t.obj_ids, t.rgb, t.depth, t.mask, np.array([v.distance for v in t.views]), progress=progress)
    notes = []
    if index.skipped:
        notes.append(
            f"LineMOD could not extract enough features from {index.skipped} of {len(t)} templates; "
            "they are missing from its template set"
        )
    sims = []
    for i in range(len(s)):
        rgb, depth = None if s.rgb is None else s.rgb[i], None if s.depth is None else s.depth[i]
        sims.append(index.similarities(rgb, depth, float(s.distances[i])))
        if progress:
            progress(1)
    ranked = [top_k(sim, n) for sim in sims]
    neighbours = np.stack([r[0] for r in ranked]).reshape(len(s), -1)
    scores = np.where(neighbours >= 0, 100.0 - np.stack([r[1] for r in ranked]).reshape(len(s), -1), np.nan)

    def lookup(i: int, idx: np.ndarray) -> np.ndarray:
        return np.array([100.0 - sims[i].get(int(j), np.nan) for j in idx])

    return Ranking(neighbours, scores, _separation(sims, t.obj_ids, s.obj_ids), lookup, notes=notes)


def _separation(sims: list[dict[int, float]], template_obj: np.ndarray, sample_obj: np.ndarray) -> np.ndarray:
    """Nearest other-object over nearest same-object template, with 100 - similarity as the distance,
    over the templates that matched (nan: undefined)."""
    out = np.full(len(sims), np.nan)
    for i, s in enumerate(sims):
        own = [100.0 - v for t, v in s.items() if template_obj[t] == sample_obj[i]]
        other = [100.0 - v for t, v in s.items() if template_obj[t] != sample_obj[i]]
        if own and other and min(own) > 0:
            out[i] = min(other) / min(own)
    return out
