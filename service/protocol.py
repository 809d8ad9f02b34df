"""uvicorn's h11 protocol with a deadline for a request's headers: a connection that opens and does
not complete a request line and headers within GARMENT_RENDER_HEADER_TIMEOUT_S (after it opened, or
after its last answer) is closed. Without it, a client that connects and sends nothing, or one byte
at a time, holds a connection for ever (1,000 such stayed open); uvicorn's keep-alive timeout stops
at the first byte received."""

from __future__ import annotations

import asyncio
import functools

from uvicorn.protocols.http.h11_impl import H11Protocol


@functools.cache
def _header_timeout_s() -> float:
    # Read once per process, from the environment (each uvicorn worker process reads its own).
    from .settings import ServiceSettings

    return ServiceSettings().header_timeout_s


class HeaderTimeoutProtocol(H11Protocol):
    header_timeout_s: float | None = None   # None: GARMENT_RENDER_HEADER_TIMEOUT_S

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._headers_deadline: asyncio.TimerHandle | None = None
        self._arm()

    def _arm(self) -> None:
        self._disarm()
        timeout = self.header_timeout_s if self.header_timeout_s is not None else _header_timeout_s()
        self._headers_deadline = self.loop.call_later(timeout, self._headers_overdue)

    def _disarm(self) -> None:
        if getattr(self, "_headers_deadline", None) is not None:
            self._headers_deadline.cancel()
            self._headers_deadline = None

    def _headers_overdue(self) -> None:
        self._headers_deadline = None
        if self.cycle is None or self.cycle.response_complete:   # no request under way: headers are late
            self.transport.close()

    def handle_events(self) -> None:
        before = self.cycle
        super().handle_events()
        if self.cycle is not before and self.cycle is not None:   # a request's headers arrived
            self._disarm()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._arm()   # the next request on this connection has the same deadline

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)
