"""Quality settings chosen from the measured benchmark table, never guessed.

`garment-render bench` writes `bench.json`; `summarize` reduces it to one entry per setting (worst
relative RMSE over the scenes, median frame time over the scenes) and `write_table` stores that in
the package (`measured.json`), from which per-request budgets are chosen (the presets are files of
their own: renderer/presets).
"""

from __future__ import annotations

import json
from pathlib import Path

from .. import config
from ..atomic import atomic_file
from ..errors import InvalidInputError

MEASURED = Path(__file__).with_name("measured.json")
# `table=STORED`: read the package's measured table now (MEASURED); a long-running caller passes the
# table it read at start-up (None: none was stored), so that every budget chooses from one.
STORED = "stored"

# Every knob a table entry records: the presets' four, the PEM filter and the others.
KNOBS = (*config.NAMES, "filter")
# The shadow bias before it was stated in each map's texels: 1.5 x 2 |box diagonal| / map size (about
# 3.3 texels on the bench scenes) and an absolute variance floor of 1e-6 in depth units (about 0.25
# texels of a 256^2 map, 1 of a 1024^2 one: this approximates it). The bench's shadow_bias row.
OLD_SHADOW_BIAS = {"normal_offset_texels": 3.3, "min_sigma_texels": 0.25}
# Knobs added after a table was stored take the value they had then (the only one there was).
KNOB_DEFAULTS = {"diffuse": "pem", "caster_detail": 1.0, "small_light_scale": 1, "small_light_min_energy": 0.0,
                 "glossy": "pem", "sharp_large_lights": False, "sharp_share_deg": 0.0, "sub_lights": 1,
                 **OLD_SHADOW_BIAS, "contact_shadow_texels": 0.0, "whole_sources": False,
                 "lobes": 1,   # before the fitted lobes, every pixel had the one Phong lobe
                 "lights_from": "median-cut", "penumbra": "fixed",
                 "aa_samples": 1}   # before anti-aliasing, one sample a pixel


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
    return {"machine": bench["machine"], "presets_digest": bench.get("presets_digest"), "size": bench["config"]["size"],
            "entries": entries}


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


def check_device(measured_on: str | None, device: str | None) -> None:
    """A budget's table, measured on the GL renderer `measured_on`, applied on `device` (None: not
    known, not checked): another device is refused."""
    if device is not None and measured_on is not None and device != measured_on:
        raise InvalidInputError(
            f"budgets choose from settings measured on {measured_on}; this renderer runs on {device}, where their "
            "times and errors were not measured: name a preset, or store a table measured on this device "
            "(garment-render bench --store)")


def budget_knobs(frame_budget_ms: float | None, error_budget: float | None,
                 table: dict | None | str = STORED, size: tuple[int, int] | None = None,
                 device: str | None = None) -> tuple[dict, str, str]:
    """The knobs (without the filter), the PEM filter and a description of the table's entry that
    meets the budgets (`choose`): what the command line and the service apply for a budget. A table
    is measured at one image size on one machine: a frame of another `size` (width, height) is
    refused, not guessed at (times and errors change with the pixels), and so is a renderer on another
    `device` (the GL renderer's name; None: not checked)."""
    table = load_table() if table == STORED else table
    if table is None:
        raise InvalidInputError("budgets choose from the measured table (renderer/presets/measured.json), and none "
                                "is stored: run `garment-render bench --store` first, or name a preset")
    check_device(table["machine"].get("gl_renderer"), device)
    measured = table.get("size")
    if size is not None and measured is not None and tuple(size) != (measured, measured):
        raise InvalidInputError(
            f"budgets choose from settings measured at {measured}x{measured} on "
            f"{table['machine'].get('gl_renderer', '?')}; a {size[0]}x{size[1]} frame's time and error were not "
            f"measured: render at {measured}x{measured}, name a preset, or store a table measured at this size "
            "(garment-render bench --store)")
    entry = choose(table, frame_budget_ms, error_budget)
    knobs = {k: entry["settings"].get(k, KNOB_DEFAULTS.get(k)) for k in KNOBS if k != "filter"}
    source = (f"budget: measured {entry['median_frame_ms']:.1f} ms median, worst rel. RMSE "
              f"{entry['worst_rel_rmse']:.4f} on {table['machine'].get('gl_renderer', '?')} "
              f"({table['machine'].get('date', '?')})")
    return knobs, entry["settings"].get("filter", "sqrt-cosine"), source
