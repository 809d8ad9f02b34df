"""Every error the service answers with, and the one place that maps errors to HTTP.

Renderer errors (`renderer.errors`) and service errors become a JSON body
`{"detail": "<what was wrong and what to do>", "code": "<machine-readable kind>"}` with a 4xx/5xx status.
Handlers raise; they never build error responses themselves.
"""

from __future__ import annotations

import json
import logging
import math

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from renderer.errors import (
    EnvironmentMapError,
    GLContextError,
    InvalidInputError,
    MaterialError,
    MeshError,
    RenderError,
    ShaderError,
)

log = logging.getLogger("service")


class ServiceError(Exception):
    """Base of the errors the service raises on purpose; `status` and `code` say how it is answered."""

    status = 500
    code = "internal"

    def __init__(self, message: str, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.headers = headers or {}


class BadRequestError(ServiceError):
    status, code = 400, "bad_request"


class UnauthorizedError(ServiceError):
    status, code = 401, "unauthorized"

    def __init__(self, message: str):
        super().__init__(message, {"WWW-Authenticate": "Bearer"})


class NotFoundError(ServiceError):
    status, code = 404, "not_found"


class NotAcceptableError(ServiceError):
    status, code = 406, "not_acceptable"


class ConflictError(ServiceError):
    status, code = 409, "conflict"


class PayloadTooLargeError(ServiceError):
    status, code = 413, "too_large"


class UnsupportedMediaTypeError(ServiceError):
    status, code = 415, "unsupported_media_type"


class InvalidRequestError(ServiceError):
    """Well-formed HTTP whose content the service cannot use (a service-side check, not the renderer's)."""

    status, code = 422, "invalid_input"


class QueueFullError(ServiceError):
    status, code = 503, "queue_full"

    def __init__(self, message: str, retry_after_s: int):
        super().__init__(message, {"Retry-After": str(max(1, int(math.ceil(retry_after_s))))})
        self.retry_after_s = retry_after_s


class NotReadyError(ServiceError):
    status, code = 503, "not_ready"

    def __init__(self, message: str):
        super().__init__(message, {"Retry-After": "5"})


class ReplicaLostError(ServiceError):
    """Scale-out (service/ray_serve.py): the replica holding the request went before it answered, and
    the request could not be sent again (a scene's registration, or no replica answered in time)."""

    status, code = 503, "replica_lost"

    def __init__(self, message: str):
        super().__init__(message, {"Retry-After": "1"})


class RenderTimeoutError(ServiceError):
    status, code = 504, "timeout"


class ClientGoneError(ServiceError):
    """The client closed its connection before the answer (nginx's 499): nothing is sent; counted."""

    status, code = 499, "client_closed_request"


def _renderer_status(exc: RenderError) -> tuple[int, str]:
    # Order matters: the most specific class first.
    if isinstance(exc, EnvironmentMapError):
        return 422, "invalid_environment"
    if isinstance(exc, MeshError):
        return 422, "invalid_mesh"
    if isinstance(exc, MaterialError):   # a U3M fabric: its message names the file and the field
        return 422, "invalid_material"
    if isinstance(exc, InvalidInputError):
        return 422, "invalid_input"
    if isinstance(exc, GLContextError):
        return 503, "gl_unavailable"
    if isinstance(exc, ShaderError):
        return 500, "shader_error"
    return 500, "render_error"


def error_response(status: int, code: str, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": message, "code": code}, status_code=status, headers=headers)


def response_for(exc: BaseException) -> JSONResponse:
    """The HTTP answer of any exception (used by the handlers below and by the body-limit middleware)."""
    if isinstance(exc, ServiceError):
        return error_response(exc.status, exc.code, str(exc), exc.headers)
    if isinstance(exc, RenderError):
        status, code = _renderer_status(exc)
        if status >= 500:
            log.error("renderer error: %s", exc)
        return error_response(status, code, str(exc))
    log.exception("unexpected error", exc_info=exc)
    return error_response(500, "internal", f"internal error ({type(exc).__name__}: {exc}); the service is still up")


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(x) for x in err.get("loc", ()) if x != "body") or "body"
        parts.append(f"{loc}: {err.get('msg', 'invalid')}")
    more = len(exc.errors()) - 5
    return "invalid request: " + "; ".join(parts) + (f"; and {more} more" if more > 0 else "")


def count_error(app, response: JSONResponse, code: str) -> None:
    metrics = getattr(app.state, "metrics", None)
    if metrics is not None:
        metrics.errors.labels(str(response.status_code), code).inc()


def _allowed_methods(request: Request) -> list[str]:
    methods: set[str] = set()
    for route in request.app.routes:
        regex, route_methods = getattr(route, "path_regex", None), getattr(route, "methods", None)
        if regex is not None and route_methods and regex.match(request.url.path):
            methods |= set(route_methods)
    return sorted(methods)


def install_error_handlers(app: FastAPI) -> None:
    async def on_error(request: Request, exc: Exception) -> JSONResponse:
        response = response_for(exc)
        count_error(request.app, response, json.loads(response.body)["code"])
        return response

    async def on_validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        response = error_response(422, "invalid_request", _validation_message(exc))
        count_error(request.app, response, "invalid_request")
        return response

    async def on_http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no such endpoint: {request.method} {request.url.path} (see /docs)"
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 405:   # every method the path takes, not only its first route's
            headers["Allow"] = ", ".join(_allowed_methods(request))
            detail = f"{request.method} is not one of the methods of {request.url.path}: {headers['Allow']}"
        response = error_response(exc.status_code, code, detail, headers or None)
        count_error(request.app, response, code)
        return response

    async def on_disconnect(request: Request, exc: ClientDisconnect) -> JSONResponse:
        # Nothing went wrong here: the client left before its request was read (a simulator stopped,
        # a network dropped). One line, with the request id of the log context; no answer is read.
        log.info("client disconnected before its request was read: %s %s", request.method, request.url.path)
        response = error_response(400, "client_disconnected", "the client disconnected before the request was read")
        count_error(request.app, response, "client_disconnected")
        return response

    app.add_exception_handler(ClientDisconnect, on_disconnect)
    app.add_exception_handler(ServiceError, on_error)
    app.add_exception_handler(RenderError, on_error)
    app.add_exception_handler(RequestValidationError, on_validation)
    app.add_exception_handler(StarletteHTTPException, on_http)
    app.add_exception_handler(Exception, on_error)
