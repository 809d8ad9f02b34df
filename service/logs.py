"""Logging of the service: every line carries the id of the request it belongs to (the client's
`X-Request-Id` when it sends a usable one, else one made by the request gate, limits.py, and
answered in `X-Request-Id`), as text or, with GARMENT_RENDER_LOG_FORMAT=json, one JSON object a line.

    uvicorn.run(app, log_config=log_config("json", "info"))
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
from contextvars import ContextVar

REQUEST_ID: ContextVar[str] = ContextVar("request_id", default="-")

# `serve --ray`'s start-up line names its Ray instance (service/ray_serve.py, run), which another
# process on the machine reads back to reach that instance and no other (service/load.py, serve_ray).
RAY_ADDRESS_IN_LOG = re.compile(r"\(Ray at ([^)\s]+)\)")


_PROCESS: tuple[int, str] | None = None


def process_label() -> str:
    """This process's name in answers (`X-Render-Process`, /stats) and its log's start: 8 random hex
    digits made once a process (again in a forked child), so that a client can tell which process
    answered without learning its id on the host."""
    global _PROCESS
    if _PROCESS is None or _PROCESS[0] != os.getpid():
        _PROCESS = (os.getpid(), secrets.token_hex(4))
    return _PROCESS[1]


def ray_address_note(address: str) -> str:
    """The part of the start-up line that names the Ray instance's address (RAY_ADDRESS_IN_LOG reads it)."""
    return f"(Ray at {address})"


# What a client's own request id may be (it is echoed and logged): short, printable, no separators.
_CLIENT_ID = re.compile(r"^[A-Za-z0-9._:-]{1,64}$")


def request_id_from(header: bytes | None) -> str:
    """The client's id when usable, else a new one (16 hex digits)."""
    if header:
        text = header.decode("latin-1")
        if _CLIENT_ID.match(text):
            return text
    return secrets.token_hex(8)


class RequestIdFilter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        record.request_id = REQUEST_ID.get()
        return True


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out = {"time": self.formatTime(record, "%Y-%m-%dT%H:%M:%S"), "level": record.levelname.lower(),
               "logger": record.name, "request_id": getattr(record, "request_id", "-"), "message": record.getMessage()}
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out)


def log_config(fmt: str, level: str) -> dict:
    """A logging.config dict for uvicorn's and the service's loggers."""
    formatter = {"()": f"{__name__}.JsonFormatter"} if fmt == "json" else \
        {"format": "%(asctime)s %(levelname)s %(name)s [%(request_id)s] %(message)s"}
    handler = {"class": "logging.StreamHandler", "formatter": "main", "filters": ["request_id"],
               "stream": "ext://sys.stderr"}
    loggers = {name: {"handlers": ["main"], "level": level.upper(), "propagate": False}
               for name in ("uvicorn", "uvicorn.error", "uvicorn.access", "service", "renderer")}
    return {"version": 1, "disable_existing_loggers": False, "filters": {"request_id": {"()": f"{__name__}.RequestIdFilter"}},
            "formatters": {"main": formatter}, "handlers": {"main": handler}, "loggers": loggers}
