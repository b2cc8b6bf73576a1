"""A profile of one call repeated (`posedesc bench --profile DIR`, roll section: one query at N objects), so a
change is judged by the function it moves:

- `calls.prof`: the standard library's cProfile over the calls (open with `pstats` or `snakeviz`);
- `top.txt`: the 20 functions of most self time in it, with their share of the calls' time;
- `flame.png` and `stacks.txt`: a flame graph from sampled stacks. A thread reads the calling thread's
  stack (`sys._current_frames`) every `SAMPLE_S` while the calls run (without cProfile, whose hooks
  would weigh on the small Python functions); each stack is counted, `stacks.txt` has them folded (one
  line `a;b;c count`), and in the picture each box is a function on its call path, its width its share of
  the samples. Time in C code (onnxruntime, FAISS, OpenCV) shows as the Python function that called it.

The sampler needs the GIL to read a stack, so the switch interval is set to the sampling period while it
runs: otherwise a thread busy in Python code would hold the GIL for 5 ms at a time and only the places
that release it would be seen."""

from __future__ import annotations

import cProfile
import pstats
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import CodeType, FrameType

from benchmarks.timing import ROOT

#: the sampling period: 1 ms gives ~1,000 samples a second, enough for a stage of a few percent of a
#: 10-50 ms call to show with 20-50 calls
SAMPLE_S = 0.001
#: functions listed in top.txt
TOP = 20
#: boxes narrower than this share of the root are left out of the picture (they would be a hair wide)
MIN_SHARE = 0.002

Stack = tuple[str, ...]  # function labels from the outermost call to the innermost


@dataclass
class Node:
    """A function on one call path: `count` samples had it there; `children` the functions it called."""

    name: str
    count: int = 0
    children: dict[str, Node] = field(default_factory=dict)

    @property
    def self_count(self) -> int:
        return self.count - sum(c.count for c in self.children.values())


@dataclass(frozen=True)
class Box:
    """One rectangle of the flame graph, in samples (`x`, `width`) and call depth (the root is 0)."""

    name: str
    x: int
    width: int
    depth: int


def tree(stacks: Mapping[Stack, int]) -> Node:
    """The call tree of counted stacks; the root ("all") counts every sample."""
    root = Node("all")
    for stack, n in stacks.items():
        root.count += n
        node = root
        for name in stack:
            node = node.children.setdefault(name, Node(name))
            node.count += n
    return root


def boxes(root: Node) -> list[Box]:
    """Every node as a box: a child starts where its previous sibling ends, widest first, within its
    parent's span."""
    out: list[Box] = []

    def walk(node: Node, x: int, depth: int) -> None:
        out.append(Box(node.name, x, node.count, depth))
        for child in sorted(node.children.values(), key=lambda c: -c.count):
            walk(child, x, depth + 1)
            x += child.count

    walk(root, 0, 0)
    return out


def label(code: CodeType) -> str:
    """A function as `file:qualified name`, the file shortened to the repository or the installed package."""
    return f"{_short(code.co_filename)}:{code.co_qualname}"


def _stack(frame: FrameType | None, stop: CodeType) -> Stack | None:
    """The labels from just below the frame running `stop` down to `frame`; None outside it."""
    names: list[str] = []
    while frame is not None:
        if frame.f_code is stop:
            return tuple(reversed(names)) or None  # None: between two calls, in the loop itself
        names.append(label(frame.f_code))
        frame = frame.f_back
    return None


def sample(fn: Callable[[], object], calls: int, period_s: float = SAMPLE_S) -> Counter[Stack]:
    """Runs `fn()` `calls` times in this thread while another counts its stacks every `period_s`."""
    counts: Counter[Stack] = Counter()
    target, done = threading.get_ident(), threading.Event()

    def run() -> None:
        for _ in range(calls):
            fn()

    def sampler() -> None:
        while not done.is_set():
            frame = sys._current_frames().get(target)
            if (s := _stack(frame, run.__code__)) is not None:
                counts[s] += 1
            time.sleep(period_s)

    switch = sys.getswitchinterval()
    sys.setswitchinterval(period_s)
    thread = threading.Thread(target=sampler, name="profile-sampler", daemon=True)
    thread.start()
    try:
        run()
    finally:
        done.set()
        thread.join()
        sys.setswitchinterval(switch)
    return counts


def folded(stacks: Mapping[Stack, int]) -> str:
    """Stacks in the folded form flame graph tools read: `outer;inner;leaf count`, most samples first."""
    return "".join(f"{';'.join(s)} {n}\n" for s, n in sorted(stacks.items(), key=lambda x: -x[1]))


def draw(root: Node, out: Path, title: str) -> Path:
    """The flame graph as a PNG: the root at the bottom, each box a function, its width its share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [b for b in boxes(root) if b.width >= MIN_SHARE * root.count]
    depth = max(b.depth for b in shown) + 1
    fig, ax = plt.subplots(figsize=(16, 0.28 * depth + 1.2))
    cmap = plt.get_cmap("YlOrRd")
    for b in shown:
        # the colour tells the file apart (a stable hash of the name), not the time
        shade = 0.15 + 0.6 * (sum(map(ord, b.name.split(":")[0])) % 97) / 97
        ax.add_patch(plt.Rectangle((b.x, b.depth), b.width, 0.95, fc=cmap(shade), ec="white", lw=0.3))
        share = b.width / root.count
        text = f"{b.name.rsplit('/', 1)[-1]} ({share:.0%})"
        fits = int(share * 16 * 72 / 5.2)  # characters that fit at fontsize 6 across the 16-inch figure
        if fits >= 4:
            ax.text(b.x + root.count * 0.002, b.depth + 0.45, text[:fits], va="center", fontsize=6)
    ax.set_xlim(0, root.count)
    ax.set_ylim(0, depth)
    ax.set_yticks([])
    ax.set_xlabel(f"samples ({root.count:,} in all); a box's width is its share of them")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def top(stats: pstats.Stats, n: int = TOP) -> list[dict]:
    """The `n` functions of most self time: calls, self and cumulative ms, self share of all the time."""
    entries = stats.stats  # type: ignore[attr-defined]  # (file, line, name) -> (cc, nc, tt, ct, callers)
    total = sum(e[2] for e in entries.values()) or 1.0
    rows = sorted(entries.items(), key=lambda kv: -kv[1][2])[:n]
    return [
        {
            "function": f"{_short(f)}:{line}({name})",
            "calls": nc,
            "self_ms": tt * 1e3,
            "cumulative_ms": ct * 1e3,
            "self_share": tt / total,
        }
        for (f, line, name), (_, nc, tt, ct, _) in rows
    ]


def _short(path: str) -> str:
    if "site-packages/" in path:
        return path.split("site-packages/", 1)[1]
    return path[len(str(ROOT)) + 1 :] if path.startswith(str(ROOT)) else path


def top_text(rows: Iterable[dict], calls: int, title: str) -> str:
    lines = [title, f"{'self %':>7}  {'self ms/call':>12}  {'cum ms/call':>11}  {'calls':>7}  function"]
    for r in rows:
        lines.append(
            f"{r['self_share']:7.1%}  {r['self_ms'] / calls:12.3f}  {r['cumulative_ms'] / calls:11.3f}  "
            f"{r['calls']:7d}  {r['function']}"
        )
    return "\n".join(lines) + "\n"


def profile(fn: Callable[[], object], calls: int, out_dir: Path, title: str, warmup: int = 2) -> dict:
    """`fn` profiled into `out_dir` (calls.prof, top.txt, stacks.txt, flame.png) after `warmup` calls;
    the files' names and the top functions, for the bench's JSON."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for _ in range(warmup):
        fn()
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(calls):
        fn()
    prof.disable()
    prof.dump_stats(out_dir / "calls.prof")
    rows = top(pstats.Stats(prof))
    (out_dir / "top.txt").write_text(
        top_text(rows, calls, f"{title}: cProfile over {calls} calls, {TOP} functions of most self time")
    )
    stacks = sample(fn, calls)
    (out_dir / "stacks.txt").write_text(folded(stacks))
    root = tree(stacks)
    if root.count:
        draw(root, out_dir / "flame.png", f"{title}: {calls} calls sampled every {SAMPLE_S * 1e3:g} ms")
    return {
        "dir": str(out_dir),
        "calls": calls,
        "files": sorted(p.name for p in out_dir.iterdir()),
        "samples": root.count,
        "top_self": rows[:10],
    }
