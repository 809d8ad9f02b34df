"""`garment-render bench`: the speed/accuracy trade of every quality knob, measured side by side in
one run on one machine, against the Monte Carlo reference (with its own noise floor stated).

One-at-a-time sweeps around the `balanced` preset (lights, PEM face size, shadow-map size, blur
scale, filter, diffuse and glossy sources, caster detail,
small lights' map size), the other presets as rows of their own, plus baselines timed in the same run on the same scenes: unshadowed prefiltered
environment lighting, the plain many-light method, ambient occlusion times environment lighting
(grey and colour), and the reference at the sample count that reaches the same error.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from renderer import presets
from renderer.camera import frame_meshes
from renderer.errors import InvalidInputError
from renderer.gpu.context import GLContext
from renderer.lighting.filters import Filter
from renderer.presets import PRESET_NAMES, knob_defaults, preset
from renderer.presets.budget import OLD_SHADOW_BIAS
from renderer.reference import artefact_share, mean_flip, relative_rmse, render_reference
from renderer.renderer import FrameSettings, Renderer, ShadingMode

from .report import machine_info
from .scenes import BenchScene, bundled_scene, shared_scenes

BALANCED = {**knob_defaults(), **preset("balanced"), "filter": "sqrt-cosine"}
# The values the sweep measures around balanced for each setting, in the registry's order (a dict
# changes several settings at once): the lab's table, not the registry's (renderer/config.py says what
# a setting is; a setting without a row here is not swept).
SETTING_SWEEPS = {
    "lights": (6, 12, 24, 48, 96, 192, 384),
    "face_size": (32, 64, 128, 256),
    "whole_sources": (False,),
    "lights_from": ("median-cut", "area"),
    "shadow_size": (64, 128, 256, 512),
    "blur_scale": (0.0, 0.1, 0.25, 0.5, 1.0, 2.0),
    "caster_detail": (1.0, 0.5, 0.25, 0.1),
    "normal_offset_texels": (1.0, 3.3),
    "min_sigma_texels": (0.0, 6.0),
    "small_light_scale": (1, 2, 4, {"small_light_scale": 2, "small_light_min_energy": 0.0}),
    "small_light_min_energy": (0.0, 1.0, 4.8),
    "sharp_large_lights": (True, {"sharp_large_lights": True, "small_light_min_energy": 4.8}),
    "sharp_share_deg": (0.0, 1.0, 4.0),
    "contact_shadow_texels": (0.0, 8.0, 48.0),
    "diffuse": ("pem",),
    "glossy": ("pem",),
    "sub_lights": (1, 4, 8),
}
# The sweep: each setting's row, then the rows that are not one setting: the PEM filter, the paper's
# lookups for both terms, the bias before it was stated in texels, the other presets as a whole
# (accurate is balanced at 192 lights: the lights row, except in the quick sweep).
SWEEPS = {
    **{name: list(values) for name, values in SETTING_SWEEPS.items()},
    "filter": [f.value for f in Filter],
    "source": [{"diffuse": "pem", "glossy": "pem"}],
    "shadow_bias": [OLD_SHADOW_BIAS],
    "preset": [preset("fast")],
}
QUICK_SWEEPS = {**SWEEPS, "lights": [6, 24, 48, 96], "face_size": [64, 128], "shadow_size": [128, 256],
                "blur_scale": [0.0, 0.1, 1.0], "filter": ["none", "sqrt-cosine"],
                "caster_detail": [1.0], "small_light_scale": [1, 2], "small_light_min_energy": [0.0],
                "contact_shadow_texels": [0.0], "sub_lights": [1],
                "preset": [preset("fast"), preset("accurate")]}
BASELINE_MODES = [ShadingMode.NO_OCCLUSION, ShadingMode.MANY_LIGHTS, ShadingMode.AO_GREY, ShadingMode.AO_COLOUR]


@dataclass
class BenchConfig:
    quick: bool = False
    size: int = 256
    frames: int = 5           # timed frames per setting (after one warm-up frame)
    # Samples per pixel of each of the reference's two independent renders (the truth is their mean).
    # The error targets are 5 %: the reference's own noise must sit well below (one render against the
    # other 2.3-3.8 % at 256^2 and 1024 spp on the target scenes; the mean's own is about half that).
    ref_spp: int = 1024
    ladder: tuple = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512)  # reference sample counts for equal-error timing
    shared: bool = True

    @classmethod
    def quick_config(cls) -> BenchConfig:
        return cls(quick=True, size=128, frames=3, ref_spp=512, ladder=(1, 2, 4, 8, 16, 32, 64, 128, 256))


@dataclass
class Row:
    scene: str
    env: str
    knob: str
    value: object
    mode: str
    settings: dict
    frame_ms: float
    stages_ms: dict
    pem_build_ms: float
    pem_bytes: int
    shadow_bytes: int
    rel_rmse: float
    flip: float
    ref_noise_rel_rmse: float
    ref_noise_flip: float
    ref_equal_error_spp: int | None = None
    ref_equal_error_ms: float | None = None
    speedup_vs_reference: float | None = None
    extra: dict = field(default_factory=dict)


def _settings_list(sweeps: dict) -> list[tuple[str, object, dict]]:
    out = [("balanced", "balanced", dict(BALANCED))]
    for knob, values in sweeps.items():
        for v in values:
            # A preset row is the preset as the CLI and service apply it (its knobs over the defaults),
            # not balanced with the preset's knobs changed.
            if knob == "preset":
                s = {**presets.merge_knobs(v, {}), "filter": BALANCED["filter"]}
            else:
                s = {**BALANCED, **(v if isinstance(v, dict) else {knob: v})}
            if s == BALANCED:
                continue
            label = ", ".join(f"{k}={x}" for k, x in v.items()) if isinstance(v, dict) else v
            label = next((name for name in PRESET_NAMES if knob == "preset" and preset(name) == v), label)
            out.append((knob, label, s))
    return out


def frame_settings(s: dict, size: int, mode: ShadingMode = ShadingMode.FULL) -> FrameSettings:
    """A benchmark setting (BALANCED's keys) as the frame settings of a size x size image."""
    return presets.frame_settings(s, size, size, mode=mode)


def _pems_for(r: Renderer, bs: BenchScene, s: dict, cache: dict):
    """The PEM set of a setting, built once per (face size, PEM settings) into `cache`."""
    pem = presets.pem_settings(s, s["filter"], None, bs.materials)
    key = (s["face_size"], pem.key())
    if key not in cache:
        cache[key] = r.build_pems(bs.cube(s["face_size"]), pem)
    return cache[key]


def time_frames(r: Renderer, scene, pems, fs: FrameSettings, camera, n: int):
    r.render(scene, pems, fs, camera)  # warm-up: shader compilation, allocations
    frames = [r.render(scene, pems, fs, camera) for _ in range(n)]
    frame_ms = float(np.median([f.timings["frame_wall_ms"] for f in frames]))
    stages = {k: float(np.median([f.timings["wall_ms"].get(k, 0.0) for f in frames])) for k in frames[0].timings["wall_ms"]}
    return frames[-1], frame_ms, stages


def bench_scene(r: Renderer, bs: BenchScene, cfg: BenchConfig, log=print, refused: list | None = None) -> list[Row]:
    """The scene's rows, one per setting of the sweep. A setting the renderer refuses on this machine
    (its shadow maps beyond what the GL driver allocates) makes no row: it goes to `refused` (scene,
    knob, value and the renderer's reason) and the sweep goes on."""
    size = cfg.size
    camera = frame_meshes(bs.meshes, 1.0)
    sweeps = QUICK_SWEEPS if cfg.quick else SWEEPS

    # Ground truth and its own noise floor: two independent reference renders.
    ref_cube = bs.cube(BALANCED["face_size"] * 2 if not cfg.quick else BALANCED["face_size"])
    t0 = time.perf_counter()
    ref_a = render_reference(bs.meshes, bs.materials, ref_cube, camera, size, size, cfg.ref_spp, seed=1)
    ref_s = time.perf_counter() - t0
    ref_b = render_reference(bs.meshes, bs.materials, ref_cube, camera, size, size, cfg.ref_spp, seed=2)
    mask = ref_a.image[..., 3] > 0.5
    # The floor: one seed against the other, what a perfect renderer would score against one of
    # them. The truth is their mean (2 x ref_spp samples): its own rel. RMSE is about half the floor's.
    noise_rmse = relative_rmse(ref_b.image, ref_a.image, mask)
    noise_flip = mean_flip(ref_b.image, ref_a.image, mask)
    truth = 0.5 * (ref_a.image + ref_b.image)
    log(f"  reference 2 x {cfg.ref_spp} spp: {ref_s:.1f} s each; noise floor (one seed against the other) "
        f"rel. RMSE {noise_rmse:.4f}, FLIP {noise_flip:.4f}")

    # Reference error and time against sample count, for the equal-error comparison.
    ladder = []
    for spp in cfg.ladder:
        t0 = time.perf_counter()
        low = render_reference(bs.meshes, bs.materials, ref_cube, camera, size, size, spp, seed=100 + spp)
        ladder.append((spp, (time.perf_counter() - t0) * 1e3, relative_rmse(low.image, truth, mask)))
    log("  reference ladder: " + ", ".join(f"{s} spp {ms:.0f} ms err {e:.3f}" for s, ms, e in ladder))

    def equal_error(err: float):
        for spp, ms, e in ladder:
            if e <= err:
                return spp, ms
        return None, None

    rows = []
    scene = r.create_scene(bs.meshes, bs.materials)
    pem_cache: dict[tuple, object] = {}
    try:
        jobs = [(k, v, s, ShadingMode.FULL) for k, v, s in _settings_list(sweeps)]
        jobs += [("baseline", m.value, dict(BALANCED), m) for m in BASELINE_MODES]
        for knob, value, s, mode in jobs:
            pems = _pems_for(r, bs, s, pem_cache)
            fs = frame_settings(s, size, mode)
            try:
                frame, frame_ms, stages = time_frames(r, scene, pems, fs, camera, cfg.frames)
            except InvalidInputError as exc:
                if refused is not None:
                    refused.append({"scene": bs.name, "knob": knob, "value": value, "mode": mode.value, "why": str(exc)})
                log(f"  {knob}={value} [{mode.value}]: not run: {exc}")
                continue
            err = relative_rmse(frame.image, truth, mask)
            flip = mean_flip(frame.image, truth, mask)
            artefacts = artefact_share(frame.image, ref_a.image, ref_b.image, mask)
            spp, ref_ms = equal_error(err)
            row = Row(bs.name, bs.env_name, knob, value, mode.value, s, frame_ms, stages, pems.build_ms, pems.nbytes,
                      frame.settings["shadow_bytes"], err, flip, noise_rmse, noise_flip, spp, ref_ms,
                      (ref_ms / frame_ms) if ref_ms else None,
                      extra={"ref_ladder_top_ms": ladder[-1][1], "artefact_share": artefacts.share,
                             "artefact_judged": artefacts.judged})
            rows.append(row)
            log(f"  {knob}={value} [{mode.value}]: {frame_ms:.0f} ms, rel. RMSE {err:.4f}, FLIP {flip:.4f}"
                + (f", reference needs {spp} spp ({ref_ms:.0f} ms)" if spp else ", reference ladder never this good"))
    finally:
        for p in pem_cache.values():
            p.release()
        scene.release()
    return rows


def run_bench(out_dir: Path, cfg: BenchConfig, log=print) -> list[Row]:
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = [bundled_scene()] + (shared_scenes() if cfg.shared else [])
    gl = GLContext()
    rows: list[Row] = []
    refused: list[dict] = []
    with Renderer(gl) as r:
        machine = machine_info(gl)
        for bs in scenes:
            log(f"scene {bs.name} ({bs.env_name})")
            rows += bench_scene(r, bs, cfg, log, refused)
            _write(out_dir, rows, machine, cfg, refused)  # partial results survive an interrupted run
    gl.release()
    return rows


def _write(out_dir: Path, rows: list[Row], machine: dict, cfg: BenchConfig, refused: list[dict] = ()) -> None:
    from renderer.presets import presets_digest

    from .report import write_markdown, write_pareto

    (out_dir / "bench.json").write_text(json.dumps(
        {"machine": machine, "presets_digest": presets_digest(), "config": asdict(cfg),
         "rows": [asdict(r) for r in rows], "refused": list(refused)}, indent=1, default=float))
    write_markdown(out_dir / "bench.md", rows, machine, cfg, refused)
    write_pareto(out_dir / "pareto.png", rows)
