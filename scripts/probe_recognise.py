"""Where the time of a real query goes, and what it answers, among as many objects as a user registers.

    PYTHONPATH=. .venv/bin/python scripts/probe_recognise.py --dataset ../shared/data/lmo \
        --frames val --distractors 93 --data-dir runs/probe-100 --settings '{"index_kind": "flat"}' \
        --json docs/results/probe-val-100-flat.json

The dataset's objects are registered through the service's registration (`evaluation.served`), then
`--distractors` more objects (the benchmarks' procedural shapes through exact image transforms, with the
model's in-plane templates: `benchmarks.objects.inplane_template_sets`) are added to the same store, so
the search runs over as many templates as a user's collection of that size. Each real instance of the
frames (the model's `split_frames`: "val", "test"; or "all") is then sent to `service.recognition.
recognise` as a user sends it (`evaluation.queries.query`: the frame as its file, the camera, the centre and
the distance), one at a time on one thread. Printed and written: the share within 5 / 20 / 40 deg (3-D),
right object and viewing direction within 20 deg at k = 1 (as `posedesc evaluate --protocol service`),
the median milliseconds of each stage the service reports, and each query's best answer and errors (so
two settings can be compared answer by answer: `--compare OTHER.json`; its `paired` entry gives the
difference of each figure with a 95 % interval that resamples instances, not queries).

`--rolls 0,72,144,216,288` sends every frame again at each camera roll (`evaluation.rolls`: the frame
turned about the principal point, the poses with it): five queries an instance instead of one, a yardstick
that can separate set-ups 115 instances cannot (`by_roll` gives each roll's figures).

`--k N` asks for N answers a query (more than the service's default cap of 100 raises it): `among_k` and
each query's `reach` say whether any of them is within 20 deg (3-D; viewing direction), what the
re-ranking could have put first (`scripts/by_visibility.py` splits it by how much of the object shows).

`--data-dir` keeps the store between runs (made once; the objects are not registered again), so settings
(`--settings`, fields of `service.settings.Settings`) can be tried in turn on the same templates. It is a
measuring tool for choices made on validation frames; the figures of record are `posedesc evaluate`'s.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.config import Config  # noqa: E402
from evaluation.masks import visible_masks  # noqa: E402
from evaluation.paper import ours  # noqa: E402
from evaluation.paper.metric import K_MAX  # noqa: E402
from evaluation.paper.samples import RENDERED, by_frame, instances_of, select_instances, served_data  # noqa: E402
from evaluation.queries import frame_files, query  # noqa: E402
from evaluation.rolls import RolledFrames, parse_rolls, roll_instance  # noqa: E402
from evaluation.served import register_objects, score  # noqa: E402
from evaluation.splits import split_frames  # noqa: E402
from index.data.bop import BopDataset  # noqa: E402
from index.features.embed import Embedder  # noqa: E402
from index.templates.render import Renderer  # noqa: E402
from service.pipeline.query import cut  # noqa: E402
from service.recognition import recognise  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.state import close_state, load_state  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", type=Path, default=ROOT / "models" / "posedesc-rgb.onnx")
    p.add_argument("--dataset", type=Path, required=True)
    p.add_argument("--scene", type=int, default=2)
    p.add_argument("--frames", default="val", help="val, test (the model's split) or all")
    p.add_argument(
        "--distractors", type=int, default=0, help="procedural objects added besides the dataset's"
    )
    p.add_argument("--data-dir", type=Path, default=None, help="kept between runs (default: a temporary one)")
    p.add_argument("--settings", default="{}", help="JSON of service settings, e.g. '{\"rerank\": 400}'")
    p.add_argument("--limit", type=int, default=0, help="only the first N instances")
    p.add_argument(
        "--compare", type=Path, default=None, help="another run's JSON: how many best answers agree"
    )
    p.add_argument(
        "--true-mask",
        choices=("full", "band", "inner"),
        default=None,
        help="the query's mask replaced by the true visible one (full), or the model's with the true one "
        "inside a band of 2 px either side of the true outline (band), or outside it (inner)",
    )
    p.add_argument(
        "--rolls",
        default=None,
        help="send every frame again at these camera rolls, degrees (evaluation/rolls.py), e.g. 0,72,144",
    )
    p.add_argument(
        "--k",
        type=int,
        default=K_MAX,
        help="answers asked a query: `among_k` and `reach` say whether any of them is within 20 deg",
    )
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    if args.k < 1:
        print(f"probe_recognise: --k must be >= 1, got {args.k}", file=sys.stderr)
        return 2
    try:
        overrides = json.loads(args.settings)
        args.rolls = parse_rolls(args.rolls) if args.rolls is not None else (0.0,)
    except json.JSONDecodeError as e:
        print(f"probe_recognise: --settings is not JSON: {e}", file=sys.stderr)
        return 2
    except ValueError as e:
        print(f"probe_recognise: --rolls: {e}", file=sys.stderr)
        return 2
    # the settings ignore a name they do not have: a stage's constant (once a setting) would be tried silently
    if unknown := sorted(set(overrides) - set(Settings.model_fields)):
        print(
            f"probe_recognise: --settings: no such setting: {', '.join(unknown)} (a stage's constant is set "
            "in the process, e.g. service.pipeline.refine.ROLL_REFINE)",
            file=sys.stderr,
        )
        return 2
    with tempfile.TemporaryDirectory(prefix="posedesc-probe-") as tmp:
        result = probe(args, overrides, args.data_dir or Path(tmp))
    print(json.dumps({k: result[k] for k in ("settings", "objects", "templates", "k1", "stages_median_ms")}))
    if "agree_with" in result:
        print(json.dumps(result["agree_with"]))
    if "paired" in result:
        print(json.dumps(result["paired"]))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


class TrueMask:
    """An embedder whose mask of the query's first cut (`service.pipeline.mask.foreground`: one patch) is
    the true visible mask (`true`, set before each query) in whole or in part (`how`: --true-mask); the
    re-ranking turns that mask to its rolls, as it turns the model's. Everything else is the embedder's."""

    def __init__(self, embedder: Embedder, how: str):
        self.embedder, self.how = embedder, how
        self.true: np.ndarray | None = None
        #: per query, the model's mask against the true one: IoU, and the share of its wrong pixels
        #: that lie within 2 px of the true outline
        self.scores: list[tuple[float, float]] = []

    def __getattr__(self, name: str):
        return getattr(self.embedder, name)

    def mask(self, inputs: np.ndarray, batch: int = 256) -> np.ndarray:
        predicted = self.embedder.mask(inputs, batch)
        if len(inputs) != 1 or self.true is None:
            return predicted
        true, self.true = self.true, None
        kernel = np.ones((5, 5), np.uint8)  # 2 px either side of the outline
        inside = cv2.dilate(true.astype(np.uint8), kernel).astype(bool)
        band = inside & ~cv2.erode(true.astype(np.uint8), kernel).astype(bool)
        wrong = predicted[0] ^ true
        iou = (predicted[0] & true).sum() / max((predicted[0] | true).sum(), 1)
        self.scores.append((float(iou), float((wrong & band).sum() / max(wrong.sum(), 1))))
        if self.how == "full":
            return true[None]
        keep = band if self.how == "band" else ~band
        return np.where(keep, true, predicted[0])[None]


def probe(args: argparse.Namespace, overrides: dict, data_dir: Path) -> dict:
    dataset = BopDataset(args.dataset)
    embedder = Embedder(args.model, 1)
    modality = embedder.modality
    frames = (
        None
        if args.frames == "all"
        else split_frames(embedder.info.extra, args.dataset, args.scene, args.frames)
    )
    cfg = Config(args.dataset, args.model, modality, scene=args.scene, frames=frames, methods=("ours",))
    instances = instances_of(cfg, dataset, dataset.obj_ids)[: args.limit or None]
    more = {"max_k": args.k} if args.k > Settings().max_k else {}
    settings = Settings(data_dir=data_dir, demo_objects=False, threads=1, **{**more, **overrides})
    ids_file = data_dir / "probe-dataset-ids.json"
    if not ids_file.is_file():
        state = load_state(settings, {modality: embedder})
        try:
            _, dataset_ids = register_objects(state, dataset, dataset.obj_ids)
            if args.distractors:
                from benchmarks.objects import inplane_template_sets

                angles = state.templates.inplane(embedder.info.inplane_step)
                sets = inplane_template_sets(
                    args.distractors,
                    {modality: (embedder, angles)},
                    settings.level,
                    embedder.info.size,
                    embedder.info.window_mm,
                )
                for j, ts in enumerate(sets[modality]):
                    state.store.add_object(
                        f"distractor-{j}", "none", {modality: ts}, extra={"benchmark": True}
                    )
        finally:
            close_state(state)
        ids_file.write_text(json.dumps({str(k): v for k, v in dataset_ids.items()}))
    dataset_ids = {int(k): v for k, v in json.loads(ids_file.read_text()).items()}
    state = load_state(settings, {modality: embedder})
    n = len(instances) * len(args.rolls)
    obj = np.full((n, args.k), -1, int)
    views = np.zeros((n, args.k, 3))
    timings, ordered, sent_rolls = [], [], []
    renderer = None
    try:
        snap = state.store.snapshot
        n_objects, n_templates = len(snap.objects), snap.models[modality].size
        index = type(getattr(snap.models[modality], "index", None)).__name__
        kind = served_data(modality, instances, None)
        renderer = Renderer() if kind in RENDERED or args.true_mask else None
        # meshes only to render (rendered depth, true masks); every annotated instance occludes a true mask
        need = renderer is not None
        meshes = {o: dataset.mesh(o, max_faces=settings.max_faces) for o in dataset.obj_ids} if need else {}
        every = by_frame(select_instances(dataset, args.scene, 0.0, frames, dataset.obj_ids)) if need else {}
        if args.true_mask:
            state = replace(
                state, embedders={m: TrueMask(e, args.true_mask) for m, e in state.embedders.items()}
            )
        frames_sent = RolledFrames(
            frame_files(dataset, instances, modality, kind, 0, renderer, meshes, settings.max_faces),
            args.rolls,
        )
        for group, rgb, depth, scale, roll in frames_sent:
            if args.true_mask and renderer is not None and rgb is not None:
                frame = cv2.imdecode(np.frombuffer(rgb, np.uint8), cv2.IMREAD_COLOR)
                # every annotated object occludes, not only those scored
                others = [roll_instance(o, roll) for o in every[group[0].frame_id]]
                masks = visible_masks(renderer, others, meshes, frame.shape[1], frame.shape[0])
            for inst in group:
                q = replace(query(inst, rgb, depth, scale), k=args.k)
                if args.true_mask:
                    k = next(j for j, o in enumerate(others) if o.obj_id == inst.obj_id)
                    mask3 = np.repeat(masks[k][..., None].astype(np.uint8) * 255, 3, axis=2)
                    true = cut(
                        q, mask3, None, embedder.info.spec, patch_distance_mm=settings.patch_distance_mm
                    ).rgb
                    assert true is not None
                    for e in state.embedders.values():
                        e.true = true[0][..., 0] > 127  # type: ignore[attr-defined]
                t0 = time.perf_counter()
                r = recognise(state, q)
                wall = 1000 * (time.perf_counter() - t0)
                timings.append({**r.timings_ms, "wall": wall})
                i = len(ordered)
                obj[i], views[i], _ = ours.answers(r.matches, dataset_ids, args.k)
                ordered.append(inst)
                sent_rolls.append(roll)
    finally:
        close_state(state)
        if renderer is not None:
            renderer.close()
    masks_scored = [x for e in state.embedders.values() for x in getattr(e, "scores", [])]
    obj, views = obj[: len(ordered)], views[: len(ordered)]
    rot, view, same = score(obj, views, ordered, {o: dataset.symmetry(o) for o in dataset.obj_ids})

    def pct(x: np.ndarray) -> float:
        return round(100 * float(x.mean()), 1)

    result = {
        "command": "scripts/probe_recognise.py " + " ".join(sys.argv[1:]),
        "model": args.model.name,
        "frames": args.frames,
        "settings": overrides,
        "true_mask": args.true_mask,
        "objects": n_objects,
        "distractors": args.distractors,
        "templates": n_templates,
        "index": index,
        "n": len(ordered),
        "rolls": list(args.rolls),
        "rolls_dropped": frames_sent.dropped,
        "k1": {
            "within_5": pct(rot[:, 0] < 5),
            "within_20": pct(rot[:, 0] < 20),
            "within_40": pct(rot[:, 0] < 40),
            "right_object": pct(same[:, 0]),
            "view_within_20": pct(view[:, 0] < 20),
        },
        "stages_median_ms": {
            k: round(float(np.median([t[k] for t in timings if k in t])), 2) for k in timings[0]
        }
        if timings
        else {},
        **(
            {
                "model_mask": {
                    "iou_mean": round(float(np.mean([a for a, _ in masks_scored])), 3),
                    "wrong_pixels_near_outline_mean": round(float(np.mean([b for _, b in masks_scored])), 3),
                }
            }
            if masks_scored
            else {}
        ),
        "by_roll": {
            f"{r:g}": {
                "n": int(m.sum()),
                "within_20": pct(rot[m, 0] < 20),
                "right_object": pct(same[m, 0]),
                "view_within_20": pct(view[m, 0] < 20),
            }
            for r in args.rolls
            if (m := np.array(sent_rolls) == r).any()
        },
        # whether any of a query's k answers is within 20 deg (3-D; viewing direction): what the re-ranking
        # and refinement hand the first place, and what they could have
        "among_k": {
            "k": args.k,
            "within_20": pct((rot < 20).any(1)),
            "view_within_20": pct((view < 20).any(1)),
        },
        "reach": [[int(a), int(b)] for a, b in zip((rot < 20).any(1), (view < 20).any(1), strict=True)],
        "best": [[int(o), *map(float, v)] for o, v in zip(obj[:, 0], views[:, 0], strict=True)],
        # each query: frame, object, roll, 3-D error, viewing-direction error (180: wrong object), right object
        "queries": [
            [i.frame_id, i.obj_id, r, round(float(a), 2), round(float(b), 2), int(c)]
            for i, r, a, b, c in zip(ordered, sent_rolls, rot[:, 0], view[:, 0], same[:, 0], strict=True)
        ],
    }
    if args.compare is not None:
        theirs = json.loads(args.compare.read_text())
        if "queries" in theirs:
            result["paired"] = paired(result["queries"], theirs["queries"], theirs.get("model", "?"))
        pairs = _common_best(result, theirs)
        same_best = [a[0] == b[0] and np.allclose(a[1:], b[1:]) for a, b in pairs]
        result["agree_with"] = {
            "file": args.compare.name,
            "n": len(pairs),
            "same_best_answer": pct(np.array(same_best)) if pairs else None,
        }
    return result


def _common_best(ours: dict, theirs: dict) -> list[tuple[list, list]]:
    """The two runs' best answers to the queries both sent: matched by (frame, object, roll) where both
    list their queries, else in order (older runs, which must then have sent the same queries)."""
    if "queries" in ours and "queries" in theirs:
        other = {tuple(q[:3]): b for q, b in zip(theirs["queries"], theirs["best"], strict=True)}
        return [
            (b, other[k])
            for q, b in zip(ours["queries"], ours["best"], strict=True)
            if (k := tuple(q[:3])) in other
        ]
    same = len(ours["best"]) == len(theirs["best"])
    return list(zip(ours["best"], theirs["best"], strict=True)) if same else []


def paired(ours: list, theirs: list, name: str, draws: int = 4000, seed: int = 0) -> dict:
    """This run against another on the queries both sent (same frame, object and roll): the difference
    in points of each k = 1 figure, with a 95 % interval from resampling the instances (frame, object):
    the rolls of one instance are not independent queries, so they are resampled together."""
    mine = {(f, o, r): e for f, o, r, *e in ours}
    other = {(f, o, r): e for f, o, r, *e in theirs}
    common = sorted(mine.keys() & other.keys())
    if not common:
        return {"against": name, "n": 0}
    clusters = sorted({(f, o) for f, o, _ in common})
    where = {c: i for i, c in enumerate(clusters)}
    cluster = np.array([where[(f, o)] for f, o, _ in common])
    a, b = np.array([mine[k] for k in common]), np.array([other[k] for k in common])
    out: dict = {"against": name, "n": len(common), "instances": len(clusters)}
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(clusters), size=(draws, len(clusters)))
    for label, hit in (
        ("within_5", lambda e: e[:, 0] < 5),
        ("within_20", lambda e: e[:, 0] < 20),
        ("right_object", lambda e: e[:, 2] > 0),
        ("view_within_20", lambda e: e[:, 1] < 20),
    ):
        d = hit(a).astype(float) - hit(b)
        total = np.bincount(cluster, d, len(clusters))
        count = np.bincount(cluster, minlength=len(clusters)).astype(float)
        boot = 100 * total[picks].sum(axis=1) / count[picks].sum(axis=1)
        out[label] = {
            "difference": round(100 * float(d.mean()), 1),
            "interval_95": [round(float(x), 1) for x in np.percentile(boot, [2.5, 97.5])],
            "better": int((d > 0).sum()),
            "worse": int((d < 0).sum()),
        }
    return out


if __name__ == "__main__":
    sys.exit(main())
