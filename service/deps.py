"""Dependencies of the routes: the loaded state, and the API key for writes."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Header, Request

from service.errors import ApiError
from service.state import AppState


def get_state(request: Request) -> AppState:
    state = getattr(request.app.state, "posedesc", None)
    if state is None:
        raise ApiError(503, "the service is starting")
    return state


StateDep = Annotated[AppState, Depends(get_state)]


def require_api_key(
    state: StateDep,
    x_api_key: Annotated[str | None, Header(description="the API key, when the service has one")] = None,
) -> None:
    key = state.settings.api_key
    if key is None:
        return
    if x_api_key is None or not secrets.compare_digest(x_api_key.encode(), key.get_secret_value().encode()):
        raise ApiError(401, "missing or wrong API key (send it as the X-API-Key header)")


ApiKeyDep = Annotated[None, Depends(require_api_key)]
