"""The OpenAPI document as the service answers: every error body is `{"detail", "code"}`
(errors.py), every status the gate and the handlers can answer is listed, and bearer auth is
declared only when the service has a token."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

ERROR_BODY = {
    "title": "ErrorBody", "type": "object", "required": ["detail", "code"],
    "properties": {"detail": {"type": "string", "description": "what was wrong and what to do"},
                   "code": {"type": "string", "description": "machine-readable kind (errors.py)"}},
}

# Every status the request gate (limits.py) or a handler may answer, on any operation.
ERROR_STATUSES = {
    "400": "malformed request (a bad Content-Length)",
    "404": "unknown id, or no such endpoint",
    "409": "a limit of held objects is reached, or the object is in use",
    "413": "the body, a mesh or a map is larger than its limit",
    "415": "a Content-Type this endpoint does not take",
    "422": "well-formed but unusable input; the detail names the problem and the limit",
    "500": "an unforeseen failure; the service is still up",
    "503": "not ready, busy or the queue is full (Retry-After says when to try again)",
    "504": "no answer from the render thread in time",
}


def install_openapi(app: FastAPI, token_set: bool) -> None:
    def openapi() -> dict:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = get_openapi(title=app.title, version=app.version, summary=app.summary, routes=app.routes)
        components = doc.setdefault("components", {})
        schemas = components.setdefault("schemas", {})
        schemas["ErrorBody"] = ERROR_BODY
        for name in ("HTTPValidationError", "ValidationError"):
            schemas.pop(name, None)
        ref = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
        statuses = dict(ERROR_STATUSES)
        if token_set:
            statuses["401"] = "missing or wrong bearer token"
        else:
            components.pop("securitySchemes", None)
        for path in doc.get("paths", {}).values():
            for op in path.values():
                if not token_set:
                    op.pop("security", None)
                for param in op.get("parameters", []):   # a parameter is absent or has a value, never null
                    _drop_null(param.get("schema", {}))
                responses = op.setdefault("responses", {})
                for status, text in statuses.items():
                    entry = responses.setdefault(status, {"description": text})
                    entry["content"] = ref
        if not components.get("schemas"):
            components.pop("schemas", None)
        app.openapi_schema = doc
        return doc

    app.openapi = openapi


def _drop_null(schema: dict) -> None:
    branches = schema.get("anyOf")
    if branches and any(b.get("type") == "null" for b in branches):
        kept = [b for b in branches if b.get("type") != "null"]
        del schema["anyOf"]
        if len(kept) == 1:
            schema.update(kept[0])
        else:
            schema["anyOf"] = kept
