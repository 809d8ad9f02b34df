"""Preview of a PEM set's median-cut regions: a lat-long image (top row +Y, centre -Z, as in
renderer/envmap/layouts.py) where each region has its own colour, shaded by the map's own brightness,
with region borders drawn dark and every light marked at its direction (circle area ~ energy share).
numpy + Pillow only; runs off the GL thread."""

from __future__ import annotations

import io

import numpy as np

from renderer.envmap import Layout, cube_to_latlong, dir_to_image, dir_to_texel, image_to_dir
from renderer.lighting.median_cut import LUMINANCE_RGB
from renderer.shading.tonemap import srgb_pnginfo


def _palette(n: int) -> np.ndarray:
    """n distinct colours: hues stepped by the golden angle, alternating lightness. float (n, 3) in [0, 1]."""
    k = np.arange(n)
    hue = (k * 0.618033988749895) % 1.0
    sat = 0.55 + 0.25 * (k % 2)
    val = 0.95 - 0.2 * ((k // 2) % 2)
    # HSV -> RGB, vectorised.
    h6 = hue * 6.0
    i = np.floor(h6).astype(int) % 6
    f = h6 - np.floor(h6)
    p, q, t = val * (1 - sat), val * (1 - sat * f), val * (1 - sat * (1 - f))
    table = np.stack([
        np.stack([val, t, p], -1), np.stack([q, val, p], -1), np.stack([p, val, t], -1),
        np.stack([p, q, val], -1), np.stack([t, p, val], -1), np.stack([val, p, q], -1)])
    return table[i, k]


def region_preview_png(cube: np.ndarray, labels: np.ndarray, directions: np.ndarray, energy_rgb: np.ndarray,
                       width: int = 512) -> bytes:
    """cube (6, F, F, 3) linear radiance; labels (6, F, F) region ids; directions (N, 3); energy_rgb (N, 3)."""
    from PIL import Image, ImageDraw

    w = max(16, int(width)) // 2 * 2
    h = w // 2
    n_face = labels.shape[1]
    xs = np.arange(w) + 0.5
    ys = np.arange(h) + 0.5
    d, _ = image_to_dir(xs[None, :], ys[:, None], Layout.LATLONG, h, w)
    face, row, col = dir_to_texel(d, n_face)
    ids = labels[face, row, col]

    # Brightness of the map itself, log-compressed into [0.25, 1] so that dark regions stay visible.
    lum = cube_to_latlong(cube, h, w)[..., :3] @ LUMINANCE_RGB
    log_l = np.log2(np.maximum(lum, 1e-6))
    lo, hi = np.percentile(log_l, [2, 99.5])
    shade = 0.25 + 0.75 * np.clip((log_l - lo) / max(hi - lo, 1e-6), 0.0, 1.0)

    n = directions.shape[0]
    rgb = _palette(n)[ids] * shade[..., None]
    border = np.zeros((h, w), bool)
    border[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    border[1:, :] |= ids[1:, :] != ids[:-1, :]
    rgb[border] *= 0.25
    img = Image.fromarray(np.rint(np.clip(rgb, 0, 1) * 255).astype(np.uint8))

    draw = ImageDraw.Draw(img)
    energy = np.asarray(energy_rgb, np.float64) @ LUMINANCE_RGB
    share = energy / max(float(energy.sum()), 1e-30)
    px, py, _ = dir_to_image(np.asarray(directions, np.float64), Layout.LATLONG, h, w)
    for x, y, s in zip(px, py, share):
        r = 2.0 + 0.04 * w * np.sqrt(s)  # area ~ share of the energy
        draw.ellipse([x - r - 1, y - r - 1, x + r + 1, y + r + 1], outline=(0, 0, 0), width=1)
        draw.ellipse([x - r, y - r, x + r, y + r], outline=(255, 255, 255), width=2)
        draw.line([x - 1, y, x + 1, y], fill=(255, 255, 255))
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=3, pnginfo=srgb_pnginfo())
    return buf.getvalue()
