"""Container health check of the images and docker/compose.yaml: exit 0 when the service in this
container answers GET /health/ready with 200 (the GL context is up and its thread runs), else 1.

Standard library only, so the image needs no curl. The port is GARMENT_RENDER_PORT (default 8000);
the readiness route needs no token.
"""

from __future__ import annotations

import os
import sys
import urllib.error
import urllib.request

READY_PATH = "/health/ready"


def main() -> int:
    port = os.environ.get("GARMENT_RENDER_PORT", "8000")
    url = f"http://127.0.0.1:{port}{READY_PATH}"
    try:
        with urllib.request.urlopen(url, timeout=float(os.environ.get("HEALTHCHECK_TIMEOUT_S", "4"))) as answer:
            ok = answer.status == 200
    except urllib.error.HTTPError as exc:  # 503 while the GL thread is not up; the body says why
        print(f"{url}: {exc.code} {exc.read(300).decode(errors='replace')}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"{url}: {exc}", file=sys.stderr)
        return 1
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
