"""Quality settings chosen from the measured benchmark table, never guessed.

`garment-render bench` writes `bench.json`; `summarize` reduces it to one entry per setting (worst
relative RMSE over the scenes, median frame time over the scenes) and `write_table` stores that in
the package (`measured.json`), from which the presets and per-request budgets are chosen.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..atomic import atomic_file
from ..errors import InvalidInputError
from ..presets import PRESET_KNOBS, STORED, knob_defaults

MEASURED = Path(__file__).with_name("measured.json")

# Error targets of the presets (relative RMSE against the Monte Carlo reference, worst scene).
PRESET_ERROR = {"fast": 0.10, "balanced": 0.05}
# A measured preset must be this much faster than the preset above it: the bench times its rows one
# after another, and on a shared machine the same work differs by up to 1.3-1.4x between rows
# (docs/benchmarks.md). A setting that costs more than balanced side by side can measure a little
# faster in the bench, and is no fast preset.
PRESET_SPEEDUP = 1.4
# Every knob a table entry records: the presets' four, the PEM filter and the others.
KNOBS = (*PRESET_KNOBS, "filter", *knob_defaults())
# The shadow bias before it was stated in each map's texels: 1.5 x 2 |box diagonal| / map size (about
# 3.3 texels on the bench scenes) and an absolute variance floor of 1e-6 in depth units (about 0.25
# texels of a 256^2 map, 1 of a 1024^2 one: this approximates it). The bench's shadow_bias row.
OLD_SHADOW_BIAS = {"normal_offset_texels": 3.3, "sharp_normal_offset_texels": 3.3, "min_sigma_texels": 0.25}
# Knobs added after a table was stored take the value they had then (the only one there was).
KNOB_DEFAULTS = {"horizon": False, "calibration": "volume", "diffuse": "pem", "glossy_horizon": "off",
                "terminator": False, "needed_levels": False, "shadow_threshold": 0.0, "sh_unshadowed": False,
                "caster_detail": 1.0, "small_light_scale": 1, "small_light_min_energy": 0.0, "glossy": "pem",
                "sharp_large_lights": False, "sharp_share_deg": 0.0, "sharp_max_maps": 0, "sharp_full_detail_deg": 90.0,
                "sub_lights": 1, **OLD_SHADOW_BIAS,
                "contact_shadow_texels": 0.0, "whole_sources": False}


def summarize(bench: dict) -> dict:
    """One entry per distinct setting of the full method: worst error and median time over scenes."""
    groups: dict[tuple, list] = {}
    for row in bench["rows"]:
        if row["mode"] != "full":
            continue
        key = tuple(row["settings"].get(k, KNOB_DEFAULTS.get(k)) for k in KNOBS)
        groups.setdefault(key, []).append(row)
    entries = []
    for key, rows in groups.items():
        times = sorted(r["frame_ms"] for r in rows)
        entries.append({"settings": dict(zip(KNOBS, key)),
                        "worst_rel_rmse": max(r["rel_rmse"] for r in rows),
                        "median_frame_ms": times[len(times) // 2],
                        "scenes": sorted(r["scene"] for r in rows)})
    return {"machine": bench["machine"], "size": bench["config"]["size"], "entries": entries}


def write_table(bench_json: Path, out: Path = MEASURED) -> dict:
    table = summarize(json.loads(Path(bench_json).read_text()))
    with atomic_file(out) as f:   # the package's table: readers never see half of it
        f.write(json.dumps(table, indent=1).encode())
    return table


def load_table(path: Path = MEASURED) -> dict | None:
    return json.loads(path.read_text()) if path.exists() else None


def choose(table: dict, frame_budget_ms: float | None = None, error_budget: float | None = None) -> dict:
    """The measured setting that meets the budgets: with an error budget, the fastest setting whose
    worst error is within it; with a frame budget, the most accurate setting within it; with both,
    the most accurate within both. Returns the table entry (settings, error, time)."""
    entries = table["entries"]
    if frame_budget_ms is not None:
        entries = [e for e in entries if e["median_frame_ms"] <= frame_budget_ms]
    if error_budget is not None:
        entries = [e for e in entries if e["worst_rel_rmse"] <= error_budget]
    if not entries:
        raise InvalidInputError(
            f"no measured setting meets frame budget {frame_budget_ms} ms and error budget {error_budget} "
            f"(measured on {table['machine'].get('gl_renderer', '?')}); relax a budget")
    if error_budget is not None and frame_budget_ms is None:
        return min(entries, key=lambda e: e["median_frame_ms"])
    return min(entries, key=lambda e: (e["worst_rel_rmse"], e["median_frame_ms"]))


def budget_knobs(frame_budget_ms: float | None, error_budget: float | None,
                 table: dict | None | str = STORED) -> tuple[dict, str, str]:
    """The knobs (without the filter), the PEM filter and a description of the table's entry that
    meets the budgets (`choose`): what the command line and the service apply for a budget."""
    table = load_table() if table == STORED else table
    if table is None:
        raise InvalidInputError("budgets choose from the measured table (renderer/bench/measured.json), and none "
                                "is stored: run `garment-render bench --store` first, or name a preset")
    entry = choose(table, frame_budget_ms, error_budget)
    knobs = {k: v for k, v in entry["settings"].items() if k != "filter"}
    source = (f"budget: measured {entry['median_frame_ms']:.1f} ms median, worst rel. RMSE "
              f"{entry['worst_rel_rmse']:.4f} on {table['machine'].get('gl_renderer', '?')} "
              f"({table['machine'].get('date', '?')})")
    return knobs, entry["settings"].get("filter", "sqrt-cosine"), source


def _entry_of(table: dict, knobs: dict) -> dict | None:
    """The table's entry of exactly these knobs (every KNOBS value), if it was measured."""
    want = tuple(knobs.get(k) for k in KNOBS)
    return next((e for e in table["entries"] if tuple(e["settings"].get(k) for k in KNOBS) == want), None)


def presets(table: dict, defaults: dict[str, dict] | None = None) -> dict[str, dict]:
    """accurate: the lowest error; balanced / fast: the fastest settings within 5 % / 10 % worst error,
    each the preset above's setting or at least PRESET_SPEEDUP times faster than it (a 10 % setting
    that takes about as long as balanced is no fast preset). `defaults`: a preset's knobs when the
    table has none for it: their entry's time is then the bound for the preset below, and without an
    entry (the default was not measured) the presets below cannot be shown to be faster and are left
    to their defaults too. Presets the table has no setting for are left out."""
    best = choose(table)
    out = {"accurate": best["settings"]}
    above = best
    for name in ("balanced", "fast"):
        try:
            entry = choose(table, error_budget=PRESET_ERROR[name])
        except InvalidInputError:
            entry = None
        # The same setting as the preset above (it is the fastest within this target too), or one clearly faster.
        if entry is not None and above is not None and (
                entry["settings"] == above["settings"]
                or entry["median_frame_ms"] * PRESET_SPEEDUP <= above["median_frame_ms"]):
            out[name] = entry["settings"]
        else:
            entry = _entry_of(table, defaults[name]) if defaults and name in defaults else None
        above = entry
    return out
