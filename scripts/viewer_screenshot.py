#!/usr/bin/env python
"""docs/viewer.png: the service's viewer page (GET /view) in headless Chromium, as a designer sees it.

A fresh service; the bundled procedural studio uploaded; the procedural skirt on the procedural body
registered (preset fast, 320 x 320) and one frame posted; the fabric bench's print uploaded after the
scene and added as its colourway (POST /scenes/{id}/colourways, what the page's "add" does); the pose
rendered again in it, turned 40 degrees (frames/views, what the page's button does), so that the page
shows that frame with its stage timings and the fabric among the choices.

    .venv/bin/python scripts/viewer_screenshot.py [--out docs/viewer.png]    # ~1 min on 2 cores
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from garment_lab.fabrics import fabric_archive  # noqa: E402
from renderer.envmap import studio_environment, write_exr  # noqa: E402
from renderer.procedural import procedural_body, procedural_garment  # noqa: E402

OCTET = {"Content-Type": "application/octet-stream"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "viewer.png")
    args = ap.parse_args(argv)
    browser = shutil.which("chromium")
    if browser is None:
        raise SystemExit("chromium is missing: bash scripts/setup.sh installs it")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        port = free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith("GARMENT_RENDER_")}
        env["GARMENT_RENDER_PEM_CACHE_DIR"] = str(tmp / "pem")
        proc = subprocess.Popen([sys.executable, "-m", "service.main", "--port", str(port), "--log-level", "warning"],
                                cwd=ROOT, env=env)
        url = f"http://127.0.0.1:{port}"
        try:
            with httpx.Client(base_url=url, timeout=600) as http:
                deadline = time.monotonic() + 120
                while True:
                    try:
                        if http.get("/health/ready").status_code == 200:
                            break
                    except httpx.TransportError:
                        pass
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise SystemExit("the service did not start")
                    time.sleep(0.1)
                write_exr(tmp / "studio.exr", studio_environment(1024))
                r = http.post("/environments", content=(tmp / "studio.exr").read_bytes(), headers=OCTET,
                              params={"name": "studio (bundled)", "preset": "fast"})
                r.raise_for_status()
                garment, body = procedural_garment(), procedural_body()
                spec = {"name": "skirt on the form", "environment_id": r.json()["id"], "quality": {"preset": "fast"},
                        "garment": {"positions": garment.positions.tolist(), "faces": garment.faces.tolist(),
                                    "uvs": garment.uvs.tolist(),
                                    "material": {"model": "pbr", "albedo": [0.55, 0.06, 0.07], "roughness": 0.6}},
                        "body": {"positions": body.positions.tolist(), "faces": body.faces.tolist(),
                                 "material": {"albedo": [0.62, 0.6, 0.58], "specular": 0.05, "glossiness": 0.3}},
                        "output": {"width": 320, "height": 320}}
                r = http.post("/scenes", json=spec)
                r.raise_for_status()
                sid = r.json()["id"]
                http.post(f"/scenes/{sid}/frames", content=np.asarray(garment.positions, "<f4").tobytes(),
                          headers=OCTET).raise_for_status()
                r = http.post("/fabrics", content=fabric_archive("print"), headers={"Content-Type": "application/zip"},
                              params={"name": "print.u3ma"})
                r.raise_for_status()
                http.post(f"/scenes/{sid}/colourways", json={"fabric_id": r.json()["id"]}).raise_for_status()
                http.post(f"/scenes/{sid}/frames/views", params={"orbit": "40,10", "colourway": 1,
                                                                 "layout": "none"}).raise_for_status()
            args.out.parent.mkdir(parents=True, exist_ok=True)
            shot = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                   "--disable-background-networking", "--disable-component-update", "--disable-sync",
                                   f"--user-data-dir={tmp / 'profile'}", "--hide-scrollbars", "--window-size=760,1160",
                                   "--virtual-time-budget=8000", f"--screenshot={args.out.resolve()}", f"{url}/view"],
                                  capture_output=True, text=True, timeout=180)
            if shot.returncode != 0 or not args.out.exists():
                raise SystemExit(f"chromium made no screenshot: {shot.stderr[-2000:]}")
        finally:
            proc.terminate()
            proc.wait(60)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
