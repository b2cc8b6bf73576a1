"""docs/evaluation.md's figures, the frames of the split and the service answers scored the BOP way, are those
of docs/results/val-rgb.json, test-rgb.json and test-rgb-bop.json."""

from __future__ import annotations

from doc_figures import doc, missing, pct, result

DOC = "docs/evaluation.md"


def test_the_validation_and_test_frames() -> None:
    val, test = result("val-rgb.json"), result("test-rgb.json")
    assert not missing(
        doc(DOC),
        [
            f"(frames {min(val['frames'])}–{max(val['frames'])} for the shipped models: {len(val['frames'])} "
            f"frames, {val['n_samples']} instances at least half visible)",
            f"(frames {min(test['frames'])}–{max(test['frames'])}: {len(test['frames'])} frames, "
            f"{test['n_samples']} instances)",
        ],
    )
    assert val["min_visib"] == test["min_visib"] == 0.5


def test_the_service_answers_scored_the_bop_way() -> None:
    before, fitted = result("test-rgb-bop.json")["bop"], result("test-rgb.json")["bop"]
    assert before == result("test-rgb-nofit.json")["bop"]  # "a run before the pose fit"
    assert not missing(
        doc(DOC),
        [
            f"it gives AR {pct(before['ar'])} (AR_MSSD {pct(before['ar_mssd'])}, AR_MSPD {pct(before['ar_mspd'])}), "
            f"ADD(-S) {pct(before['recall_add_s'])} %, 5°5cm {pct(before['recall_5deg_5cm'])} %",
            f"with it AR {pct(fitted['ar'])}, ADD(-S) {pct(fitted['recall_add_s'])} %, 5°5cm "
            f"{pct(fitted['recall_5deg_5cm'])} %, `docs/results/test-rgb.json`",
        ],
    )
