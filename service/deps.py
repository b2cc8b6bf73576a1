"""Dependencies of the routes: the loaded state, and the API key for writes.

Writes (POST /objects, DELETE /objects/{id}) need the API key when one is set. Without one they are open
on a loopback address only: a server that other hosts can reach refuses them (403) unless the operator
opts in with `allow_open_writes`, so a forgotten key does not leave the store open to the network."""

from __future__ import annotations

import ipaddress
import secrets
from typing import Annotated, Any
from urllib.parse import urlsplit

from fastapi import Depends, Header, Request
from fastapi.dependencies.models import Dependant

from service.errors import ApiError
from service.settings import Settings
from service.state import AppState


async def get_state(request: Request) -> AppState:
    # async, as every dependency of `POST /recognize` that does no blocking work: FastAPI runs a plain
    # `def` dependency on its thread pool, a hop to another thread and back for each request. This one
    # and the form's as `def` took 1.2 ms a request more over HTTP (client p50 7.3 against 6.1 ms and
    # as much more server CPU; `posedesc serve` with the pipeline's answer canned, 5 interleaved rounds of
    # 400 requests; the shared 2-core machine)
    state = getattr(request.app.state, "posedesc", None)
    if state is None:
        raise ApiError(503, "the service is starting")
    return state


StateDep = Annotated[AppState, Depends(get_state)]


def public(host: str | None) -> bool:
    """Whether a server listening on `host` is reachable from other hosts: any IP address but a loopback
    one (0.0.0.0 and :: are every interface). Not an IP (TestClient's "testserver"): not judged public."""
    try:
        return not ipaddress.ip_address(host or "").is_loopback
    except ValueError:
        return False


def host_of(url: str | None) -> str | None:
    return urlsplit(url).hostname if url else None


def open_writes_refused(settings: Settings, host: str | None) -> str | None:
    """Why writes are refused on a server listening on `host`, or None when they are allowed."""
    if settings.api_key is not None or settings.allow_open_writes or not public(host):
        return None
    return (
        f"writes are refused: the server listens on {host} without an API key; set POSEDESC_API_KEY "
        "(clients send it as X-API-Key), or POSEDESC_ALLOW_OPEN_WRITES=1 to let anyone who can reach "
        "the server register and delete objects"
    )


def require_api_key(
    request: Request,
    state: StateDep,
    x_api_key: Annotated[str | None, Header(description="the API key, when the service has one")] = None,
) -> None:
    key = state.settings.api_key
    if key is None:
        # Where `posedesc serve` listens; under another server (`uvicorn service.main:app`), the local
        # address this request came in on, which is public only if the server listens on one.
        host = host_of(request.app.state.url) or (request.scope.get("server") or (None,))[0]
        if (reason := open_writes_refused(state.settings, host)) is not None:
            raise ApiError(403, reason)
        return
    if x_api_key is None or not secrets.compare_digest(x_api_key.encode(), key.get_secret_value().encode()):
        raise ApiError(401, "missing or wrong API key (send it as the X-API-Key header)")


ApiKeyDep = Annotated[None, Depends(require_api_key)]


async def known_fields(request: Request) -> None:
    """422 naming any form field the route does not take (`image` for `rgb`): FastAPI would ignore it,
    and the answer would then be about what is missing, not about what was misnamed; and any field sent
    more than once. The accepted names are the route's own form parameters, so they cannot drift from the
    signature."""
    dependant = getattr(request.scope.get("route"), "dependant", None)
    accepted = [f.alias for f in _body_params(dependant)] if dependant is not None else []
    # FastAPI has parsed the form already (Starlette keeps it on the request): this reads no body again
    form = await request.form()
    unknown = sorted({k for k in form if k not in accepted})
    if unknown:
        names = ", ".join(f"`{k}`" for k in unknown)
        raise ApiError(
            422,
            f"unexpected form field{'s' if len(unknown) > 1 else ''} {names}; "
            f"this endpoint takes {', '.join(accepted)}",
        )
    # a field sent twice would be read as one of its values, silently: which one is the user's?
    twice = sorted({k for k in form if len(form.getlist(k)) > 1})
    if twice:
        raise ApiError(
            422,
            f"form field{'s' if len(twice) > 1 else ''} {', '.join(twice)} sent more than once: send each once",
        )


def _body_params(dependant: Dependant) -> list[Any]:  # FastAPI's ModelField, which it does not export
    """A route's form fields, those of the dependencies it shares with other routes (`/recognize`'s form)
    first, then its own."""
    return [*(p for d in dependant.dependencies for p in _body_params(d)), *dependant.body_params]


KnownFieldsDep = Depends(known_fields)
