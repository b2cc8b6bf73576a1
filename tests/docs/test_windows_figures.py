"""docs/windows.md's figures, the driller through its own window class, are those of
docs/results/windows-summary.json and the windows-*.json runs it was made from."""

from __future__ import annotations

from doc_figures import doc, missing, num, result

DOC = "docs/windows.md"


def pair(figures: dict) -> str:
    return f"{num(figures['right_object_k1'])} / {num(figures['within_20deg_k1'])}"


def test_the_driller_table_is_the_summary() -> None:
    runs = result("windows-summary.json")["runs"]
    rows = []
    for split, label in (("val", "val ({} driller instances of {})"), ("test", "test ({} of {})")):
        before, after = runs[f"before-{split}"], runs[f"after-{split}"]
        n = [result(f"windows-{who}before-{split}.json")["n_samples"] for who in ("driller-", "")]
        rows.append(
            f"| {label.format(*n)} | {pair(before['per_object']['driller'])} | {pair(before['others_mean'])} | "
            f"{pair(after['per_object']['driller'])} | {pair(after['others_mean'])} |"
        )
    assert not missing(doc(DOC), rows)


def test_the_driller_alone_and_the_speed() -> None:
    runs = result("windows-summary.json")["runs"]

    def driller(run: str, key: str) -> float:
        return runs[run]["per_object"]["driller"][key]

    lost = [
        driller(f"before-{s}", "right_object_k1") - driller(f"after-{s}", "right_object_k1")
        for s in ("val", "test")
    ]
    alone = {k: v["driller"] for k, v in runs.items() if k.startswith("driller-alone")}
    within, right = "within_20deg_k1", "right_object_k1"
    speed = [result(f"windows-{w}-val.json")["timing_ms"]["recognise_median"] for w in ("before", "after")]
    assert alone["driller-alone-before-val"][within] == alone["driller-alone-after-val"][within]
    assert not missing(
        doc(DOC),
        [
            f"-{num(lost[0])} and -{num(lost[1])} points of right object",
            f"(val {num(alone['driller-alone-before-val'][within])} both, test "
            f"{num(alone['driller-alone-before-test'][within])} -> {num(alone['driller-alone-after-test'][within])})",
            f"(right object {num(alone['driller-alone-before-val'][right])} -> "
            f"{num(alone['driller-alone-after-val'][right])}, {num(alone['driller-alone-before-test'][right])} -> "
            f"{num(alone['driller-alone-after-test'][right])})",
            f"(validation median {num(speed[0])} -> {num(speed[1])} ms per query)",
        ],
    )
