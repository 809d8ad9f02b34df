"""`garment-render speed`: frame times of the presets measured side by side.

On a shared, noisy machine a setting timed alone can be 1.3x off (rows of the same work timed one after another). Here the
settings take turns, frame by frame, for N rounds on each scene, so that a slow spell of the machine
falls on all of them alike: the medians and the ratios to `balanced` are comparable.

`--large` times the scene of the GPU speed target instead (a garment of at least 100k triangles at
1024x1024 with 48 lights: the "balanced, 48 lights" row): the newton shirt subdivided on its dress form under the
hard sun, each frame uploading the garment's positions as a simulation does, with the GL timer
queries' GPU time beside the wall clock where the driver's queries mean something (not llvmpipe),
and the PEM set's build time.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.camera import frame_meshes
from renderer.errors import InvalidInputError
from renderer.gpu.context import GLContext, StageTimer
from renderer.presets import merge_knobs, pem_settings, presets
from renderer.renderer import Renderer

from .run import _pems_for, frame_settings
from .scenes import LARGE_GARMENT_TRIANGLES, bundled_scene, large_scene, shared_scenes

# What balanced's measured choices cost and save: each variant changes one of them.
VARIANTS = {
    "balanced": {},
    "balanced, small-light scale 1": {"small_light_scale": 1},
    "balanced, every small light at scale 4": {"small_light_min_energy": 0.0},
    "balanced, every small light at scale 2": {"small_light_scale": 2, "small_light_min_energy": 0.0},
    "balanced, full caster detail": {"caster_detail": 1.0},
    "balanced, one map per sharp light": {"sharp_share_deg": 0.0},
    "balanced, bright large lights' maps at scale 4 too": {"sharp_large_lights": True},
    "balanced, no contact shadows": {"contact_shadow_texels": 0.0},
    "balanced, diffuse terms from the PEMs": {"diffuse": "pem"},
    "balanced, one glossy disc per region": {"sub_lights": 1},
    "balanced, 4 glossy discs per region": {"sub_lights": 4},
    "balanced, 48 lights": {"lights": 48},
    "fast": "fast",
    "accurate": "accurate",
    # How balanced runs, not what it computes (the same image): renderer.py's default_lighting_pass
    # and default_normals choose by these rows.
    "balanced, fragment lighting pass": {"renderer": {"lighting_pass": "fragment"}},
    "balanced, compute lighting pass": {"renderer": {"lighting_pass": "compute"}},
    "balanced, normals on the CPU": {"renderer": {"normals": "cpu"}},
    "balanced, normals on the GPU": {"renderer": {"normals": "gpu"}},
}
# The variants of a run: the normals rows only mean something where frames upload positions (--large).
UPLOAD_VARIANTS = ("balanced, normals on the CPU", "balanced, normals on the GPU")
LARGE_VARIANTS = ["balanced", "fast", "accurate", "balanced, 48 lights", "balanced, fragment lighting pass",
                  "balanced, compute lighting pass", *UPLOAD_VARIANTS]


def _renderer_args(variant) -> dict:
    """A variant's Renderer arguments (its "renderer" entry: how it runs, not what it computes)."""
    return variant.get("renderer", {}) if isinstance(variant, dict) else {}


def _setting(variant, table: dict) -> dict:
    """A variant's knobs: a preset as the CLI and service apply it (the stored table's, else the
    default), or balanced with some knobs changed."""
    if isinstance(variant, dict):
        variant = {k: v for k, v in variant.items() if k != "renderer"}
    knobs = merge_knobs(table[variant], {}) if isinstance(variant, str) else merge_knobs(table["balanced"], variant)
    return {**knobs, "filter": "sqrt-cosine"}


def _median_gpu_ms(frames: list) -> float | None:
    """Median GPU time of frames whose timings carry GL timer queries (None without them)."""
    totals = [sum(f.timings["gpu_ms"].values()) for f in frames if f.timings["gpu_ms"]]
    return float(np.median(totals)) if totals else None


def _median_stages(frames: list, kind: str) -> dict:
    """Median per stage of the frames' wall ("wall_ms") or GPU ("gpu_ms") times ({} without them)."""
    names = dict.fromkeys(k for f in frames for k in f.timings[kind])
    return {k: float(np.median([f.timings[kind].get(k, 0.0) for f in frames])) for k in names}


def run_speed(out: Path | None, rounds: int = 15, size: int = 256, shared: bool = True, log=print,
              large: bool = False, min_triangles: int = LARGE_GARMENT_TRIANGLES,
              variants: list[str] | None = None, equal_error: dict | None = None) -> dict:
    """`variants`: the names of VARIANTS to time (default all). `large`: the GPU target's scene
    (`large_scene(min_triangles)`) instead of the target scenes, positions uploaded every frame.
    `equal_error` (with `large`): run_equal_error's keyword arguments, to set each setting's last
    frame against the reference (result["equal_error"])."""
    names = ([n for n in VARIANTS if large or n not in UPLOAD_VARIANTS] if variants is None else list(variants))
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or "balanced" not in names:
        raise InvalidInputError(f"speed variants must include balanced and be among {list(VARIANTS)}, got {names}")
    if large:
        big = large_scene(min_triangles)
        if big is None:
            raise InvalidInputError("--large needs the shared assets (../shared/assets beside the project)")
        scenes = [big]
    else:
        scenes = (shared_scenes() if shared else []) or [bundled_scene()]
    table, source = presets()
    from renderer.presets import presets_digest

    result = {"size": size, "rounds": rounds, "presets": source, "presets_digest": presets_digest(), "large": large,
              "scenes": {}}
    gl = GLContext()
    # One renderer per setting on the one context: each keeps its own shadow maps and targets, as a
    # service rendering one scene at one setting does (a shared renderer would re-make them at
    # every change of size).
    renderers = {name: Renderer(gl, **_renderer_args(VARIANTS[name])) for name in names}
    try:
        result["device"] = gl.renderer_name
        result["gpu_timers"] = gl.gpu_timers_meaningful
        for bs in scenes:
            camera = frame_meshes(bs.meshes, 1.0)
            cache: dict = {}
            scenes_: dict = {}
            try:
                # A scene's vertex arrays belong to the programs of the renderer that made it: one each.
                for name, r in renderers.items():
                    scenes_[name] = r.create_scene(bs.meshes, bs.materials)
                settings = {name: _setting(VARIANTS[name], table) for name in names}
                jobs = {name: (renderers[name], scenes_[name], _pems_for(renderers[name], bs, s, cache),
                               frame_settings(s, size)) for name, s in settings.items()}
                # A simulation's frame uploads the garment's positions (and the normals made from them).
                positions = [bs.meshes[0].positions] + [None] * (len(bs.meshes) - 1) if large else None
                for r, scene, pems, fs in jobs.values():   # warm-up: programs, arrays, proxies
                    r.render(scene, pems, fs, camera, positions=positions)
                frames = {name: [] for name in jobs}
                order = list(jobs)
                for k in range(rounds):
                    # The order rotates every round, so that no setting always follows the same one.
                    for name in order[k % len(order):] + order[:k % len(order)]:
                        r, scene, pems, fs = jobs[name]
                        frames[name].append(r.render(scene, pems, fs, camera, positions=positions))
                build = _time_pem_build(renderers["balanced"], bs, settings["balanced"]) if large else None
            finally:
                for p in cache.values():
                    p.release()
                for scene in scenes_.values():
                    scene.release()
            times = {name: [f.timings["frame_wall_ms"] for f in fs_] for name, fs_ in frames.items()}
            base = float(np.median(times["balanced"]))
            rows = {name: {"median_ms": float(np.median(t)), "p10_ms": float(np.percentile(t, 10)),
                           "p90_ms": float(np.percentile(t, 90)), "ratio_to_balanced": float(np.median(t)) / base,
                           "gpu_ms": _median_gpu_ms(frames[name]),
                           "stages_ms": _median_stages(frames[name], "wall_ms"),
                           "gpu_stages_ms": _median_stages(frames[name], "gpu_ms")}
                    for name, t in times.items()}
            result["scenes"][bs.name] = rows
            if large and equal_error is not None:
                from .equal_error import run_equal_error

                last = {name: {"image": fs_[-1].image, "median_ms": rows[name]["median_ms"],
                               "gpu_ms": rows[name]["gpu_ms"]} for name, fs_ in frames.items()}
                result["equal_error"] = run_equal_error(last, size, min_triangles, log=log, **equal_error)
            if large:
                result["triangles"] = int(sum(len(m.faces) for m in bs.meshes))
                result["garment_triangles"] = int(len(bs.meshes[0].faces))
                result["pem_build"] = build
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


def _time_pem_build(r: Renderer, bs, s: dict, repeats: int = 3) -> dict:
    """Median wall (and GPU, where timer queries mean something) time of building a setting's PEM set."""
    pem = pem_settings(s, s["filter"], None, bs.materials)
    cube = bs.cube(s["face_size"])
    wall, gpu = [], []
    for _ in range(repeats):
        timer = StageTimer()
        t0 = time.perf_counter()
        r.build_pems(cube, pem, timer).release()
        wall.append((time.perf_counter() - t0) * 1e3)
        if timer.gpu_ms:
            gpu.append(sum(timer.gpu_ms.values()))
    return {"lights": int(s["lights"]), "face_size": int(s["face_size"]), "wall_ms": float(np.median(wall)),
            "gpu_ms": float(np.median(gpu)) if gpu else None}


def markdown(result: dict) -> str:
    names = list(next(iter(result["scenes"].values())))

    def cell(row):
        text = f"{row['median_ms']:.0f} ({row['p10_ms']:.0f}-{row['p90_ms']:.0f})"
        return text + (f", GPU {row['gpu_ms']:.2f}" if row.get("gpu_ms") is not None else "")

    lines = [f"| scene | {' | '.join(names)} |", "|---|" + "---|" * len(names)]
    for scene, rows in result["scenes"].items():
        lines.append(f"| {scene} | {' | '.join(cell(rows[n]) for n in names)} |")
    budgets = budget_rows(result)
    if budgets:
        lines += ["", "| preset | frame budget | median over the scenes | | scenes over the budget |", "|---|---|---|---|---|"]
        for b in budgets:
            verdict = "met" if b["met"] else f"MISSED by {b['median_ms'] - b['budget_ms']:.0f} ms ({b['factor']:.2f}x)"
            lines.append(f"| {b['preset']} | {b['budget_ms']:.0f} ms | {b['median_ms']:.0f} ms | {verdict} | "
                         f"{', '.join(b['over']) or 'none'} |")
    return "\n".join(lines)


def budget_rows(result: dict) -> list[dict]:
    """Each timed preset against its frame budget (catalogue.TARGETS at 256 x 256): the median over
    the scenes of each scene's median, met or missed, and the scenes over it."""
    from .catalogue import TARGETS

    if result.get("size") != 256 or result.get("large"):
        return []
    out = []
    for preset, targets in TARGETS.items():
        budget = targets.get("frame_ms")
        if budget is None or not all(preset in rows for rows in result["scenes"].values()):
            continue
        per_scene = {scene: rows[preset]["median_ms"] for scene, rows in result["scenes"].items()}
        median = float(np.median(list(per_scene.values())))
        out.append({"preset": preset, "budget_ms": budget, "median_ms": median, "met": median <= budget,
                    "factor": median / budget, "over": [s for s, ms in per_scene.items() if ms > budget]})
    return out
