"""`garment-render bench --shadow-maps`: the main shadow maps' size and the casters' detail, on the
broad benchmark's scenes, tuning and held-out apart.

The broad catalogue's 256 x 256 subset (catalogue.scenes: every map x the shirt, the polo and the
dress on their bodies, the sheen fabric, front view), a preset (balanced; `--preset`) with each of
`VARIANTS`, against the
mean of two references of `spp` samples per technique (fewer than the broad benchmark's 1024, so
that the run takes minutes: the error is given with its excess over the references' own noise,
sqrt(e^2 - floor^2), which is what the variants are compared by). The contact search keeps its
reach in the scene (24 texels of 256^2 maps: its texel count follows the side).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.presets import frame_settings, pem_settings, preset, presets_digest
from renderer.reference import relative_rmse
from renderer.renderer import Renderer

from .broad import maps_of_side
from .catalogue import GARMENTS, LARGE_FABRIC, LARGE_VIEW, MAPS, Scene, environment_cube, split
from .materials import ReferencePair
from .report import machine_info
from .run import time_frames
from .sizes import excess

SIZE = 256


def _variant(side: int, detail: float) -> dict:
    return {**maps_of_side(side), "caster_detail": detail}


# The first is what the others are compared with: balanced's maps before this comparison.
VARIANTS = {
    "256^2, casters at 1/4": _variant(256, 0.25),
    "256^2, full casters": _variant(256, 1.0),
    "384^2, casters at 1/4": _variant(384, 0.25),
    "384^2, casters at 1/2": _variant(384, 0.5),
    "512^2, casters at 1/4": _variant(512, 0.25),
    "512^2, casters at 1/2": _variant(512, 0.5),
    "512^2, full casters": _variant(512, 1.0),
}


def run(out_dir: Path, quick: bool = False, spp: int = 64, frames: int = 2, preset_name: str = "balanced",
        log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sets = split()
    maps = ([m for m in MAPS if sets[m] == "tuning"][:1] + [m for m in MAPS if sets[m] == "held-out"][:1]
            if quick else list(MAPS))
    garments = GARMENTS[:1] if quick else GARMENTS
    variants = dict(list(VARIANTS.items())[:2]) if quick else VARIANTS
    base = preset(preset_name)
    rows = []
    t_start = time.perf_counter()
    with Renderer() as r:
        for garment in garments:
            for name in maps:
                scene = Scene(name, garment, LARGE_FABRIC, LARGE_VIEW, SIZE)
                meshes, camera, materials = scene.meshes(), scene.camera(), scene.materials()
                truth = ReferencePair.render(meshes, materials, environment_cube(name, 256), camera, SIZE, spp)
                gs = r.create_scene(meshes, materials)
                pems = r.build_pems(environment_cube(name, int(base["face_size"])),
                                    pem_settings(base, "sqrt-cosine", None))
                try:
                    got = {}
                    for label, knobs in variants.items():
                        f, frame_ms, _ = time_frames(r, gs, pems, frame_settings({**base, **knobs}, SIZE, SIZE),
                                                     camera, frames)
                        err = relative_rmse(f.image, truth.image, truth.mask)
                        got[label] = {"rel_rmse": err, "excess": excess(err, truth.floor), "frame_ms": frame_ms}
                finally:
                    pems.release()
                    gs.release()
                rows.append({"set": sets[name], "garment": garment, "map": name, "floor": truth.floor,
                             "variants": got})
                log(f"{sets[name]:8s} {garment:6s} {name:30s} floor {truth.floor:.3f} | "
                    + " | ".join(f"{k} {v['excess']:.3f} ({v['frame_ms']:.0f} ms)" for k, v in got.items()))
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "spp": spp, "frames": frames, "quick": quick, "size": SIZE, "preset": preset_name,
            "variants": variants, "wall_s": time.perf_counter() - t_start, "rows": rows,
            "summary": summary(rows, list(variants))}
    (out_dir / "shadow_maps.json").write_text(json.dumps(data, indent=1))
    (out_dir / "shadow_maps.md").write_text(markdown(data))
    return data


def summary(rows: list[dict], labels: list[str]) -> list[dict]:
    """Per set and variant: the median of its excess against the first variant's, scene by scene, its
    range, the median rel. RMSE and the median frame time against the first's."""
    out = []
    first = labels[0]
    for which in ("tuning", "held-out"):
        sel = [r for r in rows if r["set"] == which]
        if not sel:
            continue
        for label in labels:
            ratios = [r["variants"][label]["excess"] / max(r["variants"][first]["excess"], 1e-12) for r in sel]
            times = [r["variants"][label]["frame_ms"] / r["variants"][first]["frame_ms"] for r in sel]
            out.append({"set": which, "variant": label, "scenes": len(sel),
                        "excess_ratio": float(np.median(ratios)), "excess_ratio_min": float(min(ratios)),
                        "excess_ratio_max": float(max(ratios)),
                        "rel_rmse": float(np.median([r["variants"][label]["rel_rmse"] for r in sel])),
                        "worst_rel_rmse": float(max(r["variants"][label]["rel_rmse"] for r in sel)),
                        "time_ratio": float(np.median(times))})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    labels = list(data["variants"])
    lines = ["# The main shadow maps' size and the casters' detail", "",
             f"Made by `garment-render bench --shadow-maps` on {m['gl_renderer']}, {m['cores']} cores ({m['date']}): "
             f"the broad catalogue's {data['size']} x {data['size']} scenes (sheen, front), "
             f"{data.get('preset', 'balanced')} otherwise, "
             f"against the mean of two references of {data['spp']} spp per technique; frame times the median of "
             f"{data['frames']} frames, the variants side by side ({data['wall_s'] / 60:.0f} min in all). "
             "'excess': sqrt(e^2 - floor^2), e the rel. RMSE and floor the references' own; ratios are to the "
             f"first variant's ({labels[0]}), scene by scene, then the median. The contact search keeps "
             "its reach in the scene.", "",
             "| set | variant | scenes | excess / first (median, range) | rel. RMSE median | worst | frame time / first |",
             "|---|---|---|---|---|---|---|"]
    for s in data["summary"]:
        lines.append(f"| {s['set']} | {s['variant']} | {s['scenes']} | {s['excess_ratio']:.2f}x "
                     f"({s['excess_ratio_min']:.2f}-{s['excess_ratio_max']:.2f}) | {s['rel_rmse']:.3f} | "
                     f"{s['worst_rel_rmse']:.3f} | {s['time_ratio']:.2f}x |")
    lines += ["", "Every scene (excess over the floor; frame ms):", "",
              "| set | garment | map | floor | " + " | ".join(labels) + " |",
              "|---|---|---|---|" + "---|" * len(labels)]
    for r in data["rows"]:
        cells = " | ".join(f"{r['variants'][k]['excess']:.3f} ({r['variants'][k]['frame_ms']:.0f})" for k in labels)
        lines.append(f"| {r['set']} | {r['garment']} | {r['map']} | {r['floor']:.3f} | {cells} |")
    return "\n".join(lines) + "\n"
