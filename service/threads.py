"""The thread pools the service's work runs on, each thread with FAISS's and OpenCV's thread counts set.

`faiss.omp_set_num_threads` sets OpenMP's count for the calling thread only (each thread has its own
OpenMP settings; a thread that never set it gets the default, one per core), so setting it once at
start-up left every request thread searching with all cores. Each pool therefore sets it in its
initializer, in every thread it starts; OpenCV's count (`cv2.setNumThreads`, process-wide) with it."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2

from index.store import set_threads


def limit_threads(n: int) -> None:
    """FAISS (OpenMP, this thread) and OpenCV use `n` threads per call: two cores serve concurrent
    requests better one each than every call spreading over both."""
    set_threads(n)
    cv2.setNumThreads(max(1, int(n)))


def worker_pool(workers: int, name: str, threads: int) -> ThreadPoolExecutor:
    """`workers` threads named `name`_i, each limited to `threads` FAISS and OpenCV threads per call."""
    return ThreadPoolExecutor(workers, name, initializer=limit_threads, initargs=(threads,))
