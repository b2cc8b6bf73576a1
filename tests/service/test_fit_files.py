"""The pose fit's colour models kept in the data dir (`index.refine.files`), as the service uses them: made
on the fit thread after a registration, read back by the next process, removed with their object."""

from __future__ import annotations

import numpy as np
import trimesh
from service_helpers import service_settings

from index.refine.colour import ColourModel
from service.state import close_state, load_state


def test_a_registered_object_s_colour_model_is_kept_and_read_back_by_the_next_process(
    tmp_path, posedesc_models, monkeypatch
):
    """The fit thread's colour model of a new object is kept in the data dir (`index.refine.files`); the next
    process reads it instead of making it again (0.2-0.5 s each); removing the object removes it."""
    settings = service_settings(tmp_path, posedesc_models, level=1)
    state = load_state(settings)
    try:
        oid = state.register_mesh(
            trimesh.creation.box(extents=(60.0, 40.0, 20.0)), "box", "none"
        ).record.object_id
        state.fitter.submit(lambda: None).result()  # the warm-up, done
        made = state.shapes.colour.get(oid)
        assert made is not None and state.fit_files.read(oid) is not None
    finally:
        close_state(state)

    def never(*_):
        raise AssertionError("made again")

    monkeypatch.setattr(ColourModel, "of", never)
    state = load_state(settings)
    try:
        kept = state.shapes.colour.get(oid)
        assert kept is not None and np.array_equal(kept.coords, made.coords)
        path = state.fit_files.path(oid)
        assert path is not None and path.is_file()
        assert state.remove(oid) and not path.exists() and not state.remove(oid)
    finally:
        close_state(state)
