"""A false shadow band: balanced once drew a vertical band 2x too dark down a shirt's front under a
studio lit by softboxes (3.4 % of the garment's pixels, median cut and area lights alike). The shirt of
the shared cloth simulation under the bundled softbox studio, the command line's render against its
reference, both as a user makes them."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest
from conftest import asset, needs_assets

from renderer.cli import main


def _rgba(path) -> np.ndarray:
    ch = OpenEXR.File(str(path), separate_channels=True).channels()
    return np.stack([ch[c].pixels for c in "RGBA"], axis=-1).astype(np.float64)


def _box(x: np.ndarray, k: int = 2) -> np.ndarray:
    """The mean over (2k + 1)^2 pixels: a band is many pixels wide, the reference's noise is not."""
    p = np.pad(x, k, mode="edge")
    return sum(p[k + dy:k + dy + x.shape[0], k + dx:k + dx + x.shape[1]]
               for dy in range(-k, k + 1) for dx in range(-k, k + 1)) / (2 * k + 1) ** 2


@pytest.mark.system
@needs_assets
@pytest.mark.parametrize("lights_from", ["median-cut", "area"])
def test_no_false_shadow_band_on_the_shirt_under_the_softbox_studio(tmp_path, lights_from):
    shirt, colliders = asset("sim", "newton_shirt_drape_f060.obj"), asset("sim", "newton_shirt_drape_colliders.obj")
    scene = ["--up", "z", "--mesh", str(shirt), "--mesh", str(colliders), "--size", "128x128", "--background", "black"]
    assert main(["render", *scene, "--preset", "balanced", "--lights-from", lights_from,
                 "--exr", str(tmp_path / "a.exr"), "--out", str(tmp_path / "a.png")]) == 0
    assert main(["reference", *scene, "--spp", "64", "--exr", str(tmp_path / "r.exr")]) == 0
    ours, ref = _rgba(tmp_path / "a.exr"), _rgba(tmp_path / "r.exr")
    covered = (ours[..., 3] > 0.5) & (ref[..., 3] > 0.5)
    inside = _box(covered.astype(float)) > 0.99          # whole 5 x 5 windows of the garment
    ratio = _box(ours[..., :3].mean(-1) * covered)[inside] / np.maximum(_box(ref[..., :3].mean(-1) * covered)[inside],
                                                                        1e-12)
    assert inside.sum() > 2000
    # No window of the garment 2x too dark (the band was 3.4 % of its pixels) or 2x too bright, and the
    # garment as bright as the reference within 10 %.
    assert np.mean(ratio < 0.5) < 0.001 and np.mean(ratio > 2.0) < 0.001, (np.mean(ratio < 0.5), np.mean(ratio > 2.0))
    assert 0.9 < np.median(ratio) < 1.1, np.median(ratio)
