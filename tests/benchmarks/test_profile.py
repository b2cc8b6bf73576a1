"""The profile of `posedesc bench --profile`: the flame graph's boxes from hand-made stacks, and a real
function profiled and sampled into its files."""

from __future__ import annotations

import time

from benchmarks.profile import Node, boxes, folded, profile, sample, tree

STACKS = {
    ("main", "cut", "resize"): 3,
    ("main", "cut"): 2,  # self time of cut
    ("main", "embed", "run"): 10,
    ("main", "search"): 4,
    ("idle",): 1,
}


def spans(root: Node) -> list[tuple[Node, list[Node]]]:
    out, todo = [], [root]
    while todo:
        n = todo.pop()
        out.append((n, list(n.children.values())))
        todo += n.children.values()
    return out


def test_the_tree_counts_every_sample_on_its_path():
    root = tree(STACKS)
    assert root.count == sum(STACKS.values()) == 20
    main = root.children["main"]
    assert main.count == 19 and main.children["cut"].count == 5 and main.children["cut"].self_count == 2
    assert main.children["embed"].children["run"].count == 10
    for node, children in spans(root):
        assert node.count >= sum(c.count for c in children) and node.self_count >= 0


def test_boxes_nest_within_their_parents():
    root = tree(STACKS)
    bs = boxes(root)
    assert bs[0].name == "all" and bs[0].x == 0 and bs[0].width == 20 and bs[0].depth == 0
    assert len(bs) == 8  # all, main, idle, cut, resize, embed, run, search
    for depth in range(1, max(b.depth for b in bs) + 1):
        row = sorted((b for b in bs if b.depth == depth), key=lambda b: b.x)
        parents = [b for b in bs if b.depth == depth - 1]
        for b in row:  # inside one box of the row above
            assert any(p.x <= b.x and b.x + b.width <= p.x + p.width for p in parents), b
        for a, b in zip(row, row[1:], strict=False):  # no overlap
            assert a.x + a.width <= b.x
    embed = next(b for b in bs if b.name == "embed")
    assert embed.depth == 2 and embed.width == 10 and embed.x == 0  # the widest child first
    assert folded(STACKS).splitlines()[0] == "main;embed;run 10"


def busy(ms: float) -> None:
    end = time.perf_counter() + ms / 1e3
    while time.perf_counter() < end:
        pass


def heavy() -> None:
    busy(6)


def light() -> None:
    busy(2)


def query() -> None:
    heavy()
    light()


def test_sampling_sees_where_the_time_goes():
    stacks = sample(query, 10)
    root = tree(stacks)
    assert root.count > 20 and len(root.children) == 1
    (top,) = root.children.values()
    assert top.name.endswith(":query")
    by = {n.name.rsplit(":", 1)[1]: n.count for n in top.children.values()}
    assert by["heavy"] > by["light"] > 0  # three times the work: more samples, whatever the load


def test_profile_writes_its_files(tmp_path):
    out = profile(query, 5, tmp_path / "p", "query", warmup=1)
    assert out["files"] == ["calls.prof", "flame.png", "stacks.txt", "top.txt"]
    assert (tmp_path / "p" / "flame.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out["samples"] > 0 and out["calls"] == 5
    top = (tmp_path / "p" / "top.txt").read_text().splitlines()
    assert top[0].startswith("query: cProfile over 5 calls") and any("busy" in line for line in top[2:])
    assert 0 < sum(r["self_share"] for r in out["top_self"]) <= 1.0 + 1e-9
