#!/usr/bin/env python
"""Load benchmark of the render service (not a test): the shared newton shirt drape, 512x512 PNG frames.

1. Overhead at one client: the service's own stages (decode, queue wait, encode) against the render
   time on the GL thread, from the Server-Timing of every frame. Target: <= 10 % of render.
2. Concurrency: C clients x N frames each, retrying on 503 (Retry-After): every frame answered once
   (none lost, none duplicated: X-Frame-Index echoes), p50/p99 latency as the clients see it.
3. Memory: the server's resident set over many frames. Target: flat within 5 %.

    .venv/bin/python scripts/bench_service.py --quick          # ~1-2 min on 2 cores
    .venv/bin/python scripts/bench_service.py                  # the issue's sizes: 100 x 4 clients, 2000 frames
    .venv/bin/python scripts/bench_service.py --url http://host:8000 --token T   # a running service (no RSS)

Writes out/bench_service.json.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ASSETS = ROOT.parent / "shared" / "assets"
SIM = ASSETS / "sim" / "newton_shirt_drape_60f.npz"
ENV = ASSETS / "hdri" / "pisa.hdr"

from garment_render_client import RenderClient  # noqa: E402
from renderer.presets import PRESET_NAMES  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(queue_size: int, cache_dir: str) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("GARMENT_RENDER_")}
    env.update(GARMENT_RENDER_QUEUE_SIZE=str(queue_size), GARMENT_RENDER_PEM_CACHE_DIR=cache_dir)
    proc = subprocess.Popen([sys.executable, "-m", "service.main", "--port", str(port), "--log-level", "warning"],
                            cwd=ROOT, env=env)
    url = f"http://127.0.0.1:{port}"
    c = RenderClient(url)
    for _ in range(600):
        try:
            if c.ready():
                return proc, url
        except Exception:
            pass
        if proc.poll() is not None:
            raise SystemExit(f"server exited with {proc.returncode}")
        time.sleep(0.1)
    proc.kill()
    raise SystemExit("server not ready in 60 s")


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def pct(values, q) -> float:
    return float(np.percentile(np.asarray(values, np.float64), q)) if len(values) else float("nan")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="20 overhead frames, 4 x 10 concurrent, 200 memory frames")
    p.add_argument("--url", help="benchmark a running service instead of starting one")
    p.add_argument("--token")
    p.add_argument("--preset", default="balanced", choices=PRESET_NAMES)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--clients", type=int, default=4)
    p.add_argument("--frames", type=int, help="frames per client in the concurrency phase (default 100)")
    p.add_argument("--overhead-frames", type=int, help="default 100")
    p.add_argument("--memory-frames", type=int, help="default 2000")
    p.add_argument("--queue-size", type=int, default=2, help="of the started server; small so 503s happen")
    p.add_argument("--out", type=Path, default=ROOT / "out" / "bench_service.json")
    a = p.parse_args()
    n_over = a.overhead_frames or (20 if a.quick else 100)
    n_conc = a.frames or (10 if a.quick else 100)
    n_mem = a.memory_frames or (200 if a.quick else 2000)

    if not SIM.exists():
        raise SystemExit(f"needs the shared simulation {SIM}")
    sim = np.load(SIM)
    positions = np.ascontiguousarray(sim["positions"], np.float32)  # (61, V, 3), Z-up metres
    faces = sim["triangles"]
    n_sim = positions.shape[0]

    proc = None
    tmp = tempfile.TemporaryDirectory(prefix="bench-service-")
    url = a.url
    if url is None:
        proc, url = start_server(a.queue_size, tmp.name)
    report: dict = {"url": url, "preset": a.preset, "size": a.size, "vertices": int(positions.shape[1]),
                    "triangles": int(faces.shape[0]), "quick": a.quick}
    try:
        client = RenderClient(url, token=a.token)
        if ENV.exists():
            env = client.upload_environment(ENV, preset=a.preset)
        else:
            from renderer.envmap import studio_environment, write_exr

            path = Path(tmp.name) / "studio.exr"
            write_exr(path, studio_environment(512))
            env = client.upload_environment(path, preset=a.preset)
        scene = client.create_scene(env["id"], positions=positions[0], faces=faces, up="z",
                                    material={"albedo": [0.75, 0.25, 0.2], "specular": 0.4, "glossiness": 0.7},
                                    quality={"preset": a.preset}, output={"width": a.size, "height": a.size})
        sid = scene["id"]
        report["quality"] = scene["quality"]
        report["gl"] = client.stats()["gl"]
        print(f"scene {sid}: {positions.shape[1]} vertices, {faces.shape[0]} triangles, {a.size}x{a.size}, "
              f"preset {a.preset} ({scene['quality']['lights']} lights), {report['gl']['renderer']}")

        # 1. overhead at one client --------------------------------------------------------------
        for i in range(3):
            client.send_frame(sid, positions[i % n_sim])
        rows = []
        for i in range(n_over):
            t0 = time.perf_counter()
            f = client.send_frame(sid, positions[i % n_sim])
            f.timings["client"] = (time.perf_counter() - t0) * 1e3
            rows.append(f.timings)
        med = {k: float(np.median([r.get(k, 0.0) for r in rows])) for k in rows[0]}
        own = med["decode"] + med["queue"] + med["encode"]
        report["overhead"] = {
            "frames": n_over, "median_ms": med,
            "service_overhead_ms": own, "render_ms": med["render"],
            "overhead_share_of_render": own / med["render"],
            "overhead_share_incl_normals": (own + med["normals"]) / med["render"],
            "http_and_transport_ms": med["client"] - med["total"],
        }
        print(f"[overhead] median over {n_over} frames: render {med['render']:.1f} ms; decode {med['decode']:.2f} + "
              f"queue {med['queue']:.2f} + encode {med['encode']:.2f} = {own:.2f} ms = "
              f"{100 * own / med['render']:.1f} % of render (normals off the GL thread {med['normals']:.2f} ms; "
              f"client round trip {med['client']:.1f} ms, server total {med['total']:.1f} ms)")

        # 2. concurrency -------------------------------------------------------------------------
        before = client.http.get(f"/scenes/{sid}").json()["frames_rendered"]
        latencies: list[float] = []
        answered: dict[int, int] = {}
        errors: list[str] = []
        retries = [0] * a.clients
        lock = threading.Lock()

        def simulator(k: int) -> None:
            with RenderClient(url, token=a.token, max_retries=10_000, max_retry_wait_s=1.0) as c:
                for i in range(n_conc):
                    idx = k * 1_000_000 + i
                    t0 = time.perf_counter()
                    try:
                        f = c.send_frame(sid, positions[(i + 7 * k) % n_sim], frame_index=idx)
                    except Exception as e:  # counted as lost
                        with lock:
                            errors.append(f"client {k} frame {i}: {e}")
                        continue
                    dt = (time.perf_counter() - t0) * 1e3
                    with lock:
                        latencies.append(dt)
                        answered[f.frame_index] = answered.get(f.frame_index, 0) + 1
                retries[k] = c.retries

        t0 = time.perf_counter()
        threads = [threading.Thread(target=simulator, args=(k,)) for k in range(a.clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        wall = time.perf_counter() - t0
        expected = {k * 1_000_000 + i for k in range(a.clients) for i in range(n_conc)}
        lost = sorted(expected - set(answered))
        dup = sorted(i for i, n in answered.items() if n > 1)
        server_count = client.http.get(f"/scenes/{sid}").json()["frames_rendered"] - before
        report["concurrency"] = {
            "clients": a.clients, "frames_per_client": n_conc, "answered": len(answered), "lost": len(lost),
            "duplicated": len(dup), "server_frames": server_count, "retries_503": sum(retries),
            "errors": errors[:5], "p50_ms": pct(latencies, 50), "p99_ms": pct(latencies, 99),
            "max_ms": max(latencies) if latencies else float("nan"), "wall_s": wall,
            "throughput_fps": len(latencies) / wall,
        }
        c_ = report["concurrency"]
        print(f"[concurrency] {a.clients} clients x {n_conc} frames: answered {c_['answered']}/{len(expected)}, "
              f"lost {c_['lost']}, duplicated {c_['duplicated']}, server counted {server_count}, "
              f"503 retries {c_['retries_503']}; latency p50 {c_['p50_ms']:.0f} ms, p99 {c_['p99_ms']:.0f} ms; "
              f"{c_['throughput_fps']:.2f} frames/s")

        # 3. memory ------------------------------------------------------------------------------
        if proc is not None:
            samples = []
            step = max(1, n_mem // 20)
            for i in range(n_mem):
                client.send_frame(sid, positions[i % n_sim])
                if i % step == 0 or i == n_mem - 1:
                    samples.append((i, rss_mib(proc.pid)))
            warm = [s for s in samples if s[0] >= n_mem // 10] or samples
            first, last = warm[0][1], warm[-1][1]
            report["memory"] = {"frames": n_mem, "samples_mib": samples, "after_warmup_mib": first,
                                "last_mib": last, "max_mib": max(s[1] for s in warm),
                                "change_pct": 100.0 * (last - first) / first}
            m = report["memory"]
            print(f"[memory] {n_mem} frames: RSS {first:.0f} MiB after warm-up (frame {warm[0][0]}), "
                  f"{last:.0f} MiB at the end ({m['change_pct']:+.2f} %), max {m['max_mib']:.0f} MiB")
        client.close()
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(15)
        tmp.cleanup()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
