"""Start the real service (uvicorn, `python -m service.main`) on 127.0.0.1 in a subprocess for the
service tests, wait until it is ready, stop it; plus the small scenes those tests share."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT.parent / "shared" / "assets"
PISA = ASSETS / "hdri" / "pisa.hdr"

# Small and fast: 12 lights, 32^2 PEM faces, 64^2 shadow maps, 64x64 images.
FAST_QUALITY = {"preset": "fast", "lights": 12, "face_size": 32, "shadow_size": 64}
SMALL_OUTPUT = {"width": 64, "height": 64}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServiceProcess:
    def __init__(self, log_dir: Path, workers: int = 1, wait_for: str = "ready", log_level: str = "warning",
                 **settings):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = Path(log_dir) / f"service-{self.port}.log"
        # The service's settings are the test's alone; the cache folder stays the session's (conftest).
        env = {k: v for k, v in os.environ.items()
               if not k.startswith("GARMENT_RENDER_") or k == "GARMENT_RENDER_CACHE_DIR"}
        env.update({f"GARMENT_RENDER_{k.upper()}": str(v) for k, v in settings.items()})
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.main", "--host", "127.0.0.1", "--port", str(self.port),
             "--log-level", log_level, "--workers", str(workers)], cwd=ROOT, env=env, stdout=self._log, stderr=subprocess.STDOUT)
        self._wait_ready(wait_for)

    def _wait_ready(self, wait_for: str, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the service exited with {self.proc.returncode}:\n{self.log()}")
            try:
                if httpx.get(f"{self.url}/health/{wait_for}", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"the service was not ready within {timeout} s:\n{self.log()}")

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-5000:]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


def environment_bytes(tmp_dir: Path) -> tuple[bytes, str]:
    """The shared Pisa probe when present, else a small procedural studio map written as EXR."""
    if PISA.exists():
        return PISA.read_bytes(), "pisa.hdr"
    from renderer.envmap import studio_environment, write_exr

    path = Path(tmp_dir) / "studio.exr"
    write_exr(path, studio_environment(128))
    return path.read_bytes(), "studio.exr"


def garment(resolution: int = 32):
    from renderer.procedural import procedural_garment

    return procedural_garment(resolution)


# What the service tests upload a map with: few lights on small faces, so that its PEM set builds fast.
SMALL_ENV_PARAMS = {"lights": 12, "face_size": 32, "preset": "fast"}


def upload_environment(http: httpx.Client, tmp_dir: Path, known: bool = False) -> tuple[dict, bytes, str]:
    """Upload `environment_bytes` with SMALL_ENV_PARAMS: (the answer, the file's bytes, its name).
    known: the service may have it already (200, the same id) rather than make it (201)."""
    data, name = environment_bytes(tmp_dir)
    r = http.post("/environments", content=data, headers={"Content-Type": "application/octet-stream"},
                  params={"name": name, **SMALL_ENV_PARAMS})
    assert r.status_code in ((200, 201) if known else (201,)), r.text
    return r.json(), data, name


def scene_body(env_id: str, mesh, **extra) -> dict:
    body = {"name": "test", "environment_id": env_id,
            "garment": {"positions": np.asarray(mesh.positions).tolist(), "faces": np.asarray(mesh.faces).tolist(),
                        "uvs": np.asarray(mesh.uvs).tolist() if mesh.uvs is not None else None,
                        "material": {"albedo": [0.8, 0.2, 0.2], "specular": 0.5, "glossiness": 0.8}},
            "quality": dict(FAST_QUALITY), "output": dict(SMALL_OUTPUT)}
    body.update(extra)
    return body


def assert_error(r: httpx.Response, status: int, *words: str) -> None:
    """`r` is the service's error answer of `status` whose detail names every one of `words` (any case)."""
    assert r.status_code == status, f"expected {status}, got {r.status_code}: {r.text[:2000]}"
    detail = r.json()["detail"]
    for w in words:
        assert w.lower() in detail.lower(), f"{w!r} not in {detail!r}"


@contextmanager
def one_scene_service(tmp_path: Path, **output):
    """A fresh service, the test map uploaded and a scene of the procedural garment registered with
    `output` over SMALL_OUTPUT: (http client, the scene's answer, the garment's mesh)."""
    srv = ServiceProcess(tmp_path)
    try:
        with httpx.Client(base_url=srv.url, timeout=120) as http:
            env = upload_environment(http, tmp_path)[0]["id"]
            mesh = garment(24)
            r = http.post("/scenes", json=scene_body(env, mesh, output={**SMALL_OUTPUT, **output}))
            assert r.status_code == 201, r.text
            yield http, r.json(), mesh
    finally:
        srv.stop()
