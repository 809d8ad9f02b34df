"""A load test of the service: clients sending frames of several scenes at once, throughput and latency.

    python -m service.load --url http://127.0.0.1:8000            (a running service)
    python -m service.load --ray 1,2 --out docs/scale-out.md      (starts `serve --ray` with each count)

Each run uploads a small procedural studio map, registers `scenes` scenes of a procedural garment, and
then `clients` threads send `frames` frames each, scene by scene in turn, through the client
(garment_render_client, which retries a 503 after its Retry-After). Reported: frames a second over the whole run, the median and 99th
percentile of a frame's round trip, the retries, and which replicas answered.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx
import numpy as np

from .logs import RAY_ADDRESS_IN_LOG


def run_load(url: str, scenes: int = 4, frames: int = 16, clients: int = 4, size: int = 128,
             resolution: int = 32) -> dict:
    from garment_render_client import RenderClient
    from renderer.envmap import studio_environment, write_exr
    from renderer.procedural import procedural_garment

    mesh = procedural_garment(resolution)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "studio.exr"
        write_exr(path, studio_environment(256))
        with RenderClient(url, max_retries=500, max_retry_wait_s=0.5) as c:
            env = c.upload_environment(path, preset="fast")
            ids = [c.create_scene(env["id"], positions=mesh.positions, faces=mesh.faces,
                                  quality={"preset": "fast"}, output={"width": size, "height": size})["id"]
                   for _ in range(scenes)]
            c.send_frame(ids[0], mesh.positions)   # the PEM set and shaders ready before the clock starts
    latencies: list[float] = []
    replicas: Counter = Counter()
    retries = [0]
    lock = threading.Lock()

    def client(k: int) -> None:
        rng = np.random.default_rng(k)
        with RenderClient(url, max_retries=500, max_retry_wait_s=0.5) as c:
            for i in range(frames):
                sid = ids[(k + i) % len(ids)]
                positions = mesh.positions + rng.normal(0, 1e-3, mesh.positions.shape).astype(np.float32)
                t0 = time.perf_counter()
                f = c.send_frame(sid, positions, frame_index=i)
                dt = (time.perf_counter() - t0) * 1e3
                with lock:
                    latencies.append(dt)
                    replicas[f.headers.get("x-replica", "-")] += 1
                    retries[0] += f.retries

    t0 = time.perf_counter()
    threads = [threading.Thread(target=client, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    lat = np.array(latencies)
    return {"frames": len(lat), "wall_s": wall, "throughput_fps": len(lat) / wall, "p50_ms": float(np.percentile(lat, 50)),
            "p99_ms": float(np.percentile(lat, 99)), "retries": retries[0], "replicas": dict(replicas),
            "scenes": scenes, "clients": clients, "size": size}


def serve_ray(replicas: int, tmp: Path, timeout_s: float = 300.0,
              state_dir: bool = True) -> tuple[subprocess.Popen, str, dict]:
    """`garment-render serve --ray --replicas N` on a free port of 127.0.0.1, its state, PEM cache,
    Ray session and log under `tmp`, once it answers ready: (the process, its URL, its environment,
    with which another process reaches the same Ray instance by `ray.init(address="auto")`: RAY_ADDRESS
    names it, as `address="auto"` alone attaches to any instance running on this machine).
    `state_dir` False: no GARMENT_RENDER_STATE_DIR, the local default (XDG_STATE_HOME under `tmp`)."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("GARMENT_RENDER_") or k == "GARMENT_RENDER_CACHE_DIR"}
    env.update(GARMENT_RENDER_PEM_CACHE_DIR=str(tmp / "pem"), RAY_USAGE_STATS_ENABLED="0", RAY_TMPDIR=str(tmp / "ray"))
    env.pop("RAY_ADDRESS", None)
    if state_dir:
        env["GARMENT_RENDER_STATE_DIR"] = str(tmp / "state")
    else:
        env["XDG_STATE_HOME"] = str(tmp / "xdg")
    (tmp / "ray").mkdir(parents=True, exist_ok=True)
    log_path = tmp / f"serve-{replicas}.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "renderer.cli", "serve", "--ray", "--replicas", str(replicas),
                                 "--port", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT, cwd=tmp)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout_s
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"serve --ray exited: {log_path.read_text()[-3000:]}")
        try:
            if httpx.get(f"{url}/health/ready", timeout=2).status_code == 200 and (
                    found := RAY_ADDRESS_IN_LOG.search(log_path.read_text())):
                # Another process attaches as `serve --ray` started it: the node at the loopback, and
                # the token a new local instance requires unless told otherwise (Ray enables it for an
                # address found by "auto" alone, never for one named).
                return proc, url, {"RAY_AUTH_MODE": "token", **env, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
                                   "RAY_ADDRESS": found.group(1)}
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"serve --ray was not ready in {timeout_s:g} s: {log_path.read_text()[-3000:]}")
        time.sleep(0.5)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def markdown(rows: list[dict], machine: str, command: str, date: str) -> str:
    lines = ["# Scale-out: Ray Serve replicas", "",
             f"Made by `{command}` on {machine} "
             f"({date}): {rows[0]['clients']} clients, {rows[0]['scenes']} scenes of the procedural "
             f"garment, {rows[0]['size']} x {rows[0]['size']}, the fast preset, frames of every scene in turn.", "",
             "| replicas | frames | frames/s | p50 ms | p99 ms | retries | frames per replica |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        per = ", ".join(str(v) for v in sorted(r["replicas"].values(), reverse=True))
        lines.append(f"| {r['replica_count']} | {r['frames']} | {r['throughput_fps']:.1f} | {r['p50_ms']:.0f} | "
                     f"{r['p99_ms']:.0f} | {r['retries']} | {per} |")
    counted = [r for r in rows if isinstance(r["replica_count"], int)]
    if len(counted) >= 2:
        one, most = counted[0], counted[-1]
        gain = most["throughput_fps"] / one["throughput_fps"]
        lines += ["", f"- **What it shows here.** {most['replica_count']} replicas deliver {gain:.2f}x the frames/s of "
                  f"{one['replica_count']} on {machine}. Where the GL driver already renders each frame on every core "
                  "(llvmpipe), a second replica adds no compute: it overlaps one frame's host work (decoding, "
                  "encoding, the shadow plan) with another's rendering, and its processes share the cores.",
                  "- **What a GPU machine shows.** With `--gpus-per-replica 1` each replica renders on its own "
                  "GPU while the others do, so the throughput grows with the replicas until the host's cores "
                  "(encoding), the shared PEM cache or the network limit it; this table is that machine's once "
                  "it is run there.",
                  "- **Routing.** The frames per replica are the scenes' owners at work: every request of a scene, "
                  "its registration first, goes by a consistent-hash ring on the scene's id to one replica "
                  "(service/ray_serve.py), so the split follows how the ring placed the scenes' ids."]
    for r in counted:
        if len(r["replicas"]) < r["replica_count"]:
            lines.append(f"- **This run's ring.** With {r['replica_count']} replicas the ring placed all "
                         f"{r['scenes']} scenes' ids on {len(r['replicas'])} of them: the others served nothing, "
                         "so that row is the throughput of fewer replicas than were started.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m service.load", description=__doc__.split("\n\n")[0])
    p.add_argument("--url", help="a running service")
    p.add_argument("--ray", help="replica counts to start `serve --ray` with, one after the other (e.g. 1,2)")
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--frames", type=int, default=16, help="per client")
    p.add_argument("--clients", type=int, default=4)
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--out", type=Path, help="write the table (markdown) and its .json beside it")
    a = p.parse_args(argv)
    if (a.url is None) == (a.ray is None):
        p.error("give --url or --ray")
    rows = []
    if a.url:
        rows.append({**run_load(a.url, a.scenes, a.frames, a.clients, a.size), "replica_count": "-"})
    else:
        for n in (int(x) for x in a.ray.split(",")):
            with tempfile.TemporaryDirectory() as tmp:
                proc, url, _ = serve_ray(n, Path(tmp))
                try:
                    rows.append({**run_load(url, a.scenes, a.frames, a.clients, a.size), "replica_count": n})
                finally:
                    proc.terminate()
                    proc.wait(timeout=120)
            print(json.dumps(rows[-1]), flush=True)
    machine = f"{os.cpu_count()} cores, " + (_gl_name() or "unknown GL")
    args = sys.argv[1:] if argv is None else list(argv)
    shown = list(args)
    if "--out" in shown:   # the table's own path says nothing about how it was made
        i = shown.index("--out")
        del shown[i:i + 2]
    date, command = time.strftime("%Y-%m-%d"), " ".join(["python -m service.load", *shown])
    text = markdown(rows, machine, command, date)
    print(text)
    if a.out:
        from renderer.presets import presets_digest

        a.out.write_text(text)
        # Stamped with the preset files it ran (tests/test_stored_runs.py: a preset change stales it).
        a.out.with_suffix(".json").write_text(json.dumps(
            {"machine": machine, "date": date, "command": command,
             "presets_digest": presets_digest(), "rows": rows}, indent=1))
    return 0


def _gl_name() -> str | None:
    try:
        from renderer.gpu.context import GLContext

        g = GLContext()
        try:
            return g.renderer_name
        finally:
            g.release()
    except Exception:   # noqa: BLE001 - only for the report's heading
        return None


if __name__ == "__main__":
    sys.exit(main())
