"""How every figure is measured: repetitions, medians, percentiles, and what the machine was doing.

A figure is the median of `repeats` timed runs after `warmup` untimed ones; latencies are also given as
percentiles over every run. Thread counts are set on purpose (`pin_threads`) and recorded, together
with the machine's cores and load, since a benchmark on a shared 2-core machine says little without."""

from __future__ import annotations

import gc
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Timing:
    """Seconds of every timed run of one measurement."""

    seconds: tuple[float, ...]

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)

    def percentile(self, q: float) -> float:
        return float(np.percentile(self.seconds, q))

    def ms(self) -> dict[str, float]:
        """Median, p50, p90, p99 and min in milliseconds, and how many runs: the JSON form of a latency."""
        return {
            "median_ms": self.median * 1e3,
            "p50_ms": self.percentile(50) * 1e3,
            "p90_ms": self.percentile(90) * 1e3,
            "p99_ms": self.percentile(99) * 1e3,
            "min_ms": min(self.seconds) * 1e3,
            "runs": len(self.seconds),
        }


def measure(fn: Callable[[], object], repeats: int, warmup: int = 1) -> Timing:
    """Times `fn()` `repeats` times after `warmup` untimed calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return Timing(tuple(out))


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    """numerator / denominator, None when either is missing or the denominator is not positive."""
    if numerator is None or denominator is None or denominator <= 0:
        return None
    return numerator / denominator


def pin_threads(ort_threads: int, faiss_threads: int, cv2_threads: int) -> dict[str, int]:
    """Sets FAISS's and OpenCV's thread counts (onnxruntime's is per session: `Embedder(threads=...)`)."""
    import cv2

    from index.store import set_threads

    set_threads(faiss_threads)
    cv2.setNumThreads(cv2_threads)
    return {"onnxruntime_intra_op": ort_threads, "faiss_omp": faiss_threads, "opencv": cv2_threads}


def rss_bytes() -> int:
    """Resident memory of this process now (Linux), 0 where /proc is missing."""
    try:
        return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _libc():
    import ctypes

    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def return_freed_memory() -> None:
    """Makes glibc hand every allocation over 1 MB straight back to the system when freed (a fixed mmap
    threshold instead of its adaptive one), so that the resident size measures what is alive."""
    libc = _libc()
    if libc is not None:
        libc.mallopt(-3, 1 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 1 << 20)  # M_TRIM_THRESHOLD


def live_bytes() -> int:
    """Resident memory after giving freed heap pages back (glibc `malloc_trim`): what new allocations will
    add to, even after earlier sections freed a lot."""
    gc.collect()
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
    return rss_bytes()


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_gb() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=5
        )
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def machine() -> dict[str, object]:
    """Cores, CPU, memory, load and library versions: what the numbers depend on."""
    import cv2
    import faiss
    import onnxruntime

    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "memory_gb": _memory_gb(),
        "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
        "python": platform.python_version(),
        "numpy": np.__version__,
        "onnxruntime": onnxruntime.__version__,
        "faiss": faiss.__version__,
        "opencv": cv2.__version__,
        "git_commit": _git_commit(),
    }
