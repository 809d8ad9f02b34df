"""`garment-render bench --views`: what sharing the shadow pass saves (Renderer.render_views).

The bundled default scene (the draped dress on the mannequin over a floor, the studio map), balanced
and fast, positions uploaded every frame as a simulation does: K views of a turntable rendered in one
call against K frames rendered one by one, and M colourways in one call against M scenes' frames.
Both ways take turns in one run, `rounds` times; each cell is the median of its rounds' wall times.
The images of the two ways are compared too: a view that sees the whole scene is the same image either
way, and the turntable's differ only where the shadow maps' fit to what the cameras see differs.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.camera import frame_meshes
from renderer.envmap import environment_from_array, studio_environment
from renderer.presets import frame_settings, pem_settings, preset, presets_digest
from renderer.procedural import default_scene
from renderer.renderer import Renderer
from renderer.shading.material import Material
from renderer.views import turntable

from .report import machine_info

VIEW_COUNTS = (1, 4, 8)
COLOURWAY_COUNT = 4
SIZE = 256
COLOURWAYS = [Material((0.75, 0.1, 0.1), 0.3, 0.7), Material((0.1, 0.3, 0.7), 0.5, 0.85),
              Material((0.2, 0.5, 0.2), 0.1, 0.4), Material(model="pbr", albedo=(0.3, 0.05, 0.1), roughness=0.8,
                                                             sheen_colour=(0.9, 0.5, 0.6))]


def run(out_dir: Path, quick: bool = False, rounds: int = 5, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rounds = 2 if quick else rounds
    meshes, casters = default_scene()
    base_materials = [Material((0.6, 0.55, 0.5), 0.2, 0.6), Material((0.55, 0.5, 0.45), 0.1, 0.3),
                      Material((0.45, 0.45, 0.45), 0.0, 0.3)][:len(meshes)]
    source = studio_environment(1024)
    rows = []
    t_start = time.perf_counter()
    with Renderer() as r:
        for name in ("fast", "balanced"):
            knobs = preset(name)
            cube = environment_from_array(source, "latlong", int(knobs["face_size"]), name="studio").cube
            pems = r.build_pems(cube, pem_settings(knobs, "sqrt-cosine", None, base_materials + COLOURWAYS))
            fs = frame_settings(knobs, SIZE, SIZE)
            camera = frame_meshes([m for m, c in zip(meshes, casters) if c])
            scene = r.create_scene(meshes, base_materials, casters=casters,
                                   variants=[[c] + [None] * (len(meshes) - 1) for c in COLOURWAYS])
            alone = [r.create_scene(meshes, [c] + base_materials[1:], casters=casters) for c in COLOURWAYS]
            positions = [meshes[0].positions] + [None] * (len(meshes) - 1)
            try:
                rows += _preset_rows(r, name, scene, alone, pems, fs, camera, positions, rounds, log)
            finally:
                for s in [scene] + alone:
                    s.release()
                pems.release()
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "size": SIZE, "rounds": rounds, "quick": quick,
            "wall_s": time.perf_counter() - t_start, "rows": rows}
    (out_dir / "views.json").write_text(json.dumps(data, indent=1))
    (out_dir / "views.md").write_text(markdown(data))
    return data


def _preset_rows(r: Renderer, name: str, scene, alone, pems, fs, camera, positions, rounds: int, log) -> list[dict]:
    """One preset's rows: each turntable size, then the colourways."""
    rows = []
    for k in VIEW_COUNTS:
        cams = turntable(camera, k)

        def together(cams=cams):
            return r.render_views(scene, pems, fs, cams, positions)

        def one_by_one(cams=cams):
            return [r.render(scene, pems, fs, cam, positions) for cam in cams]

        rows.append(_compare(name, f"{k} views", together, one_by_one, rounds))
        log(_line(rows[-1]))
    variants = list(range(1, COLOURWAY_COUNT + 1))
    rows.append(_compare(name, f"{COLOURWAY_COUNT} colourways",
                         lambda: r.render_views(scene, pems, fs, [camera], positions, variants=variants),
                         lambda: [r.render(s, pems, fs, camera, positions) for s in alone], rounds))
    log(_line(rows[-1]))
    return rows


def _compare(preset_name: str, what: str, together, one_by_one, rounds: int) -> dict:
    together(), one_by_one()   # warm-up: shader variants, allocations
    t_shared, t_alone, diff = [], [], 0.0
    for _ in range(rounds):   # the two ways take turns, so that the machine's drift falls on both
        t0 = time.perf_counter()
        a = together()
        t_shared.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        b = one_by_one()
        t_alone.append((time.perf_counter() - t0) * 1e3)
        diff = max(diff, max(float(np.abs(fa.image - fb.image).max() / max(float(fb.image[..., :3].max()), 1e-12))
                             for fa, fb in zip(a, b)))
    shared_ms, alone_ms = float(np.median(t_shared)), float(np.median(t_alone))
    return {"preset": preset_name, "what": what, "images": len(a), "shared_ms": shared_ms, "alone_ms": alone_ms,
            "saving": 1.0 - shared_ms / alone_ms, "max_image_difference": diff}


def _line(row: dict) -> str:
    return (f"{row['preset']:9s} {row['what']:14s}: one call {row['shared_ms']:.0f} ms, one by one "
            f"{row['alone_ms']:.0f} ms ({100 * row['saving']:.0f} % saved; images differ by at most "
            f"{row['max_image_difference']:.3g} of their peak)")


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# One frame, many views and colourways", "",
             f"Made by `garment-render bench --views{' --quick' if data['quick'] else ''}` on {m['gl_renderer']}, "
             f"{m['cores']} cores ({m['date']}): the bundled dress on the mannequin over its floor, the studio map, "
             f"{data['size']} x {data['size']}, positions uploaded with every call. Each cell is the median of "
             f"{data['rounds']} rounds, the two ways taking turns ({data['wall_s']:.0f} s in all).", "",
             "| preset | images | one call (ms) | one by one (ms) | saved | largest image difference |",
             "|---|---|---|---|---|---|"]
    for row in data["rows"]:
        lines.append(f"| {row['preset']} | {row['what']} | {row['shared_ms']:.0f} | {row['alone_ms']:.0f} | "
                     f"{100 * row['saving']:.0f} % | {row['max_image_difference']:.3g} |")
    lines += ["", "- One call draws the shadow maps and uploads the positions once; each image still has its own "
              "geometry pass, lighting pass and readback.",
              "- The largest image difference is relative to the image's peak. A turntable's views are fitted to "
              "what any camera sees, so their shadow maps can differ from a single view's; colourways share one "
              "camera, so their images are the same either way.", ""]
    return "\n".join(lines)
