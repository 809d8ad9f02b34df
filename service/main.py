"""Run the service: `python -m service.main [--host H] [--port P] [--workers N]`, or

    uvicorn service.app:create_app --factory --host 127.0.0.1 --port 8000

Settings come from GARMENT_RENDER_* environment variables (service/settings.py); --host/--port
override them. Each uvicorn worker process gets its own GL thread.
"""

from __future__ import annotations

import argparse
import os

import uvicorn

from .app import create_app
from .logs import log_config
from .protocol import HeaderTimeoutProtocol
from .settings import ServiceSettings


def serve(host: str | None = None, port: int | None = None, settings: ServiceSettings | None = None,
          workers: int = 1, log_level: str = "info") -> None:
    """Run uvicorn in this process (blocks). Several workers need the import string, so their
    settings travel through the environment."""
    settings = settings or ServiceSettings()
    host = host or settings.host
    port = settings.port if port is None else port
    if workers > 1:
        for name, value in settings.model_dump(exclude_none=True).items():
            if name == "token":
                value = settings.token.get_secret_value()
            os.environ.setdefault(f"GARMENT_RENDER_{name.upper()}", str(value))
        uvicorn.run("service.app:create_app", factory=True, host=host, port=port, workers=workers,
                    log_level=log_level, log_config=log_config(settings.log_format, log_level),
                    timeout_graceful_shutdown=settings.shutdown_timeout_s, http=HeaderTimeoutProtocol)
    else:
        protocol = type("HeaderTimeoutProtocol", (HeaderTimeoutProtocol,), {"header_timeout_s": settings.header_timeout_s})
        uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level,
                    log_config=log_config(settings.log_format, log_level),
                    timeout_graceful_shutdown=settings.shutdown_timeout_s, http=protocol)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m service.main", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host")
    p.add_argument("--port", type=int)
    p.add_argument("--workers", type=int, default=1, help="processes, each with its own GL context")
    p.add_argument("--log-level", default="info")
    args = p.parse_args(argv)
    serve(args.host, args.port, workers=args.workers, log_level=args.log_level)


if __name__ == "__main__":
    main()
