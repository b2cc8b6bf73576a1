"""Start-up work before /readyz says ready: templates a changed model lacks, and the demo objects.

The demo objects are generated shapes (`index.templates.shapes.demo_shapes`), registered through the same code path
as `POST /objects`, so the README's first `POST /recognize` finds them: once, and only into a data dir
that has never held an object (`Store.has_held_objects`), so they never mix with a user's objects, nor
come back after the user removed every object. Their names start with `DEMO_PREFIX`, and `DELETE
/objects?demo=true` removes them all."""

from __future__ import annotations

import logging

from index.store import NameTaken
from index.templates.register import reembed
from service.state import AppState

log = logging.getLogger("service")

SEEDED = "demo_seeded"
DEMO_KEY = "demo"  # in a demo object's record (`ObjectRecord.extra`): `GET /objects` marks it
#: before a demo object's name ("demo-robot"): a user's own "duck" never meets a demo one
DEMO_PREFIX = "demo-"
SEEDING = "demo_seeding"  # set before the first demo object: a seeding cut short goes on at the next start


def startup(state: AppState) -> None:
    """Runs on the registration thread; sets `state.ready` when done (also after a failure, logged)."""
    try:
        made = reembed(state.store, state.worker, state.embedders, state.templates, state.embed_pool)
        if made:
            log.info("made templates again for %d (object, model) pairs", made)
        if state.settings.demo_objects:
            seed(state)
        state.warm(state.store.snapshot.objects)  # the registered objects' pose fit models, ahead of queries
    except Exception as e:  # the service still serves what it has; /readyz shows the reason
        log.exception("start-up work failed")
        state.startup_error = f"start-up work failed: {e}"
    finally:
        state.ready.set()


def seed(state: AppState) -> None:
    store = state.store
    if store.get_meta(SEEDED):
        return
    if not store.get_meta(SEEDING):
        if store.has_held_objects():
            log.info("no demo objects: %s holds or has held objects", state.settings.data_dir)
            return
        store.set_meta(SEEDING, "1")
    from index.templates.shapes import demo_shapes

    present = {r.name for r in store.snapshot.objects.values()}
    for shape, mesh in demo_shapes().items():
        name = DEMO_PREFIX + shape
        if state.stopping.is_set():
            return
        if name in present:
            continue
        try:
            reg = state.register_mesh(mesh, name, "none", extra={DEMO_KEY: True})
        except NameTaken:  # another replica of a shared store seeding at the same time
            continue
        state.metrics.observe_registration(reg.timings)
        log.info("demo object %s registered in %.2f s", name, reg.timings["total"])
    store.set_meta(SEEDED, "1")
