"""`garment-render speed`: frame times of the presets measured side by side.

On a shared, noisy machine a setting timed alone can be 1.3x off (docs/benchmarks.md). Here the
settings take turns, frame by frame, for N rounds on each scene, so that a slow spell of the machine
falls on all of them alike: the medians and the ratios to `balanced` are comparable.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import frame_meshes
from ..gpu.context import GLContext
from ..presets import merge_knobs, presets
from ..renderer import Renderer
from .run import _pems_for, frame_settings
from .scenes import bundled_scene, shared_scenes

# What balanced's measured choices cost and save: each variant changes one of them.
VARIANTS = {
    "balanced": {},
    "balanced, small-light scale 1": {"small_light_scale": 1},
    "balanced, every small light at scale 4": {"small_light_min_energy": 0.0},
    "balanced, every small light at scale 2": {"small_light_scale": 2, "small_light_min_energy": 0.0},
    "balanced, full caster detail": {"caster_detail": 1.0},
    "balanced, one map per sharp light": {"sharp_share_deg": 0.0},
    "balanced, bright large lights' maps at scale 4 too": {"sharp_large_lights": True},
    "balanced, bright large lights too, at most 2 sharp maps": {"sharp_large_lights": True, "sharp_max_maps": 2},
    "fast": "fast",
    "accurate": "accurate",
}


def _setting(variant, table: dict) -> dict:
    """A variant's knobs: a preset as the CLI and service apply it (the stored table's, else the
    default), or balanced with some knobs changed."""
    knobs = merge_knobs(table[variant], {}) if isinstance(variant, str) else merge_knobs(table["balanced"], variant)
    return {**knobs, "filter": "sqrt-cosine"}


def run_speed(out: Path | None, rounds: int = 15, size: int = 256, shared: bool = True, log=print) -> dict:
    scenes = (shared_scenes() if shared else []) or [bundled_scene()]
    table, source = presets()
    result = {"size": size, "rounds": rounds, "presets": source, "scenes": {}}
    gl = GLContext()
    # One renderer per setting on the one context: each keeps its own shadow maps and targets, as a
    # service rendering one scene at one setting does (a shared renderer would re-make them at
    # every change of size).
    renderers = {name: Renderer(gl) for name in VARIANTS}
    try:
        result["device"] = gl.renderer_name
        for bs in scenes:
            camera = frame_meshes(bs.meshes, 1.0)
            cache: dict = {}
            scenes_: dict = {}
            try:
                # A scene's vertex arrays belong to the programs of the renderer that made it: one each.
                for name, r in renderers.items():
                    scenes_[name] = r.create_scene(bs.meshes, bs.materials)
                settings = {name: _setting(v, table) for name, v in VARIANTS.items()}
                jobs = {name: (renderers[name], scenes_[name], _pems_for(renderers[name], bs, s, cache),
                               frame_settings(s, size)) for name, s in settings.items()}
                for r, scene, pems, fs in jobs.values():   # warm-up: programs, arrays, proxies
                    r.render(scene, pems, fs, camera)
                times = {name: [] for name in jobs}
                order = list(jobs)
                for k in range(rounds):
                    # The order rotates every round, so that no setting always follows the same one.
                    for name in order[k % len(order):] + order[:k % len(order)]:
                        r, scene, pems, fs = jobs[name]
                        times[name].append(r.render(scene, pems, fs, camera).timings["frame_wall_ms"])
            finally:
                for p in cache.values():
                    p.release()
                for scene in scenes_.values():
                    scene.release()
            base = float(np.median(times["balanced"]))
            rows = {name: {"median_ms": float(np.median(t)), "p10_ms": float(np.percentile(t, 10)),
                           "p90_ms": float(np.percentile(t, 90)), "ratio_to_balanced": float(np.median(t)) / base}
                    for name, t in times.items()}
            result["scenes"][bs.name] = rows
            log(f"{bs.name}: " + ", ".join(f"{n} {v['median_ms']:.0f} ms ({v['ratio_to_balanced']:.2f}x)"
                                           for n, v in rows.items()))
    finally:
        for r in renderers.values():
            r.release()
        gl.release()
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2))
    return result


def markdown(result: dict) -> str:
    names = list(VARIANTS)
    lines = [f"| scene | {' | '.join(names)} |", "|---|" + "---|" * len(names)]
    for scene, rows in result["scenes"].items():
        cells = [f"{rows[n]['median_ms']:.0f} ({rows[n]['p10_ms']:.0f}-{rows[n]['p90_ms']:.0f})" for n in names]
        lines.append(f"| {scene} | {' | '.join(cells)} |")
    return "\n".join(lines)
