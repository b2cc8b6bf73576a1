"""Descriptor throughput: our network on onnxruntime at batch 1 and 256, against HOG on the same patches.

Both start from the same real-looking patches and make the same network input first
(`index.features.patches.batch_inputs`: per-channel normalisation, depth filled and normalised). "From the patch"
includes that step: ours is `Embedder.embed_patches`, HOG the evaluation's `evaluation.baselines.hog.hog_descriptors`
(OpenCV, one patch at a time: it has no batch mode). "Descriptor only" starts from inputs made
beforehand: onnxruntime against `evaluation.baselines.hog.describe_inputs`."""

from __future__ import annotations

from dataclasses import dataclass

from benchmarks.objects import ObjectSet
from benchmarks.timing import measure, ratio
from index.features.embed import Embedder
from index.features.patches import batch_inputs


@dataclass(frozen=True)
class DescriptorConfig:
    patches: int = 512  # patches per timed pass at batch 256 and for HOG
    patches_b1: int = 256  # patches per timed pass at batch 1 (one session call each)
    repeats: int = 5


def run(objects: ObjectSet, embedder: Embedder, cfg: DescriptorConfig) -> dict:
    from evaluation.baselines.hog import describe_inputs, hog_descriptor, hog_descriptors

    modality, window = embedder.modality, embedder.info.window_mm
    all_rgb, all_depth = objects.patches(cfg.patches)
    rgb = all_rgb if modality in ("rgb", "rgbd") else None
    depth = all_depth if modality in ("depth", "rgbd") else None
    nominal = 400.0
    x = batch_inputs(modality, rgb, depth, nominal, window, fill=True)
    n, n1 = len(x), min(cfg.patches_b1, len(x))

    def one_by_one(fn) -> None:
        for i in range(n1):
            fn(i)

    onnx_b1 = measure(lambda: one_by_one(lambda i: embedder(x[i : i + 1])), cfg.repeats)
    onnx_b256 = measure(lambda: embedder(x, batch=256), cfg.repeats)
    ours_b1 = measure(
        lambda: one_by_one(
            lambda i: embedder.embed_patches(
                None if rgb is None else rgb[i : i + 1], None if depth is None else depth[i : i + 1], nominal
            )
        ),
        cfg.repeats,
    )

    def ours_batched() -> None:
        for lo in range(0, n, 256):
            embedder.embed_patches(
                None if rgb is None else rgb[lo : lo + 256],
                None if depth is None else depth[lo : lo + 256],
                nominal,
            )

    ours_b256 = measure(ours_batched, cfg.repeats)
    hog = measure(lambda: hog_descriptors(modality, rgb, depth, nominal, window, True), cfg.repeats)
    cv_hog = hog_descriptor()
    hog_only = measure(lambda: describe_inputs(x, cv_hog), cfg.repeats)
    out: dict = {
        "modality": modality,
        "patches": n,
        "patches_b1": n1,
        "repeats": cfg.repeats,
        "onnx_b1_patches_per_s": n1 / onnx_b1.median,
        "onnx_b256_patches_per_s": n / onnx_b256.median,
        "ours_b1_patches_per_s": n1 / ours_b1.median,
        "ours_b256_patches_per_s": n / ours_b256.median,
        "hog_patches_per_s": n / hog.median,
        "hog_only_patches_per_s": n / hog_only.median,
        "descriptor_bytes": {"ours": embedder.dim * 4, "hog": int(x.shape[1]) * 1764 * 2},
    }
    out["onnx_vs_hog_ratio_b1"] = ratio(out["onnx_b1_patches_per_s"], out["hog_only_patches_per_s"])
    out["onnx_vs_hog_ratio_b256"] = ratio(out["onnx_b256_patches_per_s"], out["hog_only_patches_per_s"])
    out["ours_vs_hog_throughput_ratio_b1"] = ratio(out["ours_b1_patches_per_s"], out["hog_patches_per_s"])
    out["ours_vs_hog_throughput_ratio_b256"] = ratio(out["ours_b256_patches_per_s"], out["hog_patches_per_s"])
    return out
