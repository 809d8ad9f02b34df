"""Quality presets: the defaults, or the settings chosen from the measured benchmark table when
one is stored in the package (renderer/bench/measured.json, written by `garment-render bench --store`).
Used by the command line, the service and the benchmark alike."""

from __future__ import annotations

# The knobs every preset names; the others (knob_defaults) a preset or budget may also set.
PRESET_KNOBS = ("lights", "face_size", "shadow_size", "blur_scale")
# Knobs of knob_defaults() that change the PEM set, not the frame (pem_settings).
PEM_KNOBS = ("needed_levels", "whole_sources")


def knob_defaults() -> dict:
    """The quality knobs besides a preset's four (lights, PEM face, shadow map, blur) and their
    defaults: what a preset or budget from the measured table may also set, and what the benchmark's
    balanced setting uses. The one place these defaults are stated (FrameSettings' own)."""
    from .renderer import FrameSettings

    f = FrameSettings()
    return {"calibration": f.calibration.value, "diffuse": f.diffuse, "glossy_horizon": f.glossy_horizon,
            "terminator": f.terminator, "horizon": f.horizon, "shadow_threshold": f.shadow_threshold,
            "sh_unshadowed": f.sh_unshadowed, "needed_levels": True, "whole_sources": True, "glossy": f.glossy,
            "caster_detail": f.caster_detail, "small_light_scale": f.small_light_scale,
            "small_light_min_energy": f.small_light_min_energy, "sharp_large_lights": f.sharp_large_lights,
            "sharp_share_deg": f.sharp_share_deg, "sharp_max_maps": f.sharp_max_maps,
            "sharp_full_detail_deg": f.sharp_full_detail_deg, "sub_lights": f.sub_lights,
            "normal_offset_texels": f.normal_offset_texels, "sharp_normal_offset_texels": f.sharp_normal_offset_texels,
            "min_sigma_texels": f.min_sigma_texels, "contact_shadow_texels": f.contact_shadow_texels}


def merge_knobs(base: dict, explicit: dict) -> dict:
    """A preset's or budget's knobs (`base`) over the defaults, with the caller's explicit values
    (None: not given) over both: the one rule the command line, the service and the benchmark share."""
    from .renderer import MAX_SHADOW_SIDE

    knobs = {**knob_defaults(), **base}
    given = {k: v for k, v in explicit.items() if v is not None}
    knobs.update(given)
    missing = [k for k in PRESET_KNOBS if k not in knobs]
    if missing:
        raise ValueError(f"quality knobs without a value: {missing}")
    # A preset's small-light scale yields to an explicit large shadow map (the sharp maps stay within
    # MAX_SHADOW_SIDE); a scale the caller names is kept, and FrameSettings refuses it if too large.
    if "small_light_scale" not in given and int(knobs["shadow_size"]) * int(knobs["small_light_scale"]) > MAX_SHADOW_SIDE:
        knobs["small_light_scale"] = max(1, MAX_SHADOW_SIDE // int(knobs["shadow_size"]))
    return knobs


def frame_settings(knobs: dict, width: int, height: int, **output):
    """The FrameSettings of resolved knobs (`merge_knobs`) for a width x height image; `output` are
    the settings no preset chooses (mode, background, bleed_reduction)."""
    from .renderer import FrameSettings

    frame_knobs = {k: knobs[k] for k in knob_defaults() if k not in PEM_KNOBS}
    return FrameSettings(width=width, height=height, shadow_size=int(knobs["shadow_size"]),
                         blur_scale=float(knobs["blur_scale"]), **frame_knobs, **output)


def pem_settings(knobs: dict, filter, levels: int | None, materials=None):
    """The PEM set's settings of resolved knobs: with needed_levels and the scene's materials, only
    the levels their glossiness reads (the same image, a fraction of the memory); without
    materials, the whole chain."""
    from .lighting.filters import Filter
    from .lighting.pem import PEMSettings

    pem = PEMSettings(int(knobs["lights"]), Filter.parse(filter), levels, whole_sources=bool(knobs["whole_sources"]))
    if knobs["needed_levels"] and materials is not None:
        pem = pem.for_materials(int(knobs["face_size"]), materials, knobs["calibration"])
    return pem


# `table=STORED`: read the package's measured table now (renderer/bench/measured.json); a long-running
# caller passes the table it read at start-up (None: none was stored), so that its presets and budgets agree.
STORED = "stored"


# A preset may also set any knob of knob_defaults() (its value wins over the default), chosen from the
# benchmark (docs/benchmarks.md; numbers from the bench at 794b9ba unless a side run or an older bench
# is named). Blur 0: the paper's blur changed the error by -3 to +12 % at 48 lights (the lights' many
# hard shadows already add up to soft ones) for more time a frame. Caster detail 0.25: -1 to +2 % of
# error for 41-48 % less frame time. The median cut keeps compact sources whole (whole_sources):
# against the paper's plain cut the hard sun 0.106 -> 0.079, the interior 0.079 -> 0.059. The sun's shadow edges are the
# largest error left in sunlit scenes: balanced draws the maps of small lights with at least 2.4x the
# mean light's energy (5 % of it at 48 lights: a sun) at four times the size (hard sun 0.132 ->
# 0.079 against twice); the regions of one sun (a degree apart) share one map (sharp_share_deg 2: the
# same error for 18-20 % less time on the hard sun side by side at a921258; the bench's sharp_share_deg rows); and it leaves
# the dim ones (an interior's ten lamps and windows) to the main maps, where sharp maps for all of
# them cost 1.6x the frame time for less gain. Small lights' diffuse and glossy terms
# in closed form (their disc through the cosine and the Phong lobe) instead of their PEMs'
# prefiltered kernels: the studio dress 0.123 -> 0.052 at balanced (at a921258, with the wide glossy
# lobes below), no scene worse by more than 2 %; not in fast,
# whose hard sun measured worse with them in a side run (not a bench row). The large lights' glossy
# terms too where the lobe is wider than their disc (glossy "wide"): against "mixed" the studio
# dress 0.056 -> 0.023, hard sun 0.083 -> 0.079, interior 0.063 -> 0.059, overcast 0.056 -> 0.041,
# night 0.063 -> 0.040 (the bench's glossy rows); no worse at g = 0.5, 0.95 and 0.99 in a side run
# (before the contact shadows). Lights beyond 48 cost linear time (96 lights: 2.0-2.5x) for -5 to 17 %
# less error; the default accurate preset spends time on shadow maps instead. Contact shadows (contact_shadow_texels) find the occluders the maps' bias skips and
# the near ones a proxy's 256^2 map blurs (the collar over the dress form's neck, the lips of folds):
# at balanced (24 main-map texels, about 10 cm there) against none, hard sun 0.159 -> 0.079,
# interior 0.114 -> 0.059, overcast 0.077 -> 0.041, night 0.087 -> 0.040 rel. RMSE, FLIP lower on
# all (the bench's contact_shadow_texels rows: 8 texels and 48 measure higher on the
# shirt's worst maps). Fast and accurate keep the same distance in the scene (12 texels of 128^2
# maps, 48 of 512^2: side runs at f3dc2e1 put fast's hard sun at 0.211 with 12 against 0.233 with 5,
# and accurate lowest at that distance). With them the large lights' diffuse term from their disc too
# (diffuse "lights", balanced and accurate) against "mixed" (from the PEMs): studio dress 0.049 ->
# 0.023, hard sun 0.086 -> 0.079, interior 0.063 -> 0.059, overcast 0.076 -> 0.041, night 0.066 ->
# 0.040, FLIP lower on all five (worst 0.110 -> 0.073), and no diffuse PEM lookups (the bench's
# diffuse rows).
DEFAULT_PRESETS = {
    "fast": {"lights": 24, "face_size": 64, "shadow_size": 128, "blur_scale": 0.0, "caster_detail": 0.1,
             "contact_shadow_texels": 12.0, "diffuse": "lights", "glossy": "wide"},
    "balanced": {"lights": 48, "face_size": 128, "shadow_size": 256, "blur_scale": 0.0, "caster_detail": 0.25,
                 "small_light_scale": 4, "small_light_min_energy": 2.4, "sharp_share_deg": 2.0,
                 "sharp_full_detail_deg": 2.0, "diffuse": "lights", "glossy": "wide", "sub_lights": 2},
    "accurate": {"lights": 48, "face_size": 128, "shadow_size": 512, "blur_scale": 0.0, "caster_detail": 1.0,
                 "small_light_scale": 2, "sharp_share_deg": 2.0, "diffuse": "lights", "glossy": "wide",
                 "contact_shadow_texels": 48.0, "sub_lights": 2},
}


def presets(table: dict | None | str = STORED) -> tuple[dict, str]:
    """The presets and where they come from: the measured table's when there is one (by default the
    package's stored table, read now; or the table given, None for none), else the defaults."""
    from .bench.budget import PRESET_SPEEDUP, load_table
    from .bench.budget import presets as measured_presets

    if table == STORED:
        table = load_table()
    if table is None:
        return DEFAULT_PRESETS, "default (no measured table stored)"
    found = measured_presets(table, {name: {**merge_knobs(knobs, {}), "filter": "sqrt-cosine"}
                                     for name, knobs in DEFAULT_PRESETS.items()})
    merged = {name: {k: v for k, v in found.get(name, DEFAULT_PRESETS[name]).items() if k != "filter"}
              for name in DEFAULT_PRESETS}
    where = f"{table['machine'].get('gl_renderer', '?')} ({table['machine'].get('date', '?')})"
    measured = [n for n in DEFAULT_PRESETS if n in found]
    fallback = [n for n in DEFAULT_PRESETS if n not in found]
    source = f"measured on {where}: {', '.join(measured) or 'none'}"
    if fallback:
        source += (f"; default (no measured setting within its error target and {PRESET_SPEEDUP:g}x faster than the "
                   f"preset above): {', '.join(fallback)}")
    return merged, source


def base_knobs(preset: str, preset_knobs: dict, preset_source: str | None, frame_budget_ms: float | None,
               error_budget: float | None, table: dict | None | str = STORED) -> tuple[dict, str | None, str]:
    """What a request's knobs go over (`merge_knobs`): the measured setting that meets its budgets
    when it names one (`budget_knobs`, chosen from `table`), else its preset's knobs (from
    `preset_knobs`, the presets in use). Returns (knobs, the measured PEM filter, or None when the
    preset chose them, and where they came from): the one rule the command line and the service share."""
    if frame_budget_ms is not None or error_budget is not None:
        from .bench.budget import budget_knobs

        return budget_knobs(frame_budget_ms, error_budget, table)
    return preset_knobs[preset], None, f"preset {preset}" + (f", {preset_source}" if preset_source else "")

