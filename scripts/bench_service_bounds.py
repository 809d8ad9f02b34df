#!/usr/bin/env python
"""The largest request of many images each route accepts under the service's default limits, sent to
a real server: its peak memory and time against the estimate it was admitted on (service/budgets.py);
and each preset's scene through the service: its frame's memory against the estimate it was
registered on (renderer.costs.frame_cost, the answer's `frame_memory`) and its frame time.

For each route and image size: a scene of the procedural garment under the bundled studio (the
service's default preset), two frames to time it, then the largest request the limits admit (views
of a turntable as one sheet; a batch answered as JSON with PNG images), computed from the same
estimate the service makes (the scene's median GL time an image; the memory model), and one image
more. The server's resident set is sampled every 20 ms during each request: its peak above the set
before the request is the request's memory (llvmpipe's render targets are host memory too; they are
the scene's, allocated by its first frame, before the baseline). A preset's row: the resident set's
peak above the set before its scene was registered (the environment uploaded with the preset's PEM
settings: its PEM set built before), over the registration and five frames, against the frame's own
memory in `frame_memory` (its total less the PEM set's). Every row is a fresh service process.

    .venv/bin/python scripts/bench_service_bounds.py            # ~6 min on 2 cores
    .venv/bin/python scripts/bench_service_bounds.py --quick    # the smaller sizes only

Writes docs/service-bounds.json and docs/service-bounds.md (`--out` for elsewhere).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from renderer.envmap import studio_environment, write_exr  # noqa: E402
from renderer.presets import PRESET_NAMES, presets_digest  # noqa: E402
from renderer.procedural import procedural_garment  # noqa: E402
from service import budgets  # noqa: E402
from service.routes.frames import BATCH_FRAMES_AHEAD  # noqa: E402
from service.settings import ServiceSettings  # noqa: E402

OCTET = {"Content-Type": "application/octet-stream"}
CASES = [("views", 1024), ("batch", 1024), ("views", 4096), ("batch", 4096)]
QUICK_CASES = [("views", 512), ("batch", 512)]
PRESET_SIZES, QUICK_PRESET_SIZES = (256, 512), (256,)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


class PeakRSS:
    """The highest resident set of a process while the block runs, sampled every 20 ms."""

    def __init__(self, pid: int):
        self.pid, self.peak, self._stop = pid, 0, threading.Event()

    def __enter__(self):
        self.base = rss_bytes(self.pid)
        self.peak = self.base
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self):
        while not self._stop.wait(0.02):
            self.peak = max(self.peak, rss_bytes(self.pid))

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, rss_bytes(self.pid))


def gl_job_ms(r: httpx.Response) -> float:
    for part in r.headers["Server-Timing"].split(","):
        name, _, dur = part.strip().partition(";dur=")
        if name == "gl_job":
            return float(dur)
    raise KeyError("gl_job")


class _Scene:
    """What budgets' estimate reads of a scene: its size, its latest per-image GL times and PNG sizes."""

    def __init__(self, size: int, recent_ms: list[float], png_bytes: list[int]):
        self.frame_settings = type("Size", (), {"width": size, "height": size, "aovs": ()})()
        self.gl_ms_recent = recent_ms
        self.encoded_bpp_recent = {"png": [n / size**2 for n in png_bytes]}


def largest(route: str, size: int, recent_ms: list[float], png_bytes: list[int], settings: ServiceSettings) -> int:
    rates, scene = budgets.FrameRates(), _Scene(size, recent_ms, png_bytes)
    cap = settings.max_views if route == "views" else settings.max_batch_frames
    best = 0
    for n in range(1, cap + 1):
        cost = (budgets.views_cost(scene, n, 1, True, rates, settings) if route == "views" else
                budgets.batch_cost(scene, n, "json", "png", BATCH_FRAMES_AHEAD, rates, settings))
        if cost.held_bytes > settings.max_request_bytes or cost.gl_s > settings.max_request_s:
            break
        best = n
    return best


def send(http: httpx.Client, route: str, scene_id: str, positions: np.ndarray, n: int) -> httpx.Response:
    if route == "views":
        return http.post(f"/scenes/{scene_id}/frames/views", content=positions.tobytes(), headers=OCTET,
                         params={"turntable": n, "colourways": "false"})
    body = b"".join((positions + np.float32(1e-4 * k)).tobytes() for k in range(n))
    return http.post(f"/scenes/{scene_id}/frames/batch", content=body, headers=OCTET)


class Server:
    """A fresh service process (every measurement has its own: memory a process freed is kept by its
    allocator and reused, which would hide the next request's), the studio uploaded with `preset`'s
    PEM settings before the measurement starts."""

    def __init__(self, tmp: Path, env_path: Path, preset: str | None = None):
        self.tmp, self.env_path, self.preset = tmp, env_path, preset

    def __enter__(self):
        port = free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith("GARMENT_RENDER_")}
        env["GARMENT_RENDER_PEM_CACHE_DIR"] = str(self.tmp / "pem")
        self.proc = subprocess.Popen([sys.executable, "-m", "service.main", "--port", str(port), "--log-level",
                                      "warning"], cwd=ROOT, env=env)
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=900)
        deadline = time.monotonic() + 120
        while True:
            try:
                if self.http.get("/health/ready").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise SystemExit("the service did not start")
            time.sleep(0.1)
        params = {"name": "studio.exr", **({"preset": self.preset} if self.preset else {})}
        r = self.http.post("/environments", content=self.env_path.read_bytes(), headers=OCTET, params=params)
        r.raise_for_status()
        self.env_id = r.json()["id"]
        return self

    def __exit__(self, *exc):
        self.http.close()
        self.proc.terminate()
        self.proc.wait(60)


def measure_preset(server: Server, preset: str, size: int, mesh, positions: np.ndarray) -> dict:
    http = server.http
    body = {"environment_id": server.env_id, "quality": {"preset": preset},
            "garment": {"positions": mesh.positions.tolist(), "faces": mesh.faces.tolist()},
            "output": {"width": size, "height": size}}
    with PeakRSS(server.proc.pid) as rss:
        t0 = time.perf_counter()
        r = http.post("/scenes", json=body)
        register_s = time.perf_counter() - t0
        r.raise_for_status()
        scene = r.json()
        frames = [http.post(f"/scenes/{scene['id']}/frames", content=positions.tobytes(), headers=OCTET)
                  for _ in range(5)]
    assert all(f.status_code == 200 for f in frames), frames[-1].text
    memory = scene["frame_memory"]
    return {"preset": preset, "size": size, "register_s": round(register_s, 2),
            "first_frame_gl_ms": round(gl_job_ms(frames[0]), 1),
            "frame_gl_ms": round(statistics.median(gl_job_ms(f) for f in frames[1:]), 1),
            "estimated_mib": round((memory["total_bytes"] - memory["pem_set_bytes"]) / 2**20, 1),
            "peak_rss_above_mib": round((rss.peak - rss.base) / 2**20, 1)}


def measure_route(server: Server, route: str, size: int, mesh, positions: np.ndarray,
                  settings: ServiceSettings) -> dict:
    http = server.http
    body = {"environment_id": server.env_id, "garment": {"positions": mesh.positions.tolist(),
                                                         "faces": mesh.faces.tolist()},
            "output": {"width": size, "height": size}}
    r = http.post("/scenes", json=body)
    r.raise_for_status()
    scene_id = r.json()["id"]
    preset = r.json().get("quality", {}).get("preset")
    answers = [http.post(f"/scenes/{scene_id}/frames", content=positions.tobytes(), headers=OCTET)
               for _ in range(3)]
    timed = [gl_job_ms(r) for r in answers]
    n = largest(route, size, timed, [len(r.content) for r in answers], settings)
    with PeakRSS(server.proc.pid) as rss:
        t0 = time.perf_counter()
        r = send(http, route, scene_id, positions, n)
        wall = time.perf_counter() - t0
    estimate = dict(kv.split("=") for kv in r.headers.get("X-Request-Estimate", "").split("; ") if kv)
    t0 = time.perf_counter()
    over = send(http, route, scene_id, positions, n + 1)
    refused_s = time.perf_counter() - t0
    return {"route": route, "size": size, "preset": preset, "images": n, "status": r.status_code,
            "wall_s": round(wall, 2), "frame_ms": [round(t, 1) for t in timed],
            "estimated_held_mib": round(int(estimate.get("held_bytes", 0)) / 2**20, 1),
            "estimated_gl_s": float(estimate.get("gl_s", "nan")),
            "peak_rss_above_mib": round((rss.peak - rss.base) / 2**20, 1),
            "peak_rss_mib": round(rss.peak / 2**20, 1),
            "one_more": {"status": over.status_code, "answered_s": round(refused_s, 3),
                         "detail": over.json().get("detail") if over.status_code != 200 else None}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "docs")
    a = ap.parse_args()
    settings = ServiceSettings()
    tmp = Path(tempfile.mkdtemp(prefix="bounds-"))
    env_path = tmp / "studio.exr"
    write_exr(env_path, studio_environment(256))
    mesh = procedural_garment(48)
    positions = np.ascontiguousarray(mesh.positions, "<f4")
    rows, preset_rows = [], []
    for preset in PRESET_NAMES:
        for size in QUICK_PRESET_SIZES if a.quick else PRESET_SIZES:
            with Server(tmp, env_path, preset) as server:
                gl = server.http.get("/stats").json()["gl"]
                preset_rows.append(measure_preset(server, preset, size, mesh, positions))
            print(json.dumps(preset_rows[-1]), flush=True)
    for route, size in QUICK_CASES if a.quick else CASES:
        with Server(tmp, env_path) as server:
            rows.append(measure_route(server, route, size, mesh, positions, settings))
        print(json.dumps(rows[-1]), flush=True)
    data = {"command": "python scripts/bench_service_bounds.py" + (" --quick" if a.quick else ""),
            "presets_digest": presets_digest(),
            "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "gl": gl},
            "limits": {"max_request_bytes": settings.max_request_bytes, "max_request_s": settings.max_request_s},
            "presets": preset_rows, "rows": rows}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "service-bounds.json").write_text(json.dumps(data, indent=1) + "\n")
    (a.out / "service-bounds.md").write_text(report(data))
    print(f"wrote {a.out / 'service-bounds.json'} and .md")
    return 0


def report(data: dict) -> str:
    m, lim = data["machine"], data["limits"]
    lines = ["# The largest requests the service accepts", "",
             f"Made by `{data['command']}` on {m['cpus']} CPUs, {m['gl'].get('renderer', '?')}; the default limits "
             f"({lim['max_request_bytes'] / 2**30:g} GiB held at once, {lim['max_request_s']:g} s of render thread). "
             "Each row is the largest request of its route and size the limits admit (the service's default "
             "preset), sent to a real server: its wall time, the server's peak resident set above its set "
             "before the request, the estimate it was admitted on, and the answer to one image more.", "",
             "| route | size | images | status | wall s | est. GL s | est. held MiB | peak RSS above MiB | "
             "one more |", "|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        one = r["one_more"]
        lines.append(f"| {r['route']} | {r['size']} | {r['images']} | {r['status']} | {r['wall_s']} | "
                     f"{r['estimated_gl_s']:.1f} | {r['estimated_held_mib']} | {r['peak_rss_above_mib']} | "
                     f"{one['status']} in {one['answered_s']} s |")
    ratios = [r["peak_rss_above_mib"] / r["estimated_held_mib"] for r in data["rows"] if r["estimated_held_mib"]]
    if ratios:
        lines += ["", f"Measured peak over the estimate: median {statistics.median(ratios):.2f}, "
                      f"range {min(ratios):.2f}-{max(ratios):.2f}."]
    lines += ["", "## Each preset through the service", "",
              "A scene of each preset registered and five frames sent, in a fresh service whose environment was "
              "uploaded with the preset's PEM settings: the registration's time, the first frame's and the "
              "median of the next four frames' render-thread time, the frame's memory the scene was registered "
              "on (`frame_memory`: shadow maps and render targets, its PEM set apart) and the server's "
              "resident set's peak above its set before the registration.", "",
              "| preset | size | register s | first frame ms | frame ms | est. MiB | peak RSS above MiB |",
              "|---|---|---|---|---|---|---|"]
    for r in data.get("presets", []):
        lines.append(f"| {r['preset']} | {r['size']} | {r['register_s']} | {r['first_frame_gl_ms']} | "
                     f"{r['frame_gl_ms']} | {r['estimated_mib']} | {r['peak_rss_above_mib']} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
