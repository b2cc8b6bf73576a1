"""The report: the JSON contract, a markdown table like the paper's Table 1, per-object results, and the
pictures, all in one folder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evaluation import pictures
from evaluation.results import Evaluation

NAMES = {"ours": "ours", "hog": "HOG", "linemod": "LineMOD"}


def write_json(ev: Evaluation, path: Path) -> dict:
    summary = ev.summary()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary, indent=1))
    return summary


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def table(summary: dict, ks: tuple[int, ...] = (1, 22), key: str = "methods") -> str:
    """Rows method x k; columns: within 5°, 20°, 40°, and the right object (percent of test patches).
    `key`: "methods" (the protocol's error) or "view_direction" (the service protocol's other error)."""
    lines = [
        "| method | k | 5° | 20° | 40° | right object |",
        "|---|---|---|---|---|---|",
    ]
    for k in ks:
        for name, res in summary[key].items():
            row = res[f"k{k}"]
            cells = " | ".join(_pct(row[t]) for t in ("5", "20", "40", "180"))
            lines.append(f"| {NAMES.get(name, name)} | {k} | {cells} |")
    return "\n".join(lines)


def rejected_text(summary: dict) -> str:
    """How many queries the service answered "no known object", per method that has an open set."""
    n = summary["n_samples"]
    return "; ".join(
        f"{NAMES.get(name, name)}: {r['n']} of {n} queries rejected ({_pct(r['share'])} %), "
        f"{r['right_object_first']} of them with the right object first"
        for name, r in summary.get("rejected", {}).items()
    )


def bop_text(summary: dict) -> str:
    """The BOP figures of the service's best answers (`evaluation.bop.scores`), percent; "" without them."""
    b = summary.get("bop")
    if not b:
        return ""
    vsd = "" if b["ar_vsd"] is None else f", AR_VSD {_pct(b['ar_vsd'])}"
    return (
        f"BOP ({b['n_targets']} targets, {b['n_estimated']} with an estimate of their object): "
        f"AR {_pct(b['ar'])} (AR_MSSD {_pct(b['ar_mssd'])}, AR_MSPD {_pct(b['ar_mspd'])}{vsd}), "
        f"ADD(-S) < 0.1 d {_pct(b['recall_add_s'])}, 5°5cm {_pct(b['recall_5deg_5cm'])} (percent)"
        + (
            "; t sent with the query (the true distance): these measure the rotation"
            if "translation" in b
            else ""
        )
    )


def tables_text(summary: dict) -> str:
    """The tables as `posedesc evaluate` prints them: the protocol's error, the viewing-direction error
    where there is one, and, with the open set (the service protocol), the same answers as ranked."""
    parts = [table(summary)]
    if "view_direction" in summary:
        parts += ["viewing-direction error:", table(summary, key="view_direction")]
    if "open_set_off" in summary:
        off = summary["open_set_off"]
        parts += ["open set off (rejected answers scored as ranked):", table(off)]
        if "view_direction" in off:
            parts += ["open set off, viewing-direction error:", table(off, key="view_direction")]
        parts.append(f"open set on: {rejected_text(summary)}, counted as misses above")
    if bop := bop_text(summary):
        parts.append(bop)
    return "\n".join(parts)


def per_object_table(summary: dict, k: int = 1) -> str:
    """Per object, k nearest: within 20° / right object, percent, for every method."""
    methods = list(summary["methods"])
    unseen = set(summary.get("unseen", []))
    head = "| object | patches | " + " | ".join(f"{NAMES.get(m, m)} 20° / object" for m in methods) + " |"
    lines = [head, "|---|---|" + "---|" * len(methods)]
    for obj, res in summary["per_object"].items():
        cells = " | ".join(f"{_pct(res[m][f'k{k}']['20'])} / {_pct(res[m][f'k{k}']['180'])}" for m in methods)
        label = f"{obj} (unseen)" if int(obj) in unseen else obj
        lines.append(f"| {label} | {res['n_samples']} | {cells} |")
    for group in ("seen_objects", "unseen_objects"):
        if group in summary:
            res = summary[group]
            cells = " | ".join(
                f"{_pct(res[m][f'k{k}']['20'])} / {_pct(res[m][f'k{k}']['180'])}" for m in methods
            )
            lines.append(f"| all {group.split('_')[0]} | {res['n_samples']} | {cells} |")
    return "\n".join(lines)


def frames_text(frames: list[int], most: int = 20) -> str:
    """[1, 2, 3, 7] -> "1-3, 7"; long lists as a count and a span (the JSON has them all)."""
    if not frames:
        return "none"
    if len(frames) > most:
        return f"{len(frames)} frames from {frames[0]} to {frames[-1]} (listed in the JSON)"
    parts, start, prev = [], frames[0], frames[0]
    for f in [*frames[1:], None]:
        if f is not None and f == prev + 1:
            prev = f
            continue
        parts.append(f"{start}-{prev}" if prev > start else f"{start}")
        if f is not None:
            start = prev = f
    return ", ".join(parts)


def write_report(ev: Evaluation, folder: Path, command: str, model_3d: Path | None = None) -> Path:
    """Writes report.md and the pictures into `folder`; returns the markdown's path. Pictures that need
    what a protocol does not have (templates per answer, distances to every template) are left out."""
    folder.mkdir(parents=True, exist_ok=True)
    summary = ev.summary()
    pics = [("accuracy against threshold", pictures.accuracy_curves(ev, folder / "accuracy.png"))]
    if any(len(r.angle_distance) for r in ev.results.values()):
        pics.append(
            ("distance against pose angle", pictures.distance_vs_angle(ev, folder / "distance_vs_angle.png"))
        )
    if any(len(r.separation) for r in ev.results.values()):
        pics.append(("class separation", pictures.class_separation(ev, folder / "class_separation.png")))
    for name, r in ev.results.items():
        if r.neighbours is not None and ev.templates is not None:
            path = pictures.nearest_templates(ev, name, folder / f"nearest_{name}.png")
            pics.append((f"nearest templates, {NAMES[name]}", path))
    if (scatter := _descriptors_3d(ev, folder / "descriptors_3d.png", model_3d)) is not None:
        pics.append(("descriptors in 3-D", scatter))
    c = ev.config
    error = (
        "the angle between viewing directions"
        if c.protocol == "paper"
        else "the 3-D rotation angle, in-plane included"
    )
    md = [
        f"# Evaluation: {c.modality}, {c.protocol} protocol",
        "",
        f"```sh\n{command}\n```",
        "",
        f"- model: `{c.model}`",
        f"- data: `{c.dataset}` scene {c.scene}, {summary['test_data']} test patches "
        f"({summary['n_samples']} instances with visible fraction ≥ {c.min_visib}), "
        f"frames {frames_text(summary['frames'])}",
        f"- templates: {summary['n_templates']} ({len(summary['objects'])} objects)",
        *([f"- service: {summary['service']}"] if "service" in summary else []),
        *([f"- recognise calls (ms): {summary['timing_ms']}"] if "timing_ms" in summary else []),
        f"- seconds: {', '.join(f'{k} {v}' for k, v in summary['seconds'].items())}",
        *[f"- {note}" for note in summary["notes"]],
        "",
        f"Percent of test patches whose best pose among the k nearest answers is within 5°, 20°, 40° "
        f"(strictly below; error: {error}), and whose object is among them (a wrong object counts as 180°):",
        "",
        table(summary),
        "",
        *(
            [
                "The same by the viewing-direction error (in-plane not counted):",
                "",
                table(summary, key="view_direction"),
                "",
            ]
            if "view_direction" in summary
            else []
        ),
        *(
            [
                f"The open set was on: {rejected_text(summary)}; each counts as a miss above. The same "
                "answers as ranked, with nothing rejected (3-D rotation error, then viewing direction):",
                "",
                table(summary["open_set_off"]),
                "",
                table(summary["open_set_off"], key="view_direction"),
                "",
            ]
            if "open_set_off" in summary
            else []
        ),
        *(
            [bop, "", f"({summary['bop']['targets']}; {summary['bop']['vsd']})", ""]
            if (bop := bop_text(summary))
            else []
        ),
        "Per object, k = 1:",
        "",
        per_object_table(summary),
        "",
        *[f"![{title}]({path.name})\n" for title, path in pics],
    ]
    out = folder / "report.md"
    out.write_text("\n".join(md))
    return out


def _descriptors_3d(ev: Evaluation, path: Path, model_3d: Path | None) -> Path | None:
    """The templates (in-plane 0) as a 3-dimensional model describes them; without one, the first three
    principal components of our descriptors."""
    t = ev.templates
    if t is None:
        return None
    keep = np.array([v.inplane == 0 for v in t.views])
    if model_3d is not None:
        from evaluation.paper.ours import embed
        from index.features.embed import Embedder

        emb = Embedder(model_3d)
        if emb.dim != 3 or emb.modality != ev.config.modality:
            raise ValueError(f"--model-3d {model_3d}: needs a 3-dimensional {ev.config.modality} model")
        rgb = None if t.rgb is None else t.rgb[keep]
        depth = None if t.depth is None else t.depth[keep]
        nominal = np.array([v.distance for v, k in zip(t.views, keep, strict=True) if k])
        points = embed(emb, rgb, depth, nominal, False)
        title = f"template descriptors of the 3-D model {model_3d.name}"
    elif "templates" in ev.descriptors:
        points = pictures.pca3(ev.descriptors["templates"][keep])
        title = "template descriptors, first 3 principal components (no 3-D model given)"
    else:
        return None
    return pictures.descriptors_3d(points, t.obj_ids[keep], title, path)
