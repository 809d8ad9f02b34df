"""The images built for real from docker/Dockerfile.cpu and docker/Dockerfile.nvidia (podman, chroot
isolation: docker/build-local.sh) and the CPU image's own service spoken to over HTTP (its filesystem as
the process's root: docker/run-local.sh): ready, a frame rendered, the PEM cache written to its volume.

Needs root, podman and debootstrap (scripts/setup.sh installs them where apt can; ../shared/CONTAINERS.md);
elsewhere it is skipped, saying which is missing. The first build on a machine takes about two minutes
(Debian's base, then the Python dependencies); later ones reuse podman's layers.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_server import free_port, garment, scene_body, upload_environment

ROOT = Path(__file__).resolve().parents[1]
MISSING = [t for t in ("podman", "debootstrap") if shutil.which(t) is None]
pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or bool(MISSING),
    reason="building the images needs root and podman + debootstrap (apt-get install -y podman debootstrap); "
           f"missing: {', '.join(MISSING) or 'root'}")


def _build(*flavors: str) -> None:
    r = subprocess.run(["bash", str(ROOT / "docker" / "build-local.sh"), *flavors], capture_output=True, text=True,
                       timeout=1500)
    assert r.returncode == 0, (r.stdout[-3000:], r.stderr[-3000:])


@pytest.mark.system
def test_the_nvidia_image_builds_from_its_dockerfile():
    _build("nvidia")
    r = subprocess.run(["podman", "image", "inspect", "--format", "{{range .Config.Env}}{{println .}}{{end}}",
                        "garment-render:nvidia"], capture_output=True, text=True, check=True)
    env = dict(line.split("=", 1) for line in r.stdout.split())
    assert env["GARMENT_RENDER_REQUIRE_GPU"] == "1" and "graphics" in env["NVIDIA_DRIVER_CAPABILITIES"]


@pytest.mark.system
def test_the_cpu_image_serves_a_frame_and_writes_its_pem_cache_to_the_volume(tmp_path):
    _build("cpu")
    pem, state = tmp_path / "pem", tmp_path / "state"
    for d in (pem, state):
        d.mkdir()
        os.chown(d, 10001, 10001)   # the image's user, as a named volume would be
    port = free_port()
    log = open(tmp_path / "service.log", "wb")
    proc = subprocess.Popen(["bash", str(ROOT / "docker" / "run-local.sh"), "garment-render:cpu", str(port), str(pem),
                             str(state)], stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            assert proc.poll() is None, (tmp_path / "service.log").read_text()[-3000:]
            try:
                ready = httpx.get(f"{url}/health/ready", timeout=2)
                if ready.status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "the image's service was not ready in 120 s"
            time.sleep(0.5)
        assert "llvmpipe" in ready.json()["gl"]["renderer"]
        with httpx.Client(base_url=url, timeout=120) as http:
            env, _, _ = upload_environment(http, tmp_path)
            mesh = garment(16)
            scene = http.post("/scenes", json=scene_body(env["id"], mesh))
            assert scene.status_code == 201, scene.text
            frame = http.post(f"/scenes/{scene.json()['id']}/frames",
                              content=np.ascontiguousarray(mesh.positions, "<f4").tobytes(),
                              headers={"Content-Type": "application/octet-stream"})
            assert frame.status_code == 200 and frame.headers["content-type"] == "image/png", frame.text
            assert frame.content[:8] == b"\x89PNG\r\n\x1a\n"
        # The PEM set built inside the image is on the host's side of its volume, and the scene's
        # registration in its state volume.
        assert any(p.is_file() and p.stat().st_size > 0 for p in pem.rglob("*")), sorted(pem.rglob("*"))
        assert any(state.rglob("*")), "the state volume is empty"
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        finally:
            log.close()
    # Stopping undid every mount: the volumes, /tmp and the image itself.
    mounts = Path("/proc/mounts").read_text()
    assert str(pem) not in mounts and str(state) not in mounts
    image_id = subprocess.run(["podman", "image", "inspect", "--format", "{{.Id}}", "garment-render:cpu"],
                              capture_output=True, text=True, check=True).stdout.strip()
    still = subprocess.run(["podman", "image", "mount"], capture_output=True, text=True, check=True).stdout
    assert image_id not in still, still
