"""`garment-render bench --edges`: the ways to anti-alias, each one's cost and error against a truth that
integrates each pixel's area.

The held-out maps of the broad benchmark (lab/garment_lab/catalogue.py), one garment each in turn, at
256 x 256, against the broad benchmark's reference pair (4 x 4 strata a pixel, its cache shared). Per
preset (fast, balanced) and way:

    none        one sample a pixel: every pixel all garment or all background (aa_samples 1)
    msaa-4      the renderer's anti-aliasing (aa_samples 4): a depth-only multisampled coverage pass,
                shading once a pixel, each edge pixel's samples given the colour of the neighbour that
                shaded their surface (renderer.py, _edges_pass)
    ssaa-2x2    supersampling: the frame at twice the side with one sample a pixel, box-filtered down
                (four times the shading)

Per way: the silhouette error (reference.metrics.silhouette_error: the frame over black against the
truth's foreground over the pixels whose area holds an edge, the excess over the reference pair's own),
the coverage error there (alpha's RMSE), the rel. RMSE over the pixels both references cover wholly (as
the broad benchmark's, excess over the pair's floor), and the frame's median wall time. The ways take
turns frame by frame in one process, so that their times share the machine's state.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from renderer.presets import frame_settings, preset, presets_digest
from renderer.reference import relative_rmse, silhouette_error
from renderer.renderer import Background, Renderer

from .broad import (
    SEEDS,
    BroadConfig,
    MapResources,
    ReferenceCache,
    Truth,
    default_cache_dir,
    ensure_references,
    excess_rel_rmse,
)
from .catalogue import GARMENTS, LARGE_FABRIC, LARGE_VIEW, MAPS, Scene, split
from .report import machine_info

SIZE = 256
PRESETS = ("fast", "balanced")
WAYS = ("none", "msaa-4", "ssaa-2x2")


def edge_scenes(quick: bool = False) -> list[Scene]:
    """Every held-out map with a garment each in turn (quick: the first two) at SIZE."""
    sets = split()
    held = [m for m in MAPS if sets[m] == "held-out"]
    out = [Scene(m, GARMENTS[k % len(GARMENTS)], LARGE_FABRIC, LARGE_VIEW, SIZE) for k, m in enumerate(held)]
    return out[:2] if quick else out


def _frame(r, gl_scene, pems, knobs: dict, way: str, camera, background) -> tuple[np.ndarray, float]:
    """One frame of a way over black: (the SIZE x SIZE image, its wall ms)."""
    side = 2 * SIZE if way == "ssaa-2x2" else SIZE
    fs = replace(frame_settings(knobs, side, side), background=Background.BLACK,
                 aa_samples=4 if way == "msaa-4" else 1)
    t0 = time.perf_counter()
    frame = r.render(gl_scene, pems, fs, camera, background=background)
    image = np.asarray(frame.image)
    if way == "ssaa-2x2":   # a box filter over each 2 x 2 block (the colour is premultiplied: a plain mean)
        image = image.reshape(SIZE, 2, SIZE, 2, 4).mean(axis=(1, 3))
    return image, (time.perf_counter() - t0) * 1e3


def run(out_dir: Path, quick: bool = False, frames: int = 5, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = BroadConfig.quick_config() if quick else BroadConfig()
    frames = 2 if quick else frames
    todo = edge_scenes(quick)
    cache = ReferenceCache(Path(cfg.cache) if cfg.cache else default_cache_dir(), pixel_samples=cfg.pixel_samples)
    t_start = time.perf_counter()
    ensure_references(todo, cfg.spp_of, cache, max(1, cfg.workers or len(os.sched_getaffinity(0))), log)
    rows = []
    with Renderer() as r:
        for scene in todo:
            refs = [cache.get(scene, cfg.spp_of(scene), seed) for seed in SEEDS]
            res = MapResources(r, scene.map)
            truth = Truth.of(refs[0], refs[1], np.zeros((SIZE, SIZE, 3), np.float32), (0.0, 0.0))
            gl_scene = r.create_scene(scene.meshes(), scene.materials())
            camera = scene.camera()
            try:
                for name in PRESETS:
                    knobs = {**preset(name), "filter": "sqrt-cosine"}
                    pems = res.pem_set(knobs, scene.materials())
                    times: dict[str, list[float]] = {w: [] for w in WAYS}
                    images = {}
                    for k in range(frames + 1):   # the first round warms every way up, untimed
                        for way in WAYS:
                            images[way], ms = _frame(r, gl_scene, pems, knobs, way, camera, res.background)
                            if k:
                                times[way].append(ms)
                    for way in WAYS:
                        sil = silhouette_error(images[way], truth.foreground, truth.edge)
                        rows.append({"scene": scene.name, "map": scene.map, "garment": scene.garment, "preset": name,
                                     "way": way, "frame_ms": float(np.median(times[way])),
                                     "silhouette_rel_rmse": excess_rel_rmse(sil.rel_rmse, truth.floor_silhouette),
                                     "coverage_rmse": excess_rel_rmse(sil.coverage_rmse, truth.floor_coverage),
                                     "interior_rel_rmse": excess_rel_rmse(relative_rmse(images[way], truth.image,
                                                                                        truth.mask),
                                                                          truth.floor_rel_rmse),
                                     "edge_pixels": int(sil.pixels)})
                    log(f"{scene.name} {name}: " + ", ".join(
                        f"{r_['way']} {r_['silhouette_rel_rmse']:.3f} at {r_['frame_ms']:.1f} ms" for r_ in rows[-3:]))
            finally:
                gl_scene.release()
                res.release()
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "quick": quick, "size": SIZE,
            "frames": frames, "spp": cfg.spp_large, "pixel_samples": cfg.pixel_samples,
            "wall_s": time.perf_counter() - t_start, "rows": rows}
    (out_dir / "edges.json").write_text(json.dumps(data, indent=1))
    (out_dir / "edges.md").write_text(markdown(data))
    return data


def summary(rows: list[dict]) -> list[dict]:
    """Per preset and way: the medians over the scenes of each measure, and the frame's ratio to the
    same preset's frame without anti-aliasing (the median of the per-scene ratios)."""
    out = []
    for name in dict.fromkeys(r["preset"] for r in rows):
        base = {r["scene"]: r["frame_ms"] for r in rows if r["preset"] == name and r["way"] == "none"}
        for way in WAYS:
            sel = [r for r in rows if r["preset"] == name and r["way"] == way]
            if not sel:
                continue
            med = {k: float(np.median([r[k] for r in sel])) for k in
                   ("frame_ms", "silhouette_rel_rmse", "coverage_rmse", "interior_rel_rmse")}
            ratio = float(np.median([r["frame_ms"] / base[r["scene"]] for r in sel]))
            out.append({"preset": name, "way": way, "scenes": len(sel), **med,
                        "worst_silhouette": max(r["silhouette_rel_rmse"] for r in sel), "frame_ratio": ratio})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Anti-aliasing: the ways, their cost and their error", "",
             f"Made by `garment-render bench --edges` on {m.get('gl_renderer', '?')}, {m.get('cores', '?')} cores "
             f"({m.get('date', '?')}): {len({r['scene'] for r in data['rows']})} held-out scenes at "
             f"{data['size']} x {data['size']}, the reference pair at {data['spp']} samples a pixel over "
             f"{data['pixel_samples']} x {data['pixel_samples']} strata; medians over the scenes "
             "(lab/garment_lab/edges.py says how each is measured). Errors are the excess over the references' "
             "own; the frame ratio is to the same preset's frame without anti-aliasing, scene by scene.", "",
             "| preset | way | silhouette rel. RMSE, median / worst | coverage RMSE | interior rel. RMSE | frame | "
             "frame ratio |", "|---|---|---|---|---|---|---|"]
    for s in summary(data["rows"]):
        lines.append(f"| {s['preset']} | {s['way']} | {s['silhouette_rel_rmse']:.3f} / {s['worst_silhouette']:.3f} | "
                     f"{s['coverage_rmse']:.3f} | {s['interior_rel_rmse']:.4f} | {s['frame_ms']:.1f} ms | "
                     f"{s['frame_ratio']:.2f}x |")
    lines += ["", "## Scenes", "", "| scene | preset | way | silhouette | coverage | interior | frame | edge pixels |",
              "|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(f"| {r['scene']} | {r['preset']} | {r['way']} | {r['silhouette_rel_rmse']:.3f} | "
                     f"{r['coverage_rmse']:.3f} | {r['interior_rel_rmse']:.4f} | {r['frame_ms']:.1f} ms | "
                     f"{r['edge_pixels']} |")
    return "\n".join(lines) + "\n"
