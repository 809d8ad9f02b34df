"""`garment-render bench --fabrics`: U3M fabrics on a garment under held-out light, each against the
reference and against the same fabric without its textures (its plain twin).

Five fabrics of our own making, written as U3M 1.1 archives (renderer/u3m/write.py) and read back as
a user's would be (`load_u3m`, `material_from_u3m`): a print (a 12 cm colour repeat), a denim twill (a
2/1 twill's indigo yarns and its relief as a normal map, on an 8 mm tile), a satin (smooth, a light
sheen, anisotropic: its highlight stretched along the dress's u), a voile (pale, sheer: alpha 0.35,
transmission 0.5, the body seen through it) and a velvet (a full sheen). What the renderer does not
carry is listed per fabric; the reference renders the same Material (the satin's anisotropic GGX, the
voile's layers and transmission exactly), so the error is the method's on what is carried. Each fabric's plain twin has its mean
colour and its constants (the satin's anisotropy among them) and no texture: the ratio of the two is
the textures' own cost and error.

Scenes: the broad benchmark's draped dress (the one of its garments with UVs) on its body, front view,
at 256 x 256, under the first HELD_OUT_MAPS held-out maps (lab/garment_lab/catalogue.py's split). Per
scene and fabric the truth is the mean of two reference renders (SPP samples, 4 x 4 strata a pixel);
the error is the excess rel. RMSE over their floor on the pixels both cover wholly (broad.py), the
share of those pixels 2x off (reference.metrics.artefact_share) and of 5 x 5 windows 1.5x off; the
frame time the median of 2 x FRAMES frames, timed as the broad benchmark times a scene (consecutive frames
after a warm-up), in two blocks each, textured and plain in both orders.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from renderer.presets import frame_settings, preset, presets_digest
from renderer.reference import artefact_share, relative_rmse, render_reference, window_share
from renderer.renderer import Renderer

from .broad import MapResources, Truth, _reference_cube, excess_rel_rmse
from .catalogue import LARGE_VIEW, MAPS, Scene, split
from .processes import one_thread_pool
from .report import machine_info

SIZE, SPP, PIXEL_SAMPLES, FRAMES = 256, 128, 4, 5
HELD_OUT_MAPS = 3
GARMENT = "dress"
PRESETS = ("fast", "balanced")
FABRIC_NAMES = ("print", "denim", "satin", "voile", "velvet")


def _twill(pixels: int) -> np.ndarray:
    """A 2/1 twill's height field on a (pixels x pixels) tile of 3 x 3 yarn crossings: warp floats
    over two wefts, stepping one yarn a row (the diagonal), in [0, 1]."""
    y, x = np.mgrid[:pixels, :pixels] / pixels * 3.0
    warp_up = ((np.floor(x) - np.floor(y)) % 3) < 2
    across = np.sin(np.pi * (x % 1.0)) ** 0.5
    along = np.sin(np.pi * (y % 1.0)) ** 0.5
    return np.where(warp_up, across, along)


def _normal_from_height(h: np.ndarray, strength: float) -> np.ndarray:
    gy, gx = np.gradient(h)
    n = np.stack([-strength * gx, strength * gy, np.ones_like(h)], -1)   # +y up in the image
    return n / np.linalg.norm(n, axis=-1, keepdims=True) * 0.5 + 0.5


def fabric_archive(name: str) -> bytes:
    """The U3M archive of one of FABRIC_NAMES (deterministic)."""
    from renderer.u3m import write as w

    if name == "print":
        y, x = np.mgrid[:256, :256] / 256 * 2 * np.pi
        a = 0.5 + 0.5 * np.sin(2 * x + np.sin(3 * y))
        b = 0.5 + 0.5 * np.sin(3 * y - 2 * np.cos(x))
        colour = np.stack([0.05 + 0.6 * a, 0.05 + 0.45 * b * (1 - a), 0.08 + 0.5 * (1 - b)], -1)
        front = w.visualisation(basecolor=w.colour_texture("print.png", 120.0, 120.0), roughness=0.8,
                                sheen_value=0.2, sheen_tint=0.5)
        return w.u3ma_bytes(w.document("Print", front), {"print.png": w.srgb_png(colour)})
    if name == "denim":
        h = _twill(96)
        indigo = np.array([0.02, 0.05, 0.18]) + h[..., None] * np.array([0.12, 0.14, 0.2])
        front = w.visualisation(basecolor=w.colour_texture("twill.png", 8.0, 8.0, rotation_deg=20.0),
                                normal=w.normal_texture("twill_n.png", 8.0, 8.0, rotation_deg=20.0), roughness=0.75)
        return w.u3ma_bytes(w.document("Denim twill", front),
                            {"twill.png": w.srgb_png(indigo), "twill_n.png": w.png(_normal_from_height(h, 6.0))})
    if name == "satin":
        front = w.visualisation(basecolor=(0.5, 0.05, 0.1), roughness=0.25, sheen_value=0.4, sheen_tint=0.3,
                                anisotropy_value=0.8)
        return w.u3ma_bytes(w.document("Satin", front), {})
    if name == "voile":
        front = w.visualisation(basecolor=(0.8, 0.8, 0.75), roughness=0.6, alpha=0.35, transmission=0.5)
        return w.u3ma_bytes(w.document("Voile", front), {})
    if name == "velvet":
        front = w.visualisation(basecolor=(0.25, 0.02, 0.06), roughness=0.9, sheen_value=1.0, sheen_tint=0.6)
        return w.u3ma_bytes(w.document("Velvet", front), {})
    raise ValueError(f"no fabric {name!r}: the fabrics are {', '.join(FABRIC_NAMES)}")


def fabric_materials(name: str, scene: Scene):
    """(the fabric's garment Material, its plain twin, the warnings) on `scene`'s garment."""
    from dataclasses import replace

    from renderer.u3m import load_u3m, material_from_u3m

    garment = scene.meshes()[0]
    material, warnings = material_from_u3m(load_u3m(fabric_archive(name), name=f"{name}.u3ma"), garment)
    ts = material.texture_sets[0]
    colour = np.asarray(material.albedo, np.float64)
    if ts.albedo_map is not None:
        colour = colour * np.asarray(ts.albedo_map, np.float64).reshape(-1, 3).mean(axis=0)
    metallic, roughness = float(material.metallic), float(material.roughness)
    if ts.metallic_roughness_map is not None:
        mean = np.asarray(ts.metallic_roughness_map, np.float64).reshape(-1, 2).mean(axis=0)
        metallic, roughness = metallic * mean[0], roughness * mean[1]
    plain = replace(material, albedo=tuple(colour), metallic=metallic, roughness=roughness, texture_sets=(),
                    texture_set=None)
    return material, plain, warnings


def _scenes(quick: bool) -> list[Scene]:
    sets = split()
    held = [m for m in MAPS if sets[m] == "held-out"][:1 if quick else HELD_OUT_MAPS]
    return [Scene(m, GARMENT, "sheen", LARGE_VIEW, SIZE) for m in held]


def _reference_job(scene: Scene, fabric: str, textured: bool, seed: int, spp: int) -> dict:
    material, plain, _ = fabric_materials(fabric, scene)
    materials = [material if textured else plain] + scene.materials()[1:]
    ref = render_reference(scene.meshes(), materials, _reference_cube(scene.map), scene.camera(), SIZE, SIZE, spp,
                           seed=seed, pixel_samples=PIXEL_SAMPLES)
    return {"image": np.array(ref.image), "foreground": np.array(ref.foreground), "edge": np.array(ref.edge),
            "spp": ref.spp}


def run(out_dir: Path, quick: bool = False, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    spp, frames = (32, 2) if quick else (SPP, FRAMES)
    fabrics = FABRIC_NAMES[:2] if quick else FABRIC_NAMES
    scenes = _scenes(quick)
    t_start = time.perf_counter()
    jobs = [(s, f, t, seed) for s in scenes for f in fabrics for t in (True, False) for seed in (1, 2)]
    log(f"rendering {len(jobs)} references")
    refs = {}
    with one_thread_pool(max(1, len(os.sched_getaffinity(0)))) as pool:
        futures = {pool.submit(_reference_job, s, f, t, seed, spp): (s.map, f, t, seed) for s, f, t, seed in jobs}
        for k, (future, key) in enumerate(futures.items(), 1):
            refs[key] = future.result()
            if k % 10 == 0:
                log(f"  {k}/{len(jobs)} references, {time.perf_counter() - t_start:.0f} s")
    rows = []
    with Renderer() as r:
        for scene in scenes:
            res = MapResources(r, scene.map)
            try:
                for fabric in fabrics:
                    material, plain, warnings = fabric_materials(fabric, scene)
                    body = scene.materials()[1:]
                    gl = {t: r.create_scene(scene.meshes(), [m] + body) for t, m in ((True, material), (False, plain))}
                    try:
                        for name in PRESETS:
                            knobs = {**preset(name), "filter": "sqrt-cosine"}   # as the broad benchmark
                            pems = res.pem_set(knobs, [material, *body])
                            fs = frame_settings(knobs, SIZE, SIZE)
                            times = {True: [], False: []}
                            images = {}
                            # As the broad benchmark times a scene (consecutive frames after a warm-up: what
                            # a scene keeps between frames is kept), in two blocks each, in both orders.
                            for order in ((True, False), (False, True)):
                                for t in order:
                                    r.render(gl[t], pems, fs, scene.camera(), background=res.background)
                                    for _ in range(frames):
                                        frame = r.render(gl[t], pems, fs, scene.camera(), background=res.background)
                                        times[t].append(frame.timings["frame_wall_ms"])
                                    images[t] = np.asarray(frame.image)
                            for t in (True, False):
                                a, b = refs[(scene.map, fabric, t, 1)], refs[(scene.map, fabric, t, 2)]
                                truth = Truth.of(a, b, np.zeros((SIZE, SIZE, 3), np.float32), (0.0, 0.0))
                                rows.append({
                                    "map": scene.map, "fabric": fabric, "textured": t, "preset": name,
                                    "frame_ms": float(np.median(times[t])),
                                    "rel_rmse": excess_rel_rmse(relative_rmse(images[t], truth.image, truth.mask),
                                                                truth.floor_rel_rmse),
                                    "floor_rel_rmse": truth.floor_rel_rmse,
                                    "pixels_2x": artefact_share(images[t], a["image"], b["image"], truth.mask).share,
                                    "windows_1_5x": window_share(images[t], a["image"], b["image"]).share,
                                    "not_carried": warnings if t else []})
                            log(f"{Path(scene.map).stem} {fabric} {name}: " + ", ".join(
                                f"{'textured' if r_['textured'] else 'plain'} {r_['rel_rmse']:.3f} at "
                                f"{r_['frame_ms']:.1f} ms" for r_ in rows[-2:]))
                    finally:
                        for s in gl.values():
                            s.release()
            finally:
                res.release()
        machine = machine_info(r.gl)
    data = {"command": "garment-render bench --fabrics" + (" --quick" if quick else ""), "machine": machine,
            "presets_digest": presets_digest(), "quick": quick, "size": SIZE, "spp": spp,
            "pixel_samples": PIXEL_SAMPLES, "frames": frames, "garment": GARMENT,
            "wall_s": time.perf_counter() - t_start, "rows": rows}
    (out_dir / "fabrics.json").write_text(json.dumps(data, indent=1))
    (out_dir / "fabrics.md").write_text(markdown(data))
    return data


def summary(rows: list[dict]) -> list[dict]:
    """Per preset and fabric, the medians over the maps: textured and plain error and frame time, and
    their ratios (the median of the per-map ratios)."""
    out = []
    for name in dict.fromkeys(r["preset"] for r in rows):
        for fabric in dict.fromkeys(r["fabric"] for r in rows):
            tex = [r for r in rows if r["preset"] == name and r["fabric"] == fabric and r["textured"]]
            plain = {r["map"]: r for r in rows if r["preset"] == name and r["fabric"] == fabric and not r["textured"]}
            if not tex:
                continue

            def med(key, sel):
                return float(np.median([r[key] for r in sel]))

            out.append({"preset": name, "fabric": fabric, "maps": len(tex), "rel_rmse": med("rel_rmse", tex),
                        "plain_rel_rmse": med("rel_rmse", plain.values()),
                        "error_ratio": float(np.median([r["rel_rmse"] / max(plain[r["map"]]["rel_rmse"], 1e-6)
                                                        for r in tex])),
                        "pixels_2x": max(r["pixels_2x"] for r in tex), "windows_1_5x": max(r["windows_1_5x"] for r in tex),
                        "frame_ms": med("frame_ms", tex),
                        "cost_ratio": float(np.median([r["frame_ms"] / plain[r["map"]]["frame_ms"] for r in tex])),
                        "not_carried": tex[0]["not_carried"]})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Fabrics: U3M on the garment against the reference", "",
             f"Made by `{data['command']}` on {m.get('cpu', '?')} ({m.get('gl_renderer', m.get('renderer', '?'))}); "
             f"the {data['garment']} at {data['size']} x {data['size']} under held-out maps, references of "
             f"{data['spp']} samples and {data['pixel_samples']} x {data['pixel_samples']} strata a pixel (two "
             "each). Medians over the maps; the worst map's shares. The plain twin: the fabric's mean colour and "
             "constants, no texture (lab/garment_lab/fabrics.py).", "",
             "| preset | fabric | rel. RMSE | plain | error ratio | pixels 2x (worst) | windows 1.5x (worst) | "
             "frame ms | cost ratio | not carried |", "|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary(data["rows"]):
        carried = "; ".join(n.split(":")[0] for n in s["not_carried"]) or "-"
        lines.append(f"| {s['preset']} | {s['fabric']} | {s['rel_rmse']:.3f} | {s['plain_rel_rmse']:.3f} | "
                     f"{s['error_ratio']:.2f} | {100 * s['pixels_2x']:.2f} % | {100 * s['windows_1_5x']:.2f} % | "
                     f"{s['frame_ms']:.1f} | {s['cost_ratio']:.2f} | {carried} |")
    return "\n".join(lines) + "\n"
