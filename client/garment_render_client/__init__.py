"""The render service's Python client: numpy and httpx in, PNG/EXR frames and their timings out
(client.py says how it retries). A simulator's machine installs it alone (`pip install ./client`);
the server's package, garment-render, carries it too."""

from .client import FrameResult, RenderClient, ServiceError, parse_server_timing

__all__ = ["FrameResult", "RenderClient", "ServiceError", "parse_server_timing"]
