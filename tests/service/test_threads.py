"""FAISS's and OpenCV's thread counts hold in the threads that do the work, not only in the one that
started the service: OpenMP's count is per thread, so each pool sets it as it starts a thread."""

from __future__ import annotations

import threading

import cv2
import faiss
import trimesh
from fastapi.testclient import TestClient
from service_helpers import patch_files, service_settings, wait_ready

import service.answers
from service.main import create_app
from service.state import close_state, load_state


def counts() -> tuple[int, int]:
    return faiss.omp_get_max_threads(), cv2.getNumThreads()


def unlike_the_default() -> int:
    """A thread count no fresh thread has by default, so a pass means it was set."""
    seen: list[int] = []
    t = threading.Thread(target=lambda: seen.append(faiss.omp_get_max_threads()))
    t.start()
    t.join()
    return seen[0] + 1


def test_every_pool_thread_uses_the_set_thread_counts(tmp_path, posedesc_models):
    n = unlike_the_default()
    state = load_state(service_settings(tmp_path, posedesc_models, threads=n))
    try:
        for pool in (state.recognizer, state.registrar, state.embed_pool, state.mesh_loader):
            assert pool.submit(counts).result() == (n, n), pool
    finally:
        close_state(state)


def test_recognitions_run_in_those_threads(tmp_path, posedesc_models, monkeypatch):
    n = unlike_the_default()
    real, seen = service.answers.recognise, []

    def observed(state, q):  # the route's own function, run where the route runs it
        seen.append((threading.current_thread().name, *counts()))
        return real(state, q)

    monkeypatch.setattr(service.answers, "recognise", observed)
    with TestClient(create_app(service_settings(tmp_path, posedesc_models, threads=n))) as c:
        wait_ready(c)
        for files in patch_files().values():
            assert c.post("/recognize", files=files).status_code == 200
    assert len(seen) == 3 and all(name.startswith("recognise") for name, *_ in seen), seen
    assert {tuple(c) for _, *c in seen} == {(n, n)}


def test_the_warm_up_skips_an_object_deleted_before_its_turn(tmp_path, posedesc_models):
    """The fit models made ahead of queries (`AppState.warm`): an object deleted before its turn (here:
    never registered) gets none, where they would be made for nothing and kept until the cache dropped them."""
    state = load_state(service_settings(tmp_path, posedesc_models))
    try:
        gone = max(state.store.snapshot.objects, default=0) + 1000
        state.warm([gone], {gone: trimesh.creation.box(extents=(60.0, 40.0, 20.0))})
        state.fitter.submit(lambda: None).result()  # its jobs, in order, done
        assert gone not in state.draw_meshes and gone not in state.surfaces
        assert all(gone not in cache for cache in state.shapes.needed(state.embedders))
    finally:
        close_state(state)
