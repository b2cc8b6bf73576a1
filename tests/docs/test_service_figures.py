"""docs/service.md's speed figures are those of the bench runs it names (docs/results/bench-roll-*.json)."""

from __future__ import annotations

from doc_figures import doc, missing, num, result

DOC = "docs/service.md"


def test_the_speed_of_an_answer() -> None:
    def run(name: str) -> tuple[str, str, str, str]:
        bench = result(name)
        s, loads = bench["summary"], [bench["machine"][f"load_average_at_{w}"][0] for w in ("start", "end")]
        return (
            num(s["decoded_to_answer_p50_ms_100_q1"]),
            num(s["roll_http_frame_p50_ms"]),
            f"{num(min(loads))}-{num(max(loads))}",
            bench["machine"]["git_commit"],
        )

    quiet, readme = run("bench-roll-relief.json"), run("bench-roll-54.json")
    assert not missing(
        doc(DOC),
        [
            f"{quiet[0]} ms p50 at 100 objects, a 640×480 PNG frame over HTTP {quiet[1]} ms "
            f"(`results/bench-roll-relief.json`, load {quiet[2]}, code of {quiet[3]})",
            f"the README's speed table has the later run of `results/bench-roll-54.json`, on a quiet machine "
            f"(load {readme[2]}): {readme[0]} and {readme[1]} ms.",
        ],
    )
    assert "bench-roll-54.json" in doc("README.md")  # the README's speed table's run
