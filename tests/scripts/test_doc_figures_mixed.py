"""The figures docs/experiments.md (and docs/service.md's summaries) give for a store of shape-only and textured
objects and for patches are those of their committed JSONs (docs/results/): a mixed store's RGB-D queries with a
centre and its RGB-D patches, and patches with depth fitted in the camera they span."""

from __future__ import annotations

import json

from tests.scripts.test_doc_figures import RESULTS, ROOT, experiments, pct


def ours_k1(path: str) -> tuple[dict, dict, dict]:
    """An evaluation's JSON, its first answers' figures with the open set on and off (by error threshold)."""
    d = json.loads((RESULTS / path).read_text())
    return d, d["methods"]["ours"]["k1"], d["open_set_off"]["methods"]["ours"]["k1"]


def test_the_mixed_store_s_rules_and_runs_are_their_jsons() -> None:
    """The rules compared for a mixed store's RGB-D query with a centre (the session probe's table) and the
    evaluations before and after the change."""
    text = experiments()
    plain = text.replace("**", "")
    rules = json.loads((RESULTS / "mixed-store-rules.json").read_text())["sets"]
    for name in rules["lmo-val"]["rules"]:
        cells = [rules[s]["rules"][name] for s in ("lmo-val", "ycbv-0000", "ycbv-0001", "ycbv-0002")]
        row = " | ".join(f"{c['open_set_on']:.1f} / {c['open_set_off']:.1f}" for c in cells)
        assert f"| {row} |" in plain, (name, row)

    def cells(path: str) -> str:
        d, k, off = ours_k1(path)
        return (
            f"{pct(k['180'])} / {pct(off['180'])} | {pct(k['20'])} | {d['bop']['ar']:.3f} | "
            f"{d['timing_ms']['recognise_median']:.0f}"
        )

    for key in ("lmo-val", "lmo-test", "ycbv-0", "ycbv-1", "ycbv-2"):
        row = f"| {cells(f'mixed-before-{key}.json')} | {cells(f'mixed-after-{key}.json')} |"
        assert row in text, row
    alone = [json.loads((RESULTS / f"mixed-depth-all-ycbv-{s}.json").read_text()) for s in range(3)]
    assert " / ".join(pct(d["methods"]["ours"]["k1"]["180"]) for d in alone) + " %" in text


def test_the_mixed_store_s_parts_side_by_side_are_their_json() -> None:
    text = experiments()
    runs = json.loads((RESULTS / "mixed-parts-threads-ab.json").read_text())["runs"]
    for n in (1, 2):
        one, two = runs[f"one thread, {n}"], runs[f"two threads, {n}"]
        assert (
            one["right_object"] == two["right_object"] and one["bop_ar"] == two["bop_ar"]
        )  # the same answers
        row = (
            f"| {n} | {one['recognise_median_ms']} / {one['recognise_p90_ms']} ms | "
            f"{two['recognise_median_ms']} / {two['recognise_p90_ms']} ms |"
        )
        assert row in text, row


def test_a_mixed_store_s_rgbd_patches_are_their_jsons() -> None:
    """The rules compared for a mixed store's RGB-D patch (the session probe's table), the evaluations before and
    after, and docs/service.md's summary of them."""
    text = experiments()
    plain = text.replace("**", "")
    rules = json.loads((RESULTS / "patch-mixed-rules.json").read_text())["sets"]
    order = ("lmo-val", "ycbv-0000", "ycbv-0001", "ycbv-0002", "lmo-test")
    for name in rules["lmo-val"]["rules"]:
        row = " | ".join(f"{rules[s]['rules'][name]['open_set_on']:.1f}" for s in order)
        assert f"| {row} |" in plain, (name, row)

    def right(path: str) -> tuple[str, str, str]:
        d, k, off = ours_k1(path)
        return pct(k["180"]), pct(off["180"]), f"{d['timing_ms']['recognise_median']:.0f}"

    service = " ".join((ROOT / "docs" / "service.md").read_text().split())
    for key in ("lmo-val", "lmo-test", "ycbv-0", "ycbv-1", "ycbv-2"):
        (b_on, b_off, b_ms), (a_on, a_off, a_ms) = (
            right(f"patch-mixed-before-{key}.json"),
            right(f"patch-mixed-{key}.json"),
        )
        row = f"| {b_on} / {b_off} | {b_ms} ms | {a_on} / {a_off} | {a_ms} ms |"
        assert row in text, row
        if key.startswith("ycbv"):  # docs/service.md gives them with the patch fitted (below)
            fitted = right(f"patch-fit-mixed-{key}.json")[0]
            assert f"{fitted} %" in service or f"{fitted} and" in service, key
    befores = [right(f"patch-mixed-before-ycbv-{s}.json")[0] for s in range(3)]
    assert f"right {float(befores[0]):g}, {float(befores[1]):g} and {befores[2]} % a video before" in service


def test_a_patch_with_depth_fitted_is_its_jsons() -> None:
    """The patch fit's table before and after, the mixed store's patches with it, the rules recorded again, and
    docs/service.md's summary."""
    text = experiments()

    def cells(path: str) -> str:
        d, k, off = ours_k1(path)
        return (
            f"{pct(k['180'])} / {pct(off['180'])} | {pct(k['5'])} | {pct(k['20'])} | "
            f"{d['timing_ms']['recognise_median']:.0f} ms"
        )

    for key in ("depth-y0", "depth-y1", "depth-y2", "depth-lval", "depth-ltest", "rgbd-lval", "rgbd-ltest"):
        row = f"| {cells(f'patch-fit-before-{key}.json')} | {cells(f'patch-fit-after-{key}.json')} |"
        assert row in text, row

    def on(path: str) -> str:
        return pct(ours_k1(path)[1]["180"])

    fitted = [on(f"patch-fit-mixed-ycbv-{s}.json") for s in range(3)]
    assert f"named right {fitted[0]}, {fitted[1]} and {fitted[2]} % a video" in text
    lmo = [on(f"patch-fit-mixed-lmo-{s}.json") for s in ("val", "test")]
    assert f"validation and test patches {lmo[0]} and {lmo[1]} %" in text
    rules = json.loads((RESULTS / "patch-fit-mixed-rules.json").read_text())["sets"]
    shipped = next(n for n in rules["lmo-val"]["rules"] if n.endswith("(shipped)"))
    for key, path in (("lmo-val", "lmo-val"), ("ycbv-0000", "ycbv-0"), ("lmo-test", "lmo-test")):
        assert f"{rules[key]['rules'][shipped]:.1f}" == on(
            f"patch-fit-mixed-{path}.json"
        )  # the probe only records
    windows = json.loads((RESULTS / "patch-windows-fitted.json").read_text())["all"]
    assert (
        windows["right"] == windows["n"]
        and f"{windows['right']} of {windows['n']} answers right, none wrong" in text
    )
    service = " ".join((ROOT / "docs" / "service.md").read_text().split())
    before = [on(f"patch-fit-before-depth-y{s}.json") for s in range(3)]
    after = [on(f"patch-fit-after-depth-y{s}.json") for s in range(3)]
    assert (
        f"right {before[0]}, {before[1]} and {before[2]} % a video before, {after[0]}, {after[1]} and {after[2]} % now"
        in service
    )
