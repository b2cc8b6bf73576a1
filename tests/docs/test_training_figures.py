"""docs/training.md's figures of the heads and features tried are those of their committed runs
(docs/results/): the service's answers on the validation frames, paired where the doc pairs them."""

from __future__ import annotations

from doc_figures import doc, missing, num, pct, result

DOC = "docs/training.md"


def probe(name: str) -> dict:
    return result(name)["k1"]


def service(name: str, t: str = "20") -> str:
    return pct(result(name)["methods"]["ours"]["k1"][t])


def test_the_mask_heads_and_local_features_tried() -> None:
    shipped, jitter = probe("probe-val-7.json"), probe("probe-val-7-local-jitter3.json")
    outline = [probe(f"probe-val-7-mask-outline{s}.json") for s in ("", "-soft")]
    assert all(
        o["within_20"] == shipped["within_20"] and o["right_object"] == shipped["right_object"]
        for o in outline
    )

    def four(r: dict) -> str:
        return " / ".join(num(r[k]) for k in ("within_5", "within_20", "within_40", "right_object"))

    assert not missing(
        doc(DOC),
        [
            f"the same {num(shipped['within_20'])} % within 20° and {num(shipped['right_object'])} % right object as "
            "the shipped head (Evaluation; `probe-val-7-mask-outline.json` and `probe-val-7-mask-outline-soft.json` "
            "against `probe-val-7.json`)",
            f"validation frames {four(jitter)}, view {num(jitter['view_within_20'])} (`scripts/probe_recognise.py`, "
            f"`probe-val-7-local-jitter3.json`) against {four(shipped)} (`probe-val-7.json`)",
            f"20° on validation frames {service('val-rgb-imagenet-local.json')} → {service('val-rgb.json')} %, "
            f"`val-rgb-imagenet-local.json` → `val-rgb.json`, on test frames {service('test-rgb-imagenet-local.json')} "
            f"→ {service('test-rgb-rerank200.json')} %, `test-rgb-imagenet-local.json` → `test-rgb-rerank200.json`",
            f"on validation frames {service('val-rgb-local-hard.json')} % within 20° against {service('val-rgb.json')} "
            "% without (`val-rgb-local-hard.json`, `val-rgb.json`;",
        ],
    )


def test_the_negatives_tried_on_the_rolled_yardstick() -> None:
    runs = ["probe-val-rolls5-local-others12.json", "probe-val-rolls5-local-others12-last.json"]
    paired = [result(n)["paired"] for n in [*runs, "probe-val-rolls5-local-same15-far20.json"]]

    def signed(x: float) -> str:
        return f"+{num(x)}" if x > 0 else num(x).replace("-", "−")

    within = ", ".join(signed(p["within_20"]["difference"]) for p in paired[:2])
    right = ", ".join(signed(p["right_object"]["difference"]) for p in paired[:2])
    # "every interval spanning zero or below it"
    assert all(p[m]["interval_95"][0] <= 0 for p in paired for m in ("within_20", "right_object"))
    assert not missing(
        doc(DOC),
        [
            f"within 20° {within} and {signed(paired[2]['within_20']['difference'])} points against the shipped "
            "features (`probe-val-rolls5-local-others12.json`, `-others12-last.json`, `-same15-far20.json`, each "
            "paired with the shipped run)",
            f"right object {right} and {signed(paired[2]['right_object']['difference'])}, every interval spanning "
            "zero or below it",
        ],
    )
