"""`garment-render bench --area`: the two decompositions side by side on every shared map, against the
Monte Carlo reference (issue: a second way to cut the light).

Per map (the polo on its body, front view, 128 x 128, the broad benchmark's mid-gloss fabric),
the balanced preset with `lights_from` median-cut and area at each light budget of `budgets` (a
quarter, a half and all of balanced's lights), and
auto (`PEMSettings.lights_from`, its rule in lighting/area_lights.py) at the balanced budget: rel.
RMSE against the mean of two references (`spp` samples per technique, the floor their own), the
median frame time of `frames` frames, side by side in one run, and the lights each used.

"Equal light count": area against median cut at the same budget. "Equal frame time": area's error
against the median cut's interpolated at area's frame time (linear in log time between the budgets,
clamped at the ends). Each map is labelled tuning or held-out by the broad benchmark's rule
(`catalogue.split`): a rule chosen on the tuning maps is judged on the held-out ones.

"The knob sweep's scenes": the bundled default (the studio dress) and the newton shirt on its dress
form under the four target probes (scenes.bundled_scene, shared_scenes: the scenes the presets'
other values were chosen on), the balanced preset with the median cut and with auto, the two taking
turns twice.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.config import BY_NAME
from renderer.presets import frame_settings, pem_settings, preset, presets_digest
from renderer.reference import relative_rmse
from renderer.renderer import Renderer

from .catalogue import BODY, FABRICS, MAPS, Scene, environment_cube, split
from .materials import ReferencePair
from .report import machine_info
from .run import time_frames
from .scenes import bundled_scene, shared_scenes

FABRIC = "sheen"


def budgets(lights: int) -> tuple[int, ...]:
    """The light budgets compared: a quarter, a half and all of a preset's `lights` (none below the
    setting's least)."""
    least = BY_NAME["lights"].minimum
    return (max(least, lights // 4), max(least, lights // 2), lights)


def run(out_dir: Path, quick: bool = False, spp: int = 128, frames: int = 3, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sets = split()
    maps = [m for m in MAPS if sets[m] == "tuning"][:2] + [m for m in MAPS if sets[m] == "held-out"][:2] \
        if quick else list(MAPS)
    base = preset("balanced")
    steps = budgets(int(base["lights"]))
    rows = []
    t_start = time.perf_counter()
    with Renderer() as r:
        for name in maps:
            scene = Scene(name, "polo", FABRIC, "front", 128)
            meshes, camera, materials = scene.meshes(), scene.camera(), [FABRICS[FABRIC], BODY]
            truth = ReferencePair.render(meshes, materials, environment_cube(name, 256), camera, 128, spp)
            cube = environment_cube(name, int(base["face_size"]))
            gs = r.create_scene(meshes, materials)
            try:
                variants = ([(lf, b, "fixed") for b in steps for lf in ("median-cut", "area")]
                            + [("auto", base["lights"], "fixed"), ("area", base["lights"], "blocker")])
                for lights_from, budget, penumbra in variants:
                    if penumbra != base["penumbra"] and not any(
                            r["area_lights"] for r in rows if r["map"] == name and r["lights_from"] == "area"):
                        continue   # the penumbra setting changes area lights only: none were found here
                    knobs = {**base, "lights": budget, "lights_from": lights_from, "penumbra": penumbra}
                    pems = r.build_pems(cube, pem_settings(knobs, "sqrt-cosine", None))
                    try:
                        f, frame_ms, _ = time_frames(r, gs, pems, frame_settings(knobs, 128, 128), camera, frames)
                        s = pems.summary()
                        row = {"map": name, "set": sets[name], "lights_from": lights_from, "budget": budget,
                               "penumbra": penumbra,
                               "used": s["lights_from_used"], "lights": s["n_regions"],
                               "area_lights": len(s["area_lights"] or []), "ambient_share": s["ambient_share"],
                               "rel_rmse": relative_rmse(f.image, truth.image, truth.mask), "noise_floor": truth.floor,
                               "frame_ms": frame_ms}
                    finally:
                        pems.release()
                    rows.append(row)
                    log(f"{name:32s} {lights_from:10s} {budget:3d} {penumbra:7s}: {row['lights']:3d} lights "
                        f"({row['area_lights']} area), rel. RMSE {row['rel_rmse']:.3f} (floor {truth.floor:.3f}), "
                        f"{row['frame_ms']:.0f} ms")
            finally:
                gs.release()
        sweep = [] if quick else sweep_scenes(r, base, spp, frames, log)
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "spp": spp, "frames": frames, "quick": quick,
            "budgets": list(steps),
            "wall_s": time.perf_counter() - t_start, "rows": rows, "maps": compare(rows), "sweep": sweep}
    (out_dir / "area.json").write_text(json.dumps(data, indent=1))
    (out_dir / "area.md").write_text(markdown(data))
    return data


def sweep_scenes(r: Renderer, base: dict, spp: int, frames: int, log=print, scenes=None) -> list[dict]:
    """The knob sweep's scenes at 128 x 128: balanced with the median cut and with auto, each twice,
    taking turns (the frame time the median of both turns' medians)."""
    from renderer.camera import frame_meshes

    out = []
    for bs in scenes if scenes is not None else [bundled_scene()] + shared_scenes():
        camera = frame_meshes(bs.meshes, 1.0)
        truth = ReferencePair.render(bs.meshes, bs.materials, bs.cube(256), camera, 128, spp)
        gs = r.create_scene(bs.meshes, bs.materials)
        try:
            got: dict[str, dict] = {}
            for lights_from in ("median-cut", "auto") * 2:
                knobs = {**base, "lights_from": lights_from}
                pems = r.build_pems(bs.cube(int(base["face_size"])), pem_settings(knobs, "sqrt-cosine", None))
                try:
                    f, frame_ms, _ = time_frames(r, gs, pems, frame_settings(knobs, 128, 128), camera, frames)
                    s = pems.summary()
                    row = got.setdefault(lights_from, {"used": s["lights_from_used"],
                                                       "area_lights": len(s["area_lights"] or []),
                                                       "rel_rmse": relative_rmse(f.image, truth.image, truth.mask),
                                                       "ms": []})
                    row["ms"].append(frame_ms)
                finally:
                    pems.release()
        finally:
            gs.release()
        row = {"scene": bs.name, "map": bs.env_name, "noise_floor": truth.floor,
               **{f"{k}_{lf}": (float(np.median(v)) if k == "ms" else v) for lf, d in got.items() for k, v in d.items()}}
        out.append(row)
        log(f"{bs.name:24s} median cut {row['rel_rmse_median-cut']:.3f} ({row['ms_median-cut']:.0f} ms), auto "
            f"({row['used_auto']}) {row['rel_rmse_auto']:.3f} ({row['ms_auto']:.0f} ms)")
    return out


def _interp_error(points: list[tuple[float, float]], ms: float) -> float:
    """The error of a (frame ms, error) curve at `ms`, linear in log time, clamped at the ends."""
    points = sorted(points)
    t = np.log([p[0] for p in points])
    return float(np.interp(np.log(ms), t, [p[1] for p in points]))


def compare(rows: list[dict]) -> list[dict]:
    """Per map: area against median cut at equal light budget and at equal frame time, and auto
    against the better of the two at auto's frame time (both curves interpolated there)."""
    out = []
    for name in dict.fromkeys(r["map"] for r in rows):
        mine = [r for r in rows if r["map"] == name]
        mc = {r["budget"]: r for r in mine if r["lights_from"] == "median-cut"}
        area = {r["budget"]: r for r in mine if r["lights_from"] == "area" and r["penumbra"] == "fixed"}
        auto = next(r for r in mine if r["lights_from"] == "auto")
        b = auto["budget"]
        # The area set with contact-hardening penumbrae (FrameSettings.penumbra), where it has area lights.
        blocker = next((r for r in mine if r["penumbra"] == "blocker"), None)
        curve = [(r["frame_ms"], r["rel_rmse"]) for r in mc.values()]
        area_curve = [(r["frame_ms"], r["rel_rmse"]) for r in area.values()]
        equal_time = _interp_error(curve, area[b]["frame_ms"])
        # auto against the better of the two at auto's own frame time.
        best = min(_interp_error(curve, auto["frame_ms"]), _interp_error(area_curve, auto["frame_ms"]))
        out.append({"map": name, "set": mine[0]["set"], "area_lights": area[b]["area_lights"],
                    "ambient_share": area[b]["ambient_share"],
                    "median_cut": mc[b]["rel_rmse"], "area": area[b]["rel_rmse"],
                    "median_cut_at_area_time": equal_time, "area_ms": area[b]["frame_ms"],
                    "median_cut_ms": mc[b]["frame_ms"], "auto": auto["rel_rmse"], "auto_used": auto["used"],
                    "auto_over_best": auto["rel_rmse"] / best if best > 0 else float("nan"),
                    "area_blocker": blocker["rel_rmse"] if blocker else None,
                    "area_blocker_ms": blocker["frame_ms"] if blocker else None,
                    "noise_floor": mine[0]["noise_floor"]})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Median cut against area lights, map by map", "",
             f"Made by `garment-render bench --area{' --quick' if data['quick'] else ''}` on {m['gl_renderer']}, "
             f"{m['cores']} cores ({m['date']}): the polo, front, 128 x 128, balanced otherwise; references of "
             f"{data['spp']} spp per technique, two seeds; frame times the median of {data['frames']} frames side by "
             f"side ({data['wall_s'] / 60:.0f} min in all). Balanced's budget of {data['budgets'][-1]} "
             "lights unless said; 'at area's time': the median cut's error interpolated (log time) at the area set's frame time.",
             "", "| map | set | area lights | ambient | median cut | area | median cut at area's time | area ms | "
             "median cut ms | auto (used) | auto / best at its time | area, blocker penumbrae (ms) | floor |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in data["maps"]:
        amb = "-" if c["ambient_share"] is None else f"{c['ambient_share']:.0%}"
        lines.append(f"| {c['map']} | {c['set']} | {c['area_lights']} | {amb} | {c['median_cut']:.3f} | {c['area']:.3f} "
                     f"| {c['median_cut_at_area_time']:.3f} | {c['area_ms']:.0f} | {c['median_cut_ms']:.0f} | "
                     f"{c['auto']:.3f} ({c['auto_used']}) | {c['auto_over_best']:.2f}x | "
                     + ("-" if c["area_blocker"] is None else f"{c['area_blocker']:.3f} ({c['area_blocker_ms']:.0f})")
                     + f" | {c['noise_floor']:.3f} |")
    wins_time = sum(c["area"] < c["median_cut_at_area_time"] for c in data["maps"] if c["area_lights"])
    with_lights = sum(1 for c in data["maps"] if c["area_lights"])
    worst = max(data["maps"], key=lambda c: c["auto_over_best"])
    lines += ["", f"- Maps with area lights: {with_lights} of {len(data['maps'])}; area beats the median cut at "
              f"equal frame time on {wins_time} of them.",
              f"- auto is within {100 * (worst['auto_over_best'] - 1):.1f} % of the better of the two on every map "
              f"(worst: {worst['map']}); the target is 5 %."]
    pen = [c for c in data["maps"] if c["area_blocker"] is not None]
    if pen:
        better = sum(c["area_blocker"] < c["area"] - 0.002 for c in pen)
        worse = sum(c["area_blocker"] > c["area"] + 0.002 for c in pen)
        ratio = np.median([c["area_blocker_ms"] / c["area_ms"] for c in pen])
        lines.append(f"- Blocker penumbrae on the area lights (`penumbra = \"blocker\"`): lower error on {better}, "
                     f"higher on {worse} of {len(pen)} maps (by more than 0.002), median frame time "
                     f"{ratio:.2f}x the fixed maps'.")
    lines.append("")
    if data.get("sweep"):
        lines += ["The knob sweep's scenes (the bundled studio dress; the newton shirt on its dress form; 128 x 128, "
                  "balanced otherwise):", "",
                  "| scene | map | median cut | auto (used, area lights) | median cut ms | auto ms | floor |",
                  "|---|---|---|---|---|---|---|"]
        for w in data["sweep"]:
            lines.append(f"| {w['scene']} | {w['map']} | {w['rel_rmse_median-cut']:.3f} | {w['rel_rmse_auto']:.3f} "
                         f"({w['used_auto']}, {w['area_lights_auto']}) | {w['ms_median-cut']:.0f} | {w['ms_auto']:.0f} | "
                         f"{w['noise_floor']:.3f} |")
        lines.append("")
    lines += ["Every row:", "", "| map | lights_from | budget | penumbra | lights (area) | rel. RMSE | frame ms |",
              "|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(f"| {r['map']} | {r['lights_from']} ({r['used']}) | {r['budget']} | {r['penumbra']} | "
                     f"{r['lights']} ({r['area_lights']}) | {r['rel_rmse']:.3f} | {r['frame_ms']:.0f} |")
    return "\n".join(lines) + "\n"
