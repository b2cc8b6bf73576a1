"""The FastAPI app: the lifespan loads models, stores and the render thread onto `app.state.posedesc`."""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi_offline import FastAPIOffline

from index.store.search import Snapshot
from service import errors, openapi
from service.demo import DEMO_KEY, startup
from service.deps import host_of, open_writes_refused, public
from service.inputs.limits import BodyLimit
from service.metrics import Observe
from service.pipeline.calibration import stale
from service.routes import health, jobs, objects, page, recognize
from service.settings import Settings, unknown_variables
from service.state import AppState, close_state, load_state

DESCRIPTION = """Recognises known 3-D objects in images and tells from which viewpoint they are seen
(Wohlhart & Lepetit, CVPR 2015: learnt descriptors, nearest templates). Register a mesh with
`POST /objects`, then `POST /recognize` a patch or a frame. Angles are degrees: azimuth about the
object's +z from +x towards +y, elevation above its xy plane, in-plane counter-clockwise in the image."""


DOCS_ASSETS = "/docs-assets"


log = logging.getLogger("service")


def create_app(settings: Settings | None = None, url: str | None = None) -> FastAPI:
    """`url`: where the server listens (`posedesc serve` binds it first), for the log and the write guard."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if (reason := open_writes_refused(settings, host_of(url))) is not None:
            log.warning("%s", reason)
        elif settings.api_key is None and public(host_of(url)):
            log.warning(
                "writes are open to anyone who can reach %s (POSEDESC_ALLOW_OPEN_WRITES, no API key)", url
            )
        if unknown := unknown_variables(os.environ):
            log.warning(
                "%s: no such setting, ignored (the settings: docs/service.md; tuning constants live in their "
                "stage modules)",
                ", ".join(unknown),
            )
        state = await run_in_threadpool(load_state, settings)
        for problem in stale(settings, state.embedders).values():  # also in GET /readyz
            log.warning("%s: its rejection and confidences were measured on other scores", problem)
        app.state.posedesc = state
        state.registrar.submit(startup, state)
        announcer = asyncio.create_task(announce_ready(state, url))
        try:
            yield
        finally:
            announcer.cancel()
            app.state.posedesc = None
            await run_in_threadpool(close_state, state)

    # /docs and /redoc load Swagger UI and ReDoc from the installed fastapi-offline package (served under
    # DOCS_ASSETS), not from a CDN: they work on a machine without internet. No validator badge: Swagger UI
    # would send the schema's URL to validator.swagger.io.
    app = FastAPIOffline(
        title="posedesc",
        version="0.1.0",
        description=DESCRIPTION,
        lifespan=lifespan,
        responses=errors.responses(500, 503),  # any route: a bug; while starting or stopping
        static_url=DOCS_ASSETS,
        swagger_ui_parameters={"validatorUrl": None},
    )
    app.state.settings = settings
    app.state.url = url
    errors.install(app)
    openapi.install(app)
    for r in (recognize.router, objects.router, jobs.router, health.router, page.router):
        app.include_router(r)

    app.add_middleware(Observe)

    def limit_for(path: str) -> int | None:
        if path.startswith("/objects"):
            return int(settings.max_mesh_mb * 1e6)
        if path.startswith("/recognize"):
            return int(settings.max_image_mb * 1e6)
        return None

    app.add_middleware(BodyLimit, limit_for=limit_for)
    return app


async def announce_ready(state: AppState, url: str | None) -> None:
    """One log line once /readyz answers 200 (the start-up work may take a while after uvicorn's own
    start-up lines: a changed model's templates, the demo objects): `ready_line`."""
    while not state.ready.is_set():
        await asyncio.sleep(0.05)
    log.info("%s", ready_line(state.store.snapshot, url, state.startup_error))


def ready_line(snap: Snapshot, url: str | None, startup_error: str | None = None) -> str:
    """Where, and what is served: the objects (the demo ones named, with how to be rid of them: they answer
    for a user's frames too) and the templates each model searches, in-plane variants included."""
    where = url or ""
    demo = sorted((r.name, oid) for oid, r in snap.objects.items() if r.extra.get(DEMO_KEY))
    objects = f"{len(snap.objects)} objects"
    if demo:
        named = ", ".join(f"{name} ({oid})" for name, oid in demo)
        objects += (
            f" ({len(demo)} of them demo objects, which answer for your frames too: {named}; remove them all "
            f"for good with `curl -X DELETE '{where or 'URL'}/objects?demo=true'` (one: "
            f"`curl -X DELETE {where or 'URL'}/objects/ID`), or serve a new data dir with "
            "`posedesc serve --no-demo` or POSEDESC_DEMO_OBJECTS=false)"
        )
    templates = ", ".join(f"{m} {mi.size}" for m, mi in sorted(snap.models.items()))
    failed = f"; {startup_error}" if startup_error else ""
    return (
        f"ready{f' on {where}' if where else ''}: {objects}; templates searched (all objects, viewpoints x "
        f"in-plane angles): {templates}{failed}"
    )


app = create_app()  # `uvicorn service.main:app`; `posedesc serve` builds its own from its arguments
