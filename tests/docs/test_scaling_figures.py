"""docs/scaling.md's Milvus figures are those of docs/results/bench-milvus.json (the stores side by side) and
bench-milvus-replica-start.json (a replica started after the registrations, the changes seen by another)."""

from __future__ import annotations

from doc_figures import doc, missing, num, result

DOC = "docs/scaling.md"


def ms(x: float) -> str:
    """A p50 as the doc writes it: two decimals below 1 ms, one below 100, whole above."""
    return num(x, 2) if x < 1 else num(x) if x < 100 else num(x, 0)


def tail(x: float) -> str:
    """A p99 as the doc writes it: one decimal below 10 ms, whole above."""
    return num(x) if x < 10 else num(x, 0)


def test_the_stores_table_and_its_text() -> None:
    bench = result("bench-milvus.json")
    small, large = (bench["sections"]["milvus"]["by_size"][n] for n in ("30100", "1000000"))
    load = [bench["machine"][f"load_average_at_{w}"][0] for w in ("start", "end")]

    def answers(size: dict, store: str, bold: bool = False) -> str:
        r, b = size["recognition"][store], "**" if bold else ""
        return f"{b}{ms(r['p50_ms'])}{b} / {tail(r['p99_ms'])}"

    def reg(size: dict, store: str) -> str:
        return num(size["registration"][store]["p50_ms"], 0)

    def rss(size: dict, when: str) -> str:
        return num(size[f"milvus_server_rss_bytes_{when}"] / 1e6, 0)

    grown = large["milvus_server_rss_bytes_loaded"] - large["milvus_server_rss_bytes_before"]
    assert small["objects"] == 100 and small["filled"] == "add_object" and large["filled"] == "bulk"
    assert round(grown / large["templates"], -1) == 480  # "~480 B a template"
    assert not missing(
        doc(DOC),
        [
            f"(copied to `docs/results/bench-milvus.json`; {num(bench['seconds']['total'], 0)} s;",
            f"(load average {num(load[0])} at the start, {num(load[1])} at the end)",
            f"| {small['templates']:,} (100 objects, each through `add_object`) | {answers(small, 'embedded', bold=True)} | "
            f"{answers(small, 'milvus')} | **{reg(small, 'embedded')}** / {reg(small, 'milvus')} | "
            f"{num(small['recall_at_k'], 3)} |",
            f"| {large['templates']:,} ({large['objects']:,} objects, bulk-loaded) | {answers(large, 'embedded')} | "
            f"{answers(large, 'milvus', bold=True)} | – / {reg(large, 'milvus')} | {num(large['recall_at_k'], 3)} |",
            f"Milvus's HNSW index is {num(large['recognition']['embedded']['p50_ms'] / large['recognition']['milvus']['p50_ms'])}× "
            f"faster than the embedded store's exact flat search",
            f"grew from {rss(large, 'before')} to {rss(large, 'loaded')} MB with the 10⁶ templates loaded",
            f"(load {num(load[0])} → {num(load[1])}): at 10⁶ 16-d templates, k = {bench['sections']['milvus']['k']}, "
            f"Milvus (HNSW) answers in {ms(large['recognition']['milvus']['p50_ms'])} ms p50 / "
            f"{tail(large['recognition']['milvus']['p99_ms'])} ms p99 against the embedded exact flat search's "
            f"{answers(large, 'embedded')} ms",
            f"at 100 objects ({small['templates']:,} templates, not yet indexed by Milvus) {answers(small, 'milvus')} "
            f"ms against {answers(small, 'embedded')} ms. A registration's store part: {reg(small, 'milvus')}–"
            f"{reg(large, 'milvus')} ms through Milvus, {reg(small, 'embedded')} ms embedded",
            f"{rss(large, 'before')} MB → {rss(large, 'loaded')} MB with 10⁶ templates loaded",
        ],
    )


def test_a_replica_started_after_and_the_changes_seen() -> None:
    bench = result("bench-milvus-replica-start.json")
    milvus = bench["sections"]["milvus"]
    start, seen = milvus["by_size"]["30100"]["replica_start"], milvus["propagation"]
    load = max(bench["machine"][f"load_average_at_{w}"][0] for w in ("start", "end"))  # 1-minute
    reg, dele = seen["registration"], seen["deletion"]
    assert start["objects"] == 100
    assert not missing(
        doc(DOC),
        [
            f"answers exactly as the other's {num(start['p50_s'], 2)} s p50 ({num(start['max_s'], 2)} s max, "
            f"{start['runs']} starts)",
            f"(load up to {num(load)}: an evaluation ran)",
            f"registration seen after {num(reg['seen_p50_ms'] / 1000, 2)} s p50 ({num(reg['seen_max_ms'] / 1000, 2)} s "
            f"max), its call taking {num(reg['call_p50_ms'] / 1000, 2)} s, a deletion after "
            f"{num(dele['seen_p50_ms'] / 1000, 2)} s ({num(dele['seen_max_ms'] / 1000, 2)} s), its call "
            f"{num(dele['call_p50_ms'] / 1000, 2)} s",
        ],
    )
