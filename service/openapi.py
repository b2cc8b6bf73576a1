"""The OpenAPI schema, with optional multipart fields written as they are on the wire.

FastAPI writes an optional form field (`X | None = None`) as `anyOf: [X, {"type": "null"}]`. A multipart
form cannot carry a null: the field is simply left out. Clients generated from the schema, and fuzzers
(schemathesis), then do not see that `rgb` or `depth` is a file and send it as text. So in multipart
bodies the null branch is dropped (such a field is not required, which is what optional means there),
and file fields also say `format: binary`, OpenAPI 3.0's spelling, which most client generators know."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI


def install(app: FastAPI) -> None:
    default = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            _no_null_in_multipart(default())  # FastAPI caches it in app.openapi_schema
        return app.openapi_schema  # type: ignore[return-value]

    app.openapi = openapi  # type: ignore[method-assign]


def _no_null_in_multipart(schema: dict[str, Any]) -> None:
    components = schema.get("components", {}).get("schemas", {})
    for operations in schema.get("paths", {}).values():
        for op in operations.values():
            body = op.get("requestBody", {}).get("content", {}).get("multipart/form-data", {})
            ref = body.get("schema", {}).get("$ref", "")
            form = components.get(ref.rsplit("/", 1)[-1], {})
            for name, prop in form.get("properties", {}).items():
                branches = [b for b in prop.get("anyOf", []) if b != {"type": "null"}]
                if len(branches) == 1 and len(prop["anyOf"]) == 2:
                    prop = {**branches[0], **{k: v for k, v in prop.items() if k != "anyOf"}}
                if prop.get("contentMediaType") == "application/octet-stream":
                    prop["format"] = "binary"
                form["properties"][name] = prop
