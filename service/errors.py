"""Every error the API returns is JSON `{"detail": "<one line>"}` with a 4xx code; 507 when the disk is full
(nothing was changed), 503 while starting or overloaded, a 500 only as a last resort. The OpenAPI schema
documents exactly these (`responses`), so a client can rely on the shape of every answer."""

from __future__ import annotations

import errno
import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from index.store.records import StoreError
from service.schemas import ErrorOut

log = logging.getLogger("service")

# What a write that hit a full disk answers: the store rolled it back (index/store/__init__.py).
DISK_FULL = "the server's disk is full: nothing was changed; retry once space is freed"

MEANING = {
    400: "a malformed request body (not multipart form data)",
    401: "missing or wrong API key",
    403: "writes are refused: the server listens on a public address without an API key",
    404: "unknown id",
    409: "an object of that name exists already (its id is in `detail`)",
    413: "request body or image over the limit",
    422: "bad input: what is wrong is in `detail`",
    500: "internal error (a bug)",
    503: "the service is starting or too busy, or its template store does not answer; retry later",
    507: "the server's disk is full; nothing was changed",
}


def responses(*codes: int) -> dict[int | str, dict]:
    """OpenAPI entries for these error codes, all `{"detail": "..."}`. Naming 422 here also replaces
    FastAPI's default 422 schema (a list of field errors), which is not what the handler below sends."""
    return {code: {"model": ErrorOut, "description": MEANING[code]} for code in codes}


class ApiError(Exception):
    """Bad input or an unknown resource: its status code and a message that says what is wrong."""

    def __init__(self, status_code: int, detail: str):
        super().__init__(detail)
        self.status_code, self.detail = status_code, detail


class NoSuchWindow(ApiError):
    """A 422 for a patch whose window no registered object of the model asked has. A part of a mixed store
    (`service.recognition`) may refuse a patch so while the other part has the window and refuses it for a
    reason of its own: that reason is the one to tell."""

    def __init__(self, detail: str):
        super().__init__(422, detail)


class NothingMeasured(ApiError):
    """A 422 for a place in the frame where nothing can be measured: no depth around it, a depth patch all
    zero, a distance no camera or window allows. Sent by the user it is bad input; at a place the service
    chose itself (a detection's proposal) it means that nothing is there, and only this error does: any
    other error while verifying a proposal is a failure, not an answer."""

    def __init__(self, detail: str):
        super().__init__(422, detail)


def _where(loc: tuple) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or "request"


def install(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def api_error(request: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's default is a list of dicts; one readable line per field is what a person wants.
        msgs = [f"{_where(tuple(e.get('loc', ())))}: {e.get('msg', 'invalid')}" for e in exc.errors()]
        return JSONResponse({"detail": "; ".join(msgs)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return JSONResponse(
            {"detail": str(exc.detail)}, status_code=exc.status_code, headers=getattr(exc, "headers", None)
        )

    @app.exception_handler(StoreError)
    async def store_down(request: Request, exc: StoreError) -> JSONResponse:
        # the Milvus store's server unreachable or restarting: nothing was changed, retry later
        log.warning("%s %s: %s", request.method, request.url.path, exc)
        return JSONResponse({"detail": str(exc)}, status_code=503)

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
            log.error("%s %s: %s", request.method, request.url.path, exc)
            return JSONResponse({"detail": DISK_FULL}, status_code=507)
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": f"internal error ({type(exc).__name__})"}, status_code=500)
