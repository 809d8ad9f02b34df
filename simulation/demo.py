"""Drape a dress, sewn from two panels, on a mannequin and have a running render service draw every
frame: the garment and the mannequin cast shadows on each other, the floor only receives them.

    python -m simulation.demo --server http://127.0.0.1:8000 --frames 120

The simulation of frame k+1 runs while the service renders frame k (one frame in flight). Every
`--drape-frames` frames the dress is put back on its placed panels and hangs again; `--frames 0`
runs until interrupted. Each frame prints its simulation time, the service's render time and the
round trip.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import httpx
import numpy as np

from garment_render_client import RenderClient
from renderer.presets import PRESET_NAMES

from .dress import DRESS_SETTINGS, SETTLE_FRAMES
from .feed import FRONT, THREE_QUARTER, DrapeFeed, upload_studio_environment
from .panels import Garment, dress
from .proxy import mannequin
from .solver import ClothSim

VIEWS = {"front": FRONT, "three-quarter": THREE_QUARTER}


def _size(text: str) -> tuple[int, int]:
    w, _, h = text.lower().partition("x")
    return int(w), int(h or w)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m simulation.demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--server", default="http://127.0.0.1:8000", help="the render service's base URL")
    p.add_argument("--token", default=os.environ.get("GARMENT_RENDER_TOKEN"), help="bearer token, if the service has one")
    p.add_argument("--frames", type=int, default=0, help="frames to render; 0: until interrupted")
    p.add_argument("--drape-frames", type=int, default=90, help="frames per drape (then the dress hangs anew)")
    p.add_argument("--spacing", type=float, default=0.025, help="the dress panels' grid spacing, metres")
    p.add_argument("--substeps", type=int, default=DRESS_SETTINGS.substeps, help="simulation substeps per frame")
    p.add_argument("--size", type=_size, default=(512, 512), help="image size WxH")
    p.add_argument("--preset", default="fast", choices=PRESET_NAMES)
    p.add_argument("--views", default="front", help=f"comma-separated, one scene each: {', '.join(VIEWS)}")
    p.add_argument("--format", default="png", choices=("png", "exr", "json"), help="image format asked for")
    p.add_argument("--env", help="an .exr/.hdr environment map; default: the bundled procedural studio")
    p.add_argument("--wait", type=float, default=120.0, help="seconds to wait for the service to be ready")
    args = p.parse_args(argv)
    unknown = [v for v in args.views.split(",") if v not in VIEWS]
    if unknown:
        p.error(f"unknown view(s) {unknown}; choose from {list(VIEWS)}")
    return args


def wait_ready(client: RenderClient, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if client.ready():
                return
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline:
            raise SystemExit(f"demo: the service at {client.http.base_url} was not ready within {timeout_s:g} s")
        time.sleep(0.25)


def new_simulation(args: argparse.Namespace, garment: Garment) -> ClothSim:
    """The dress as sewn, on the mannequin: each run drapes it from its placed panels."""
    return ClothSim(garment.cloth, mannequin(), replace(DRESS_SETTINGS, substeps=args.substeps))


def _stored_body_and_floor() -> dict:
    """The mannequin's render mesh and the floor as the bundled default scene stores them (made from
    `mannequin()` by `python -m simulation.dress --store`), not polygonized again at every start."""
    from renderer.procedural import default_scene

    meshes, _ = default_scene()
    return {role: (np.asarray(m.positions), np.asarray(m.faces)) for role, m in zip(("body", "floor"), meshes[1:])}


def run(args: argparse.Namespace) -> int:
    with RenderClient(args.server, token=args.token) as client:
        wait_ready(client, args.wait)
        env = client.upload_environment(args.env) if args.env else upload_studio_environment(client)
        garment = dress(args.spacing)
        sim = new_simulation(args, garment)
        views = tuple(VIEWS[v] for v in args.views.split(","))
        feed = DrapeFeed(client, sim, env["id"], views=views, quality={"preset": args.preset},
                         output={"width": args.size[0], "height": args.size[1]}, format=args.format,
                         garment=garment, **_stored_body_and_floor())
        print(f"demo: {sim.cloth.n_vertices} cloth vertices, {len(sim.cloth.faces)} triangles; scenes "
              f"{', '.join(feed.scene_ids)} on {args.server}", flush=True)
        with ThreadPoolExecutor(1, thread_name_prefix="post") as pool:
            pending = (0, pool.submit(feed.post, 0), 0.0)  # (frame, its answer, its simulation ms)
            k = 0
            while args.frames <= 0 or k + 1 < args.frames:
                k += 1
                if k % args.drape_frames == 0:
                    sim = feed.sim = new_simulation(args, garment)
                    sim_ms = 0.0
                else:
                    sim_ms = sim.step_frame().step_ms
                    if k % args.drape_frames <= SETTLE_FRAMES:   # as `dress.drape` settles the placed panels
                        sim.v[:] = 0.0
                positions = sim.x.copy()
                _report(pending[0], pending[1].result(), pending[2])
                pending = (k, pool.submit(feed.post, k, positions), sim_ms)
            _report(pending[0], pending[1].result(), pending[2])
    return 0


def _report(k: int, results, sim_ms: float) -> None:
    render = max(r.timings.get("render", 0.0) for r in results)
    total = max(r.timings.get("total", 0.0) for r in results)
    print(f"frame {k:5d}: simulation {sim_ms:6.1f} ms, render {render:6.1f} ms, service total {total:6.1f} ms",
          flush=True)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # SIGTERM (demo.sh stopping its children) ends like Ctrl-C: the with-blocks close the connection.
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        return run(args)
    except KeyboardInterrupt:
        print("demo: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
