"""The open set's figures in models/README.md are those of the calibrations' JSON (docs/results/reject-*.json),
and the figures it reads from the models' metadata (models/*.onnx) are the metadata's, which holds the same
thresholds as those JSON files."""

from __future__ import annotations

import json

import pytest
from doc_figures import ROOT, doc, missing, num, pct, result

DOC = "models/README.md"
OBJECTS = {
    "1": "ape",
    "5": "can",
    "6": "cat",
    "8": "driller",
    "10": "egg box",
    "11": "glue",
    "12": "hole puncher",
}
# the README's row label -> the statistic's name in each JSON's `explored`
STATISTICS = {
    "distance (before)": "distance",
    "lead, weight 0.5": "lead, weight 0.5",
    "lead, weight 1": "lead, weight 1",
    "lead, weight 2": "lead, weight 2",
    "lead, weight 4": "lead, weight 4",
    "ratio: distance / nearest other object's": "ratio: distance / nearest other object's",
    "the lead alone": "minus the lead alone",
    "share of the top 10 not the best's object": "share of the top 10 not the best's object",
    "distance + 5 x the descriptor distance (offline only)": "distance + 5 x the descriptor run's best distance (offline)",
    "lead, weight 2, + 1 x the colour distance (a colour frame with its camera and centre)": (
        "lead, weight 2, + 1 x the colour distance"
    ),
    "lead, weight 0.5, + 0.2 x the unexplained share (a frame with depth, its camera and centre)": (
        "lead, weight 0.5, + 0.2 x the unexplained share"
    ),
}


def reject(modality: str) -> dict:
    return result(f"reject-posedesc-{modality}.json")


def explored_cell(modality: str, kind: str, statistic: str) -> str:
    rows = {r["statistic"]: r for r in reject(modality)["explored"][kind]}
    if statistic not in rows:
        return "-"
    r, shipped = rows[statistic], reject(modality)["calibrations"][kind]
    cell = f"{pct(r['unknown_rejected'], 0)} % ({pct(r['worst_object'], 0)}) {num(r['auc'], 2)}"
    chosen = shipped["statistic"] == "lead" and statistic == f"lead, weight {shipped['weight']:g}" + (
        f", + {shipped['colour']['weight']:g} x the colour distance" if "colour" in shipped else ""
    )
    return f"**{cell}**" if chosen and modality != "depth" else cell  # depth: chosen on real depth


def test_the_statistics_tried_on_validation() -> None:
    rows = [
        f"| {label} | {explored_cell('rgb', 'local', s)} | {explored_cell('rgbd', 'local', s)} | "
        f"{explored_cell('depth', 'descriptor', s)} |"
        for label, s in STATISTICS.items()
    ]
    best = {  # sorted best first; the colour and fit terms are rows of their own (a term needs a frame)
        m: next(
            r
            for r in reject(m)["explored"]["descriptor"]
            if "colour" not in r["statistic"] and "unexplained" not in r["statistic"]
        )
        for m in ("rgb", "rgbd")
    }

    def said(r: dict) -> str:
        return "the distance" if r["statistic"] == "distance" else r["statistic"].replace(",", "")

    real = result("reject-posedesc-depth-real.json")["explored"]["descriptor"]
    assert not missing(
        doc(DOC),
        [
            *rows,
            f"rgb {said(best['rgb'])}, {pct(best['rgb']['unknown_rejected'], 0)} %; rgbd {said(best['rgbd'])}, "
            f"{pct(best['rgbd']['unknown_rejected'], 0)} % (JSON, `explored`)",
            f"(`reject-posedesc-depth-real.json`: at most {pct(max(r['unknown_rejected'] for r in real), 0)} % of "
            f"the unknowns, AUC at most {num(max(r['auc'] for r in real), 2)})",
        ],
    )


def test_the_test_frames_table() -> None:
    def row(label: str, modality: str, kind: str, registered_digits: int, per_object: bool = True) -> str:
        test = reject(modality)["test"][kind]
        six = test["by_registered"]["6"]
        unknown, registered = (
            pct(six["rejected_unknown"], 0),
            pct(six["rejected_registered"], registered_digits),
        )
        objects = [pct(test["per_unregistered_object"][o]["rejected_unknown"], 0) for o in OBJECTS]
        if label.startswith("rgb (local"):
            objects = [f"{name} {x}" for name, x in zip(OBJECTS.values(), objects, strict=True)]
        if not per_object:
            return f"| {label} | {unknown} % | {registered} % | {pct(six['rejected_right'])} % | |"
        return (
            f"| {label} | **{unknown} %** ({six['n_unknown']}) | **{registered} %** ({six['n_registered']}) | "
            f"{pct(six['rejected_right'])} % | {', '.join(objects)} |"
        )

    rgb = reject("rgb")
    six = rgb["test"]["local"]["by_registered"]["6"]
    on_val = rgb["calibrations"]["local"]["at_threshold"]["rejected_right"]
    assert not missing(
        doc(DOC),
        [
            row("rgb (local; the lead plus the colours)", "rgb", "local", 0),
            row("rgbd (local; rendered depth)", "rgbd", "local", 1),
            row(
                "depth (descriptor; the lead plus the unexplained share; rendered depth; threshold set on real depth)",
                "depth",
                "descriptor",
                1,
            ),
            row("rgb (descriptor, RERANK 0)", "rgb", "descriptor", 1, per_object=False),
            row("rgbd (descriptor, RERANK 0)", "rgbd", "descriptor", 1, per_object=False),
            f"rgb rejects too many registered patches on the test frames ({pct(six['rejected_registered'], 0)} %: "
            f"{pct(six['rejected_right'], 0)} % of its right answers against {pct(on_val, 0)} % on validation, and "
            f"{pct(six['rejected_wrong'], 0)} % of its wrong ones)",
            f"the depth model rejects the unknowns "
            f"({pct(reject('depth')['test']['descriptor']['by_registered']['6']['rejected_unknown'], 0)} %;",
        ],
    )


def test_the_calibrations() -> None:
    rgb, rgbd = reject("rgb"), reject("rgbd")
    filtered = [r["compare_filtered"]["local"] for r in (rgb, rgbd)]
    settings = rgbd["calibrations"]["local"]["settings"]
    assert rgb["calibrations"]["local"]["settings"] | {"relief_weight": 5.0} == settings
    assert settings["inplane_extent"] == 180.0  # the whole turn
    real = result("reject-posedesc-depth-real.json")["calibrations"]["descriptor"]
    assert all("reject at most 0.08 of the registered" in r["rule"] for r in (rgb, rgbd, real))
    assert len(rgb["frames"]["val"]) == 20
    assert not missing(
        doc(DOC),
        [
            f"the statistic off by more than {num(filtered[0]['statistic_difference']['p90_abs'], 3)} / "
            f"{num(filtered[1]['statistic_difference']['p90_abs'], 3)} for one in ten",
            f"named another object for {pct(1 - filtered[0]['same_object'])} % (rgb) and "
            f"{pct(1 - filtered[1]['same_object'])} % (rgbd) of the validation patches",
            f"(level {settings['level']}, in-plane {settings['inplane_step']:g} deg over the whole turn for rgb and "
            f"rgbd, query turns {settings['query_turns']}, RERANK {settings['rerank']}, ROLL_SWEEP "
            f"{settings['roll_sweep']}, RELIEF_WEIGHT {settings['relief_weight']:g} for rgbd, and the "
            f"refinement's and the mask's constants, roll_refine {settings['roll_refine']}, refine rounds "
            f"{settings['refine_rounds']}, mask_coverage {settings['mask_coverage']:g}:",
            f"(the rgb model's `split_frames`, {len(rgb['frames']['val'])} frames, "
            f"{rgb['calibrations']['local']['n']['unknown']} instances)",
            f"set on the real videos ({num(real['threshold'], 3)};",
            "**The threshold**: rejecting at most 8 % of the registered objects' validation patches",
            f"the shipped statistic is now the lead, threshold {num(rgb['calibrations']['local']['threshold'], 3)},",
        ],
    )


@pytest.fixture(scope="module")
def metadata() -> dict[str, dict[str, str]]:
    onnx = pytest.importorskip("onnx")
    names = ("posedesc-rgb", "posedesc-rgbd", "posedesc-depth", "posedesc-objectness")
    return {
        n: {p.key: p.value for p in onnx.load(str(ROOT / "models" / f"{n}.onnx")).metadata_props}
        for n in names
    }


def test_the_metadata_holds_the_committed_thresholds(metadata) -> None:
    for model, kinds, name in (
        ("posedesc-rgb", ("local", "descriptor"), "reject-posedesc-rgb.json"),
        ("posedesc-rgbd", ("local", "descriptor"), "reject-posedesc-rgbd.json"),
        ("posedesc-depth", ("descriptor",), "reject-posedesc-depth-real.json"),
    ):
        held = json.loads(metadata[model]["reject_above"])
        for kind in kinds:
            assert held[kind]["threshold"] == result(name)["calibrations"][kind]["threshold"], (model, kind)


def test_the_figures_read_from_the_metadata(metadata) -> None:
    rgb, depth, objectness = (
        metadata["posedesc-rgb"],
        metadata["posedesc-depth"],
        metadata["posedesc-objectness"],
    )
    mask, local = json.loads(rgb["mask"]), json.loads(rgb["local"])
    split = json.loads(rgb["split_frames"])["lmo/000002"]
    val, test = split["val"], split["test"]
    checked = json.loads(depth["validation"])
    assert int(objectness["step"]) == int(result("objectness-val.json")["model_step"])
    assert len(json.loads(objectness["levels"])) == 9 and len(json.loads(objectness["config"])["levels"]) == 5
    size = (ROOT / "models" / "posedesc-objectness.onnx").stat().st_size
    assert not missing(
        doc(DOC),
        [
            f"the checkpoint with the most validation answers within 20 deg: epoch {rgb['epoch']} of",
            f"best validation IoU {num(mask['val_iou'], 3)} at step {mask['step']} of",
            f"best validation top-1 {num(local['val_top1'], 3)} at step {local['step']:,}",
            f"Frames: training {len(split['train'])} frames, validation {len(val)} ({min(val)}-{max(val)}), test "
            f"{len(test)} ({min(test)}-{max(test)})",
            f"frames: epoch {depth['epoch']} of 39, 3-D within 20 deg {pct(checked['within_3d_20'], 0)} %, "
            f"recognised {pct(checked['recognised'], 0)} %",
            f"step {int(objectness['step']):,} of the run, chosen on the validation frames; {size / 1e6:.1f} MB",
        ],
    )
