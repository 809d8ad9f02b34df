"""`garment-render bench --area`'s comparison (lab/garment_lab/area.py): equal light count, equal frame
time, auto against the better of the two, and the blocker penumbrae's column, on rows of known values."""

from __future__ import annotations

import pytest

from garment_lab.area import compare, markdown


def _row(lights_from, budget, err, ms, area_lights=2, penumbra="fixed"):
    return {"map": "m.hdr", "set": "tuning", "lights_from": lights_from, "budget": budget, "penumbra": penumbra,
            "used": "area" if lights_from != "median-cut" else "median-cut", "lights": budget,
            "area_lights": 0 if lights_from == "median-cut" else area_lights, "ambient_share": 0.4,
            "rel_rmse": err, "noise_floor": 0.05, "frame_ms": ms}


ROWS = [_row("median-cut", 12, 0.30, 50.0), _row("area", 12, 0.25, 40.0),
        _row("median-cut", 24, 0.20, 100.0), _row("area", 24, 0.18, 80.0),
        _row("median-cut", 48, 0.10, 200.0), _row("area", 48, 0.12, 100.0),
        _row("auto", 48, 0.12, 100.0), _row("area", 48, 0.11, 150.0, penumbra="blocker")]


def test_area_is_judged_against_the_median_cut_at_its_own_frame_time():
    (c,) = compare(ROWS)
    assert c["median_cut"] == 0.10 and c["area"] == 0.12   # equal light count
    # At area's 100 ms the median cut's curve reads its 24-light point exactly.
    assert c["median_cut_at_area_time"] == pytest.approx(0.20)
    # auto (0.12 at 100 ms) against the better of the two curves there: area's own 0.12.
    assert c["auto_over_best"] == pytest.approx(1.0)
    assert (c["area_blocker"], c["area_blocker_ms"]) == (0.11, 150.0)


def test_the_table_says_where_the_blocker_penumbrae_win_and_what_they_cost():
    data = {"machine": {"gl_renderer": "llvmpipe", "cores": 2, "date": "2026-12-02"}, "quick": False, "spp": 8,
            "frames": 1, "budgets": [12, 24, 48], "wall_s": 60.0, "rows": ROWS, "maps": compare(ROWS)}
    text = markdown(data)
    assert "0.110 (150)" in text and "budget of 48 lights" in text
    assert "lower error on 1, higher on 0 of 1 maps" in text and "1.50x the fixed maps'" in text
    # A map without area lights has no blocker row, and its column says so.
    rows = [dict(r, area_lights=0) for r in ROWS if r["penumbra"] == "fixed"]
    (c,) = compare(rows)
    assert c["area_blocker"] is None and "| - |" in markdown(dict(data, rows=rows, maps=[c]))
