"""`garment-render bench --shadow-maps` (lab/garment_lab/shadow_maps.py): its variants keep the contact
search's reach in the scene, and its report compares each variant with the first scene by scene."""

from __future__ import annotations

import pytest

from garment_lab.shadow_maps import VARIANTS, markdown, summary


def test_every_variant_keeps_the_contact_reach_of_24_texels_at_256():
    for knobs in VARIANTS.values():
        assert knobs["contact_shadow_texels"] * 256 / knobs["shadow_size"] == pytest.approx(24.0)
    first = next(iter(VARIANTS.values()))
    assert (first["shadow_size"], first["caster_detail"]) == (256, 0.25)


def _row(which, excesses, times):
    return {"set": which, "garment": "shirt", "map": "m.hdr", "floor": 0.05,
            "variants": {k: {"rel_rmse": e + 0.05, "excess": e, "frame_ms": t}
                         for k, e, t in zip(("a", "b"), excesses, times)}}


def test_ratios_are_taken_scene_by_scene_then_the_median():
    rows = [_row("tuning", (0.10, 0.05), (100.0, 200.0)), _row("tuning", (0.02, 0.03), (100.0, 150.0)),
            _row("tuning", (0.04, 0.04), (100.0, 100.0)), _row("held-out", (0.2, 0.1), (50.0, 75.0))]
    s = {(x["set"], x["variant"]): x for x in summary(rows, ["a", "b"])}
    b = s[("tuning", "b")]
    assert b["excess_ratio"] == pytest.approx(1.0) and b["excess_ratio_min"] == pytest.approx(0.5)
    assert b["excess_ratio_max"] == pytest.approx(1.5) and b["time_ratio"] == pytest.approx(1.5)
    assert b["worst_rel_rmse"] == pytest.approx(0.10) and b["scenes"] == 3
    assert s[("held-out", "b")]["excess_ratio"] == pytest.approx(0.5)
    data = {"machine": {"gl_renderer": "llvmpipe", "cores": 2, "date": "2026-12-03"}, "spp": 8, "frames": 1,
            "size": 256, "variants": {"a": {}, "b": {}}, "wall_s": 60.0, "rows": rows,
            "summary": summary(rows, ["a", "b"])}
    text = markdown(data)
    assert "| held-out | b | 1 | 0.50x (0.50-0.50) | 0.150 | 0.150 | 1.50x |" in text
    assert "| tuning | shirt | m.hdr | 0.050 | 0.100 (100) | 0.050 (200) |" in text
