"""`garment-render bench --sizes` (lab/garment_lab/sizes.py): its settings per size, the box filter to
256, the excess over the floor, the rim ring, and the report on rows of known values."""

from __future__ import annotations

import numpy as np
import pytest

from garment_lab.sizes import TEXEL_KNOBS, _rim, box_down, excess, markdown, summary, variants
from renderer.config import BY_NAME
from renderer.presets import preset


def test_maps_follow_the_image_with_and_without_their_texel_knobs():
    base = preset("balanced")
    assert variants(256) == {"balanced": {}}
    v = variants(1024)
    assert v["maps follow"] == {"shadow_size": 4 * base["shadow_size"]}
    same = v["maps follow, same scene widths"]
    assert same["shadow_size"] == 4 * base["shadow_size"]
    assert all(same[k] == min(4 * base[k], BY_NAME[k].maximum) for k in TEXEL_KNOBS)
    assert len(same) == 1 + len(TEXEL_KNOBS)
    contact = BY_NAME["contact_shadow_texels"]
    assert variants(512)["maps follow, same scene widths"]["contact_shadow_texels"] == \
        min(2 * base["contact_shadow_texels"], contact.maximum)


def test_box_down_averages_blocks_and_keeps_channels():
    img = np.arange(4 * 4 * 2, dtype=np.float64).reshape(4, 4, 2)
    low = box_down(img, 2)
    assert low.shape == (2, 2, 2)
    assert low[0, 0, 0] == pytest.approx(np.mean([0, 2, 8, 10]))
    assert box_down(img, 1) is img


def test_excess_removes_the_floor_in_quadrature():
    assert excess(0.05, 0.03) == pytest.approx(0.04)
    assert excess(0.02, 0.03) == 0.0


def test_rim_is_the_masks_outer_ring():
    mask = np.zeros((6, 6), bool)
    mask[1:5, 1:5] = True
    rim = _rim(mask)
    assert rim.sum() == 12 and not rim[2:4, 2:4].any() and rim[1, 1] and rim[4, 2]


def _row(scene, size, settings, err, floor, err_low, floor_low, set_="tuning"):
    return {"set": set_, "scene": scene, "size": size, "settings": settings, "shadow_size": 256,
            "rel_rmse": err, "floor": floor, "excess": excess(err, floor), "rel_rmse_at_256": err_low,
            "floor_at_256": floor_low, "excess_at_256": excess(err_low, floor_low), "rim_share": 0.1,
            "frame_ms": 100.0, "reference_s": 1.0}


def test_the_report_compares_each_size_with_the_first_and_the_maps_rules_with_balanced():
    rows = [_row("a", 256, "balanced", 0.05, 0.03, 0.05, 0.03),
            _row("a", 1024, "balanced", 0.10, 0.06, 0.05, 0.03),
            _row("a", 1024, "maps follow", 0.1, 0.0, 0.05, 0.03)]
    (s,) = summary(rows)
    assert (s["size"], s["excess_ratio"], s["excess_at_256_ratio"]) == (1024, pytest.approx(2.0), pytest.approx(1.0))
    data = {"machine": {"gl_renderer": "llvmpipe", "cores": 2, "date": "2026-12-03"}, "spp": 8, "frames": 1,
            "wall_s": 60.0, "rows": rows, "summary": [s]}
    text = markdown(data)
    assert "| tuning | a | 1024 | 2.00x | 1.00x |" in text
    assert "maps follow: excess 1.25x balanced's at the same size" in text
