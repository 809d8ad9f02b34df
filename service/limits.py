"""The request gate (pure ASGI middleware): what every request passes before a handler runs.

On the headers alone, before one byte of the body is read:
  1. the bearer token, when the service has one (every path but `PUBLIC_PATHS`): 401;
  2. the Content-Type of a request that carries a body, against every type some endpoint takes: 415
     (each endpoint then checks its own, `deps.raw_body`);
  3. the declared Content-Length against `max_upload_bytes`: 413.
Then the body streams through to the app, counted against the same limit (a chunked upload that
grows beyond it: 413), so every endpoint, JSON ones included, is covered and the gate holds none of it.

A refusal before the body was read closes the connection (`Connection: close`): the unread body
would otherwise be taken for the next request. An exception that escapes the app is answered here
(a 500 naming it) instead of by Starlette's outermost handler, which answers and then re-raises, so
that uvicorn drops the keep-alive connection without saying so and the client's next request on it
fails with a reset.
"""

from __future__ import annotations

import secrets

from .errors import (
    BadRequestError,
    PayloadTooLargeError,
    ServiceError,
    UnauthorizedError,
    UnsupportedMediaTypeError,
    response_for,
)
from .logs import REQUEST_ID, request_id_from

# After refusing a body, keep reading (and discarding) up to this many bytes so that the client, still
# sending, gets the answer instead of a reset connection; beyond it the connection is simply closed.
_DRAIN_FACTOR = 4

# Paths anyone may call with a token set: probes for a load balancer, the viewer page (its data
# calls carry the token) and the API's documentation.
PUBLIC_PATHS = frozenset({"/health/live", "/health/ready", "/", "/view", "/docs", "/docs/oauth2-redirect", "/redoc",
                          "/openapi.json"})


def bearer_refusal(authorization: bytes, token: bytes) -> UnauthorizedError | None:
    """The 401 an Authorization header value calls for against the service's token (None: it passes)."""
    scheme, _, given = authorization.partition(b" ")
    if scheme.lower() != b"bearer" or not given.strip():
        return UnauthorizedError("this service needs a bearer token: send 'Authorization: Bearer <token>'")
    if not secrets.compare_digest(given.strip(), token):
        return UnauthorizedError("wrong bearer token: send the service's GARMENT_RENDER_TOKEN")
    return None


class RequestGate:
    def __init__(self, app, max_bytes: int, token: str | None, media_types: tuple[str, ...]):
        self.app, self.max_bytes = app, int(max_bytes)
        self.token = token.encode() if token else None
        self.media_types = frozenset(media_types)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers", ()))
        request_id = request_id_from(headers.get(b"x-request-id"))
        REQUEST_ID.set(request_id)   # every log line of this request carries it (logs.py)
        outer_send = send

        async def send(message):   # every answer says which request it is
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", ()), (b"x-request-id", request_id.encode())]}
            await outer_send(message)
        refusal, declared = self._check_headers(scope, headers)
        if refusal is not None:
            return await self._refuse(scope, receive, send, refusal, declared)

        # The body streams through to the app, counted against the limit as it comes: the gate holds
        # none of it. Past the limit the app's receive sees the client gone, whatever it answers to
        # that is dropped, and the gate answers 413.
        limit, total, over, more = self.max_bytes, 0, False, False

        async def counted():
            nonlocal total, over, more
            if over:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                total += len(message.get("body", b""))
                if total > limit:
                    over = True
                    more = message.get("more_body", False)
                    return {"type": "http.disconnect"}
            return message

        started = False

        async def tracked_send(message):
            nonlocal started
            if over:
                return   # the app's answer to a body cut short: replaced by the 413 below
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, tracked_send)
        except Exception as exc:  # noqa: BLE001 - answered here, on a connection that stays usable
            if started:
                raise
            if not over:
                return await self._answer(scope, receive, send, exc, close=False)
        if over and not started:
            exc = PayloadTooLargeError(self._too_large(scope, f"more than {limit} bytes streamed"))
            await self._refuse(scope, receive, send, exc, _DRAIN_FACTOR * limit - total if more else 0)

    def _check_headers(self, scope, headers: dict) -> tuple[ServiceError | None, int]:
        """The first refusal the headers call for (None: none) and the body bytes to drain after it."""
        if self.token is not None and scope.get("path", "") not in PUBLIC_PATHS:
            refusal = bearer_refusal(headers.get(b"authorization", b""), self.token)
            if refusal is not None:
                return refusal, 0
        declared = None
        if b"content-length" in headers:
            try:
                declared = int(headers[b"content-length"])
            except ValueError:
                return BadRequestError(f"bad Content-Length header {headers[b'content-length']!r}"), 0
            if declared < 0:
                return BadRequestError(f"bad Content-Length header {declared}"), 0
        has_body = (declared or 0) > 0 or b"chunked" in headers.get(b"transfer-encoding", b"").lower()
        if has_body:
            media = headers.get(b"content-type", b"").split(b";")[0].strip().lower().decode("latin-1")
            if media not in self.media_types:
                return UnsupportedMediaTypeError(
                    f"Content-Type {media or '(none)'!r} is not one this service takes; the endpoints take "
                    f"{', '.join(sorted(self.media_types))} (see /docs for which takes which)"), 0
        if declared is not None and declared > self.max_bytes:
            drain = declared if declared <= _DRAIN_FACTOR * self.max_bytes else 0
            return PayloadTooLargeError(self._too_large(scope, f"Content-Length {declared}")), drain
        return None, 0

    def _too_large(self, scope, how: str) -> str:
        return (f"request body too large ({how}); the limit is {self.max_bytes} bytes (GARMENT_RENDER_MAX_UPLOAD_BYTES)"
                + ("; split a batch into several requests" if "/batch" in scope.get("path", "") else ""))

    async def _refuse(self, scope, receive, send, exc: ServiceError, drain: int) -> None:
        if drain > 0:
            await self._drain(receive, drain)
        await self._answer(scope, receive, send, exc, close=True)

    @staticmethod
    async def _drain(receive, budget: int) -> None:
        while budget > 0:
            message = await receive()
            if message["type"] != "http.request":
                return
            budget -= len(message.get("body", b""))
            if not message.get("more_body", False):
                return

    @staticmethod
    async def _answer(scope, receive, send, exc: BaseException, close: bool) -> None:
        response = response_for(exc)
        if close:
            response.headers["Connection"] = "close"
        app = scope.get("app")
        metrics = getattr(getattr(app, "state", None), "metrics", None)
        if metrics is not None:
            code = exc.code if isinstance(exc, ServiceError) else "internal"
            metrics.errors.labels(str(response.status_code), code).inc()
        await response(scope, receive, send)
