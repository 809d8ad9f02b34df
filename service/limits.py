"""Request-body limit (pure ASGI middleware): refuses a body whose Content-Length, or whose streamed
size (chunked uploads), exceeds `max_upload_bytes`, before any handler reads it. The body is read
here once and replayed to the app, so every endpoint, JSON ones included, is covered."""

from __future__ import annotations

from .errors import BadRequestError, PayloadTooLargeError, response_for

# After refusing, keep reading (and discarding) up to this many bytes so that the client, still
# sending, gets the 413 instead of a reset connection; beyond it the connection is simply closed.
_DRAIN_FACTOR = 4


class BodyLimitMiddleware:
    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, int(max_bytes)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        limit = self.max_bytes
        declared = None
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    return await response_for(BadRequestError(f"bad Content-Length header {value!r}"))(
                        scope, receive, send)
        if declared is not None and declared > limit:
            if declared <= _DRAIN_FACTOR * limit:
                await self._drain(receive, declared)
            return await self._refuse(scope, receive, send, declared, declared=True)

        chunks, total, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return  # the client went away; nothing to answer
            body = message.get("body", b"")
            total += len(body)
            more = message.get("more_body", False)
            if total > limit:
                if more:
                    await self._drain(receive, _DRAIN_FACTOR * limit - total)
                return await self._refuse(scope, receive, send, total, declared=False)
            chunks.append(body)
        body = b"".join(chunks)
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    async def _drain(self, receive, budget: int) -> None:
        while budget > 0:
            message = await receive()
            if message["type"] != "http.request":
                return
            budget -= len(message.get("body", b""))
            if not message.get("more_body", False):
                return

    async def _refuse(self, scope, receive, send, size: int, declared: bool) -> None:
        how = f"Content-Length {size}" if declared else f"more than {self.max_bytes} bytes streamed"
        exc = PayloadTooLargeError(
            f"request body too large ({how}); the limit is {self.max_bytes} bytes (GARMENT_RENDER_MAX_UPLOAD_BYTES)"
            + ("; split a batch into several requests" if "/batch" in scope.get("path", "") else ""))
        response = response_for(exc)
        response.headers["Connection"] = "close"
        app = scope.get("app")
        metrics = getattr(getattr(app, "state", None), "metrics", None)
        if metrics is not None:
            metrics.errors.labels("413", exc.code).inc()
        await response(scope, receive, send)
