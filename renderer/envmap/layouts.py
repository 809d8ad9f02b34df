"""Environment-map layouts and their area-correct resampling to the cube map of `cube.py` (numpy only).

Conventions (world right-handed, Y up; a direction points away from the scene, towards the light):

Lat-long (equirectangular), H x W, any size (2:1 when detected). Column coordinate u = x_px / W in
[0, 1), row coordinate v = y_px / H in [0, 1), top to bottom; pixel centres at +0.5.
    azimuth   phi   = 2 pi (u - 0.5)
    elevation theta = pi (0.5 - v)
    d = (sin(phi) cos(theta), sin(theta), -cos(phi) cos(theta))
so the image centre is -Z, u = 0.75 is +X, u = 0.25 is -X, the left/right edge is +Z, the top row +Y.

Angular light probe (P. Debevec, "Light Probe Image Gallery", pauldebevec.com/Probes), square. For a
unit direction D the image point is (x, y) = (Dx r, Dy r) in [-1, 1]^2 with
    r = (1 / pi) acos(Dz) / sqrt(Dx^2 + Dy^2),
image x to the right, image y UP (row = (1 - y) / 2 * H). The centre is +Z (a mirror ball seen by a
camera looking down -Z), the rim is -Z; outside the unit disc is invalid.

Crosses: six square tiles, each a perspective view with forward f, right r and up w; inside a tile
    x = dot(d, r) / dot(d, f),  y = dot(d, w) / dot(d, f)  in [-1, 1],  image y up inside the tile.

    horizontal cross (4 x 3 tiles)          vertical cross (3 x 4 tiles)
         +----+                                  +----+
         | +Y |                                  | +Y |
    +----+----+----+----+                   +----+----+----+
    | -X | -Z | +X | +Z |                   | -X | -Z | +X |
    +----+----+----+----+                   +----+----+----+
         | -Y |                                  | -Y |
         +----+                                  +----+
                                                 | +Z |
                                                 +----+
    tile  f    r    w                       (same frames; the vertical +Z tile is f=+Z, r=+X, w=-Y)
    -X    -X   -Z   +Y
    -Z    -Z   +X   +Y
    +X    +X   +Z   +Y
    +Z    +Z   -X   +Y
    +Y    +Y   +X   +Z
    -Y    -Y   +X   -Z
These frames make the unfolding continuous across every edge the tiles share in the image.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import NamedTuple

import numpy as np

from renderer.envmap.cube import face_uv_to_dir, sample_bilinear, texel_solid_angles
from renderer.errors import EnvironmentMapError, InvalidInputError
from renderer.threads import map_threads


class Layout(str, Enum):
    LATLONG = "latlong"
    ANGULAR = "angular"
    HCROSS = "hcross"
    VCROSS = "vcross"


_ASPECTS = "2:1 lat-long, 1:1 angular light probe, 4:3 horizontal cross, 3:4 vertical cross (width:height)"

_X, _Y, _Z = np.eye(3)
# (column, row, forward, right, up) of each tile, in the grid of tiles.
_HCROSS_TILES = (
    (0, 1, -_X, -_Z, _Y),
    (1, 1, -_Z, _X, _Y),
    (2, 1, _X, _Z, _Y),
    (3, 1, _Z, -_X, _Y),
    (1, 0, _Y, _X, _Z),
    (1, 2, -_Y, _X, -_Z),
)
_VCROSS_TILES = (
    (1, 0, _Y, _X, _Z),
    (0, 1, -_X, -_Z, _Y),
    (1, 1, -_Z, _X, _Y),
    (2, 1, _X, _Z, _Y),
    (1, 2, -_Y, _X, -_Z),
    (1, 3, _Z, _X, -_Y),
)
_CROSS = {Layout.HCROSS: (4, 3, _HCROSS_TILES), Layout.VCROSS: (3, 4, _VCROSS_TILES)}


def as_layout(layout: Layout | str) -> Layout:
    """The Layout named by a Layout or its string value; InvalidInputError listing the accepted names."""
    try:
        return Layout(layout)
    except ValueError:
        raise InvalidInputError(
            f"unknown environment-map layout {layout!r}; accepted: {', '.join(m.value for m in Layout)}") from None


def detect_layout(h: int, w: int) -> Layout:
    """Layout from the image size (height h, width w), by exact aspect ratio."""
    if w == 2 * h:
        return Layout.LATLONG
    if w == h:
        return Layout.ANGULAR
    if 3 * w == 4 * h and w % 4 == 0:
        return Layout.HCROSS
    if 4 * w == 3 * h and w % 3 == 0:
        return Layout.VCROSS
    raise EnvironmentMapError(
        f"cannot tell the layout of a {w}x{h} (width x height) image; accepted aspects are {_ASPECTS}. "
        "Crop or resize it, or pass the layout explicitly")


def check_layout_size(layout: Layout | str, h: int, w: int) -> Layout:
    """Raise EnvironmentMapError if an h x w image cannot hold the layout; returns the Layout."""
    layout = as_layout(layout)
    if h < 1 or w < 1:
        raise EnvironmentMapError(f"empty environment map ({w}x{h})")
    if layout is Layout.ANGULAR and h != w:
        raise EnvironmentMapError(f"an angular light probe must be square, got {w}x{h} (width x height)")
    if layout in _CROSS:
        cols, rows, _ = _CROSS[layout]
        if w % cols or h % rows or w // cols != h // rows:
            raise EnvironmentMapError(
                f"a {layout.value} map must be {cols}x{rows} square tiles, got {w}x{h} (width x height)")
    return layout


# ----------------------------------------------------------------------------------------------------------------
# Directions <-> image positions


def dir_to_image(d: np.ndarray, layout: Layout | str, h: int, w: int):
    """Continuous pixel coordinates of directions d (..., 3) (need not be unit) in an h x w image.

    Returns (x_px, y_px, valid): float64 (...) with pixel centres at +0.5 (x right, y down), and a bool
    array (False only for zero directions; every direction has a place in every layout).
    """
    xn, yn, valid = _dir_to_normalized(np.asarray(d, np.float64), as_layout(layout))
    return xn * w, yn * h, valid


def image_to_dir(x_px: np.ndarray, y_px: np.ndarray, layout: Layout | str, h: int, w: int):
    """Unit directions float64 (..., 3) of continuous pixel coordinates; the inverse of `dir_to_image`.

    Returns (d, valid); d is NaN where valid is False (outside the image, the probe's disc or the tiles).
    """
    layout = as_layout(layout)
    xn = np.asarray(x_px, np.float64) / w
    yn = np.asarray(y_px, np.float64) / h
    xn, yn = np.broadcast_arrays(xn, yn)
    inside = (xn >= 0) & (xn <= 1) & (yn >= 0) & (yn <= 1)
    if layout is Layout.LATLONG:
        phi = 2.0 * np.pi * (xn - 0.5)
        theta = np.pi * (0.5 - yn)
        ct = np.cos(theta)
        d = np.stack([np.sin(phi) * ct, np.sin(theta), -np.cos(phi) * ct], axis=-1)
        valid = inside
    elif layout is Layout.ANGULAR:
        x, y = 2.0 * xn - 1.0, 1.0 - 2.0 * yn
        rho = np.hypot(x, y)
        angle = np.pi * rho
        # sin(pi rho) / rho, finite at the centre: pi * sinc(rho)
        s = np.pi * np.sinc(rho)
        d = np.stack([s * x, s * y, np.cos(angle)], axis=-1)
        valid = inside & (rho <= 1.0)
    else:
        cols, rows, tiles = _CROSS[layout]
        gx, gy = xn * cols, yn * rows
        d = np.full(xn.shape + (3,), np.nan)
        valid = np.zeros(xn.shape, bool)
        for col, row, f, r, up in tiles:
            # Closed tile squares: a point on an edge shared with an empty cell still belongs to the tile
            # (dir_to_image puts e.g. (1, 1, 0) there); on edges shared by two tiles both give one direction.
            m = inside & ~valid & (gx >= col) & (gx <= col + 1) & (gy >= row) & (gy <= row + 1)
            lx = 2.0 * (gx[m] - col) - 1.0
            ly = 1.0 - 2.0 * (gy[m] - row)
            d[m] = f + lx[:, None] * r + ly[:, None] * up
            valid |= m
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d = np.where(valid[..., None], d, np.nan)
    return d, valid


def _dir_to_normalized(d: np.ndarray, layout: Layout):
    """Normalized image coordinates (xn, yn) in [0, 1] (x right, y down) and validity of directions d."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    norm = np.sqrt(x * x + y * y + z * z)
    valid = norm > 0
    if layout is Layout.LATLONG:
        phi = np.arctan2(x, -z)
        theta = np.arctan2(y, np.hypot(x, z))
        xn = phi / (2.0 * np.pi) + 0.5
        xn = np.where(xn >= 1.0, xn - 1.0, xn)  # phi = pi (+Z) is the left edge, u = 0
        yn = 0.5 - theta / np.pi
    elif layout is Layout.ANGULAR:
        s = np.hypot(x, y)
        rho = np.arctan2(s, z) / np.pi  # acos(Dz) / pi, stable near both poles
        safe = s > 0
        sc = np.where(safe, rho / np.where(safe, s, 1.0), 0.0)
        px = np.where(safe, x * sc, rho)  # -Z itself (s == 0, rho == 1) lands on the rim at (1, 0)
        py = y * sc
        xn, yn = 0.5 * (px + 1.0), 0.5 * (1.0 - py)
    else:
        cols, rows, tiles = _CROSS[layout]
        fwd = np.stack([t[2] for t in tiles])  # (6, 3)
        dots = d @ fwd.T
        tile = np.argmax(dots, axis=-1)
        xn = np.empty(x.shape)
        yn = np.empty(x.shape)
        for i, (col, row, f, r, up) in enumerate(tiles):
            m = tile == i
            if np.any(m):
                dm = d[m]
                df = dm @ f
                df = np.where(df > 0, df, 1.0)
                xn[m] = (col + 0.5 * (dm @ r / df + 1.0)) / cols
                yn[m] = (row + 0.5 * (1.0 - dm @ up / df)) / rows
    return xn, yn, valid


def latlong_row_solid_angles(h: int, w: int) -> np.ndarray:
    """Exact solid angle (steradians) of one texel in each row of an h x w lat-long map: float64 (h,).

    A row spans elevations [theta_bot, theta_top]: (2 pi / w) * (sin(theta_top) - sin(theta_bot)).
    """
    theta = np.pi * (0.5 - np.arange(h + 1) / h)
    return (2.0 * np.pi / w) * (np.sin(theta[:-1]) - np.sin(theta[1:]))


def _source_texel_solid_angle(d: np.ndarray, layout: Layout, h: int, w: int, extent: np.ndarray) -> np.ndarray:
    """Solid angle of the level-0 source texel at unit directions d, for choosing a pyramid level.

    extent is the angular size (radians) of the cube texel looking it up: where the probe squeezes texels
    to nothing (its rim, -Z) the cube texel still spans at least extent/2 from the singular point, and
    the mean squeeze over a cap of radius a about it is 2a/3, so we floor the squeeze at extent/3.
    """
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    if layout is Layout.LATLONG:
        # After _isotropic_latlong every texel acts like an equatorial one, at least as wide as tall.
        return np.full(x.shape, (np.pi / h) * max(np.pi / h, 2.0 * np.pi / w))
    if layout is Layout.ANGULAR:
        # Area element: d(omega) = sin(angle) d(angle) d(alpha) with angle = pi rho, image area = rho d(rho) d(alpha)
        # => d(omega)/d(area) = pi sin(pi rho) / rho; one pixel has image area (2/w)(2/h).
        angle = np.arctan2(np.hypot(x, y), z)
        return (4.0 / (w * h)) * np.pi * np.pi * np.maximum(np.sin(angle), extent / 3.0) / np.maximum(angle, 1e-12)
    cols, rows, _ = _CROSS[layout]
    xn, yn, _ = _dir_to_normalized(d, layout)
    lx = 2.0 * (xn * cols % 1.0) - 1.0
    ly = 2.0 * (yn * rows % 1.0) - 1.0
    # Perspective tile at unit distance: d(omega) = (1 + x^2 + y^2)^(-3/2) dx dy; a pixel is (2/t)^2.
    return (2.0 * cols / w) * (2.0 * rows / h) * (1.0 + lx * lx + ly * ly) ** -1.5


# ----------------------------------------------------------------------------------------------------------------
# Area-correct resampling to a cube


class _Level(NamedTuple):
    values: np.ndarray   # (h, w, C): solid-angle weighted mean radiance of each texel
    weights: np.ndarray  # (h, w) or (h, 1) float32: mean solid-angle density; 0 = no data (outside disc/tiles)


def _isotropic_latlong(values: np.ndarray) -> np.ndarray:
    """Lat-long rows box-filtered so every texel is as wide (in angle) as it is tall: float32 (h, w, C).

    A lat-long texel at latitude theta is cos(theta) times narrower than at the equator, so a pyramid
    level chosen by solid angle is far too coarse in latitude near the poles (11 degrees of blur at 128^2
    faces from a 1k map, and 1.2 % of a bright zenith's energy lost where the level changes fast), and
    one chosen by height aliases in longitude. Instead each row of the level that is read is box-filtered
    circularly over W / (2 H cos(theta)) texels (capped at the whole row), exactly, through its running
    integral; then every texel acts like an equatorial one and one level choice fits every latitude.
    Row sums, hence energy, are unchanged.
    """
    h, w, c = values.shape
    # cos(theta) of each row, as its solid angle relative to an equatorial texel's
    cos_eff = latlong_row_solid_angles(h, w) / ((2.0 * np.pi / w) * (np.pi / h))
    widths = np.clip(w / (2.0 * h * np.maximum(cos_eff, 1e-300)), 1.0, float(w))
    out = np.array(values, np.float32, copy=True)
    j = np.arange(w)
    for r in np.flatnonzero(widths >= 1.001):
        row = values[r].astype(np.float64)
        # Running integral at integer positions -w..2w of the periodic, piecewise constant row.
        cum = np.zeros((3 * w + 1, c))
        np.cumsum(np.concatenate([row, row, row]), axis=0, out=cum[1:])
        half = 0.5 * widths[r]
        ends = []
        for t in (0.5 - half, 0.5 + half):  # box ends relative to each texel's left edge, in [-w/2, w/2 + 1]
            whole = math.floor(t)
            fr = t - whole
            lo = cum[w + whole + j]
            ends.append(lo + fr * (cum[w + whole + j + 1] - lo))
        out[r] = (ends[1] - ends[0]) / widths[r]
    return out


def _level0_weights(layout: Layout, h: int, w: int) -> np.ndarray:
    """Relative solid angle of each source texel (0 where the layout has no data)."""
    if layout is Layout.LATLONG:
        return latlong_row_solid_angles(h, w).astype(np.float32)[:, None]
    yc = (np.arange(h) + 0.5) / h
    xc = (np.arange(w) + 0.5) / w
    if layout is Layout.ANGULAR:
        x = 2.0 * xc[None, :] - 1.0
        y = 1.0 - 2.0 * yc[:, None]
        rho = np.hypot(x, y)
        # A pixel counts if its centre lies in the disc (what image_to_dir calls valid); its density,
        # sin(pi rho) / (pi rho) (up to a constant), is taken at most half a pixel from the rim, where it
        # vanishes, so that rim pixels keep a small positive weight.
        rho_eff = np.minimum(rho, 1.0 - 1.0 / max(w, h))
        return np.where(rho <= 1.0, np.sinc(rho_eff), 0.0).astype(np.float32)
    cols, rows, tiles = _CROSS[layout]
    gx, gy = xc * cols, yc * rows
    lx = 2.0 * (gx % 1.0) - 1.0
    ly = 2.0 * (gy % 1.0) - 1.0
    dens = (1.0 + lx[None, :] ** 2 + ly[:, None] ** 2) ** -1.5
    present = np.zeros((rows, cols), bool)
    for col, row, *_ in tiles:
        present[row, col] = True
    mask = present[np.floor(gy).astype(int)[:, None], np.floor(gx).astype(int)[None, :]]
    return np.where(mask, dens, 0.0).astype(np.float32)


class _Taps(NamedTuple):
    """Box filter from n texels to m = n // 2: output i is sum_t frac[t][i] * input[index[t][i]]."""
    index: list
    frac: list
    halving: bool  # n == 2m: index[t] == 2i + t, frac == 0.5 (slices instead of gathers)


def _box_taps(n: int, m: int) -> _Taps:
    if n == 2 * m:
        return _Taps([], [], True)
    scale = n / m
    a = np.arange(m) * scale
    b = a + scale
    index, frac = [], []
    for t in range(int(math.ceil(scale)) + 1):
        j = np.floor(a).astype(np.int64) + t
        overlap = np.clip(np.minimum(b, j + 1) - np.maximum(a, j), 0.0, None) / scale
        if np.any(overlap > 0):
            index.append(np.minimum(j, n - 1))
            frac.append(overlap.astype(np.float32))
    return _Taps(index, frac, False)


def _take_rows(arr: np.ndarray, taps: _Taps, i0: int, i1: int):
    if taps.halving:
        return [(arr[2 * i0 + t:2 * i1:2], np.float32(0.5)) for t in (0, 1)]
    return [(arr[idx[i0:i1]], fr[i0:i1, None]) for idx, fr in zip(taps.index, taps.frac)]


def _take_cols(arr: np.ndarray, taps: _Taps, m: int):
    if taps.halving:
        return [(arr[:, t:2 * m:2], np.float32(0.5)) for t in (0, 1)]
    return [(arr[:, idx], fr[None, :]) for idx, fr in zip(taps.index, taps.frac)]


def _downsample(level: _Level, chunk_values: int = 1 << 22) -> _Level:
    """Next pyramid level: solid-angle weighted box filter over 2x2 texels (over n/(n//2) texels on odd sides).

    Processes bands of output rows so the temporaries stay small (level 0 may be the caller's 16k map).
    """
    values, weights = level
    h, w, c = values.shape
    h2, w2 = max(1, h // 2), max(1, w // 2)
    row_taps, col_taps = _box_taps(h, h2), _box_taps(w, w2)
    per_row_weights = weights.shape[1] == 1
    out_v = np.empty((h2, w2, c), np.float32)
    out_w = np.empty((h2, 1 if per_row_weights else w2), np.float32)
    band = max(1, chunk_values // max(1, 2 * w * c))
    for i0 in range(0, h2, band):
        i1 = min(h2, i0 + band)
        acc_p = acc_w = None
        for (v, fr), (wt, _) in zip(_take_rows(values, row_taps, i0, i1), _take_rows(weights, row_taps, i0, i1)):
            fw = wt * fr
            p = v * fw[..., None]
            acc_p = p if acc_p is None else acc_p + p
            acc_w = fw if acc_w is None else acc_w + fw
        p2 = None
        for v, fr in _take_cols(acc_p, col_taps, w2):
            p = v * (fr[..., None] if isinstance(fr, np.ndarray) else fr)
            p2 = p if p2 is None else p2 + p
        if per_row_weights:
            w_band = acc_w
        else:
            w_band = sum(v * fr for v, fr in _take_cols(acc_w, col_taps, w2))
        has_data = np.broadcast_to(w_band > 0, p2.shape[:2])
        out_v[i0:i1] = p2 / np.where(w_band > 0, w_band, 1.0)[..., None]
        out_v[i0:i1][~has_data] = 0.0
        out_w[i0:i1] = w_band
    return _Level(out_v, out_w)


def _pyramid_sizes(h: int, w: int) -> list[tuple[int, int]]:
    sizes = [(h, w)]
    while sizes[-1] != (1, 1):
        hh, ww = sizes[-1]
        sizes.append((max(1, hh // 2), max(1, ww // 2)))
    return sizes


def _bilinear(level: _Level, x_px: np.ndarray, y_px: np.ndarray, wrap_x: bool, use_weights: bool) -> np.ndarray:
    """Bilinear lookup at continuous pixel coordinates (centres at +0.5): float32 (..., C).

    Lat-long wraps in x; everything clamps at the edges. With use_weights, taps without data (weight 0)
    are left out and the rest renormalized, so no black from outside the probe's disc or the tiles leaks in.
    """
    values, weights = level
    h, w, c = values.shape
    x = x_px - 0.5
    y = y_px - 0.5
    x0f = np.floor(x)
    y0f = np.floor(y)
    fx = (x - x0f).astype(np.float32)
    fy = (y - y0f).astype(np.float32)
    x0 = x0f.astype(np.int32)
    y0 = y0f.astype(np.int32)
    if wrap_x:
        x0 %= w
        x1 = x0 + 1
        x1[x1 == w] = 0
    else:
        x1 = np.clip(x0 + 1, 0, w - 1)
        np.clip(x0, 0, w - 1, out=x0)
    y1 = np.clip(y0 + 1, 0, h - 1)
    np.clip(y0, 0, h - 1, out=y0)
    # Rows of the flattened image, one np.take per tap (a 2-D fancy index costs several times as much).
    flat = values.reshape(-1, c)
    r0, r1 = y0 * w, y1 * w
    gx, gy = 1 - fx, 1 - fy
    taps = ((r0 + x0, gx * gy), (r0 + x1, fx * gy), (r1 + x0, gx * fy), (r1 + x1, fx * fy))
    out = np.zeros(x.shape + (c,), np.float32)
    if not use_weights:
        for idx, b in taps:
            out += np.take(flat, idx, axis=0) * b[..., None]
        return out
    flat_w = np.broadcast_to(weights, (h, w)).reshape(-1) if weights.shape[1] == w else np.repeat(weights[:, 0], w)
    total = np.zeros(x.shape, np.float32)
    for idx, b in taps:
        b = np.where(np.take(flat_w, idx) > 0, b, np.float32(0))
        out += np.take(flat, idx, axis=0) * b[..., None]
        total += b
    out /= np.where(total > 0, total, np.float32(1))[..., None]  # no data in any tap: 0
    return out


def to_cube(img: np.ndarray, layout: Layout | str, face_size: int, *,
            samples_per_axis: int | None = None) -> np.ndarray:
    """Resample an environment map (H, W, C) to a cube float32 (6, F, F, C) in the cube.py convention.

    Each cube texel is the solid-angle mean of the map over the texel (area-correct: no aliasing when
    shrinking, energy kept). The map's pyramid (2x2 box filter weighted by texel solid angle) is read at
    the level whose texels best match the cube texel's solid angle at its direction, trilinearly: the
    finest level L not larger than that, blended towards L + 1 by the fractional level, since a hard
    switch between levels counts a sun next to the switch partly twice. Each texel averages k x k
    stratified sub-directions (weighted by their exact solid angles) with bilinear lookups; k is
    samples_per_axis or, by default, 4 on faces of 128 and more, up to 32 on smaller faces (see
    _default_samples_per_axis), and 2 where the cube texel is smaller than a source texel. Lat-long
    rows are widened near the poles first (_isotropic_latlong). Non-finite texels are not checked here
    (see io.check_texels).

    Energy (sum of cube * cube_solid_angles vs. the map's integral) is kept to 0.1 % at 128^2 and to
    1.2 % at 4^2..16^2 on the shared HDRI assets; memory is the input plus ~0.6x of it at most.
    """
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] < 1 or not np.issubdtype(img.dtype, np.number):
        raise InvalidInputError(f"expected an environment map of shape (H, W, C) of numbers, got {img.shape} "
                                f"{img.dtype}")
    h, w, n_chan = img.shape
    layout = check_layout_size(layout, h, w)
    if isinstance(face_size, bool) or not isinstance(face_size, (int, np.integer)) or face_size < 1:
        raise InvalidInputError(f"face_size must be a positive integer, got {face_size!r}")
    if samples_per_axis is not None and not 1 <= samples_per_axis <= 32:
        raise InvalidInputError(f"samples_per_axis must be in 1..32, got {samples_per_axis}")
    n = int(face_size)
    k = int(samples_per_axis) if samples_per_axis is not None else _default_samples_per_axis(n)
    frames = _face_frames()
    sizes = _pyramid_sizes(h, w)
    log_area = np.log([(h * w) / (hh * ww) for hh, ww in sizes])  # level L texels: area[L] level-0 texels

    # Per cube texel: the pyramid level to read, the blend weight towards the next one, samples per axis.
    level_of = np.empty((6, n, n), np.int16)
    frac = np.empty((6, n, n), np.float32)
    k_of = np.empty((6, n, n), np.int8)
    omega_cube = texel_solid_angles(n)  # (n, n), the same on every face
    for face in range(6):
        centres = _face_dirs(frames, face, *_texel_centre_uv(n))
        centres /= np.linalg.norm(centres, axis=-1, keepdims=True)
        ratio = omega_cube / _source_texel_solid_angle(centres, layout, h, w, np.sqrt(omega_cube))
        # Sub-samples are s/k apart on a cube texel of size s; a level whose texels are at least 2s/k wide
        # ((k/4)^2 of them in the cube texel, one for k = 4) is sampled densely enough for the bilinear
        # reconstruction to integrate a point source to < 1 % (the sinc^2 aliasing term of a tent). Read
        # the largest L with area[L] <= target, blended towards L + 1 by where target lies between
        # area[L] and area[L + 1] (in log scale): trilinear filtering.
        log_target = np.log(ratio * (4.0 / max(k, 4)) ** 2)
        lev = np.clip(np.searchsorted(log_area, log_target, side="right") - 1, 0, len(sizes) - 1)
        upper = np.append(log_area[1:], np.inf)
        level_of[face] = lev
        frac[face] = np.clip((log_target - log_area[lev]) / (upper[lev] - log_area[lev]), 0.0, 1.0)
        # Where the cube texel is smaller than a source texel the bilinear lookup is the reconstruction
        # already and 2 x 2 samples suffice.
        k_of[face] = np.where((ratio < 1.0) & (samples_per_axis is None), 2, k)

    def for_lookup(level: _Level | None) -> _Level | None:
        if level is None or layout is not Layout.LATLONG:
            return level
        return _Level(_isotropic_latlong(level.values), level.weights)

    wrap_x = layout is Layout.LATLONG
    use_weights = layout is not Layout.LATLONG
    cube = np.empty((6, n, n, n_chan), np.float32)
    # Walk up the pyramid; texels at level L read L and L + 1, so two levels are live at a time.
    raw = _Level(img, _level0_weights(layout, h, w))
    look_coarser = None
    for lev in range(int(level_of.max()) + 1):
        raw_coarser = _downsample(raw) if lev + 1 < len(sizes) else None
        here = level_of == lev
        if not np.any(here):
            look_coarser = None
            raw = raw_coarser
            continue
        look = look_coarser if look_coarser is not None else for_lookup(raw)
        look_coarser = for_lookup(raw_coarser) if np.any(frac[here] > 0) else None
        def fill(face: int, look=look, look_coarser=look_coarser, here=here) -> None:
            for kk in np.unique(k_of[face][here[face]]):
                rows, cols = np.nonzero(here[face] & (k_of[face] == kk))
                _sample_texels(cube[face], look, look_coarser, frac[face, rows, cols], layout, frames[face], n,
                               int(kk), rows, cols, wrap_x, use_weights)

        map_threads(fill, range(6))   # the faces on every core
        raw = raw_coarser
    return cube


def _default_samples_per_axis(n: int) -> int:
    """512 / n clamped to 4..32: 4 on faces of 128 and more; smaller faces take as many samples as 128^2.

    With 4 per axis a small face reads a coarse level (a 16^2 face a 64 x 32 level of a 1k map), where
    the bilinear reconstruction near the poles and the level changes move up to 8 % of a sun's energy;
    more samples allow a proportionally finer level and keep that within 1.2 % on every shared asset.
    """
    return int(np.clip(512 // n, 4, 32))


def _face_frames() -> np.ndarray:
    """(6, 3, 3): centre, d/du and d/dv of each face; `face_uv_to_dir` is linear in (u, v), so this takes
    the convention from cube.py and makes sub-texel directions a cheap multiply-add."""
    f = np.arange(6)
    c = face_uv_to_dir(f, 0.0, 0.0)
    return np.stack([c, face_uv_to_dir(f, 1.0, 0.0) - c, face_uv_to_dir(f, 0.0, 1.0) - c], axis=1)


def _face_dirs(frames: np.ndarray, face, u, v) -> np.ndarray:
    """Unnormalized directions (..., 3) of face coordinates; face None means frames is one face's (3, 3)."""
    fr = frames if face is None else frames[face]
    return fr[..., 0, :] + np.asarray(u)[..., None] * fr[..., 1, :] + np.asarray(v)[..., None] * fr[..., 2, :]


def _texel_centre_uv(n: int):
    c = (np.arange(n) + 0.5) * (2.0 / n) - 1.0
    v, u = np.meshgrid(c, c, indexing="ij")  # v along rows, u along columns, as in cube.py
    return u, v


def _sample_texels(face_out, cur, coarser, frac, layout, frame, n, k, rows, cols, wrap_x, use_weights,
                   max_samples=1 << 18):
    """Fill face_out[rows, cols] (one face, (n, n, C)) with the solid-angle weighted mean of k x k bilinear
    lookups at stratified sub-directions of each texel, in level cur blended with the coarser level by frac."""
    sub = (np.arange(k) + 0.5) / k
    sv, su = np.meshgrid(sub, sub, indexing="ij")
    su, sv = su.ravel(), sv.ravel()
    step = max(1, max_samples // (k * k))
    for s0 in range(0, rows.size, step):
        r, c = rows[s0:s0 + step, None], cols[s0:s0 + step, None]
        u = (c + su) * (2.0 / n) - 1.0  # (texels, k*k)
        v = (r + sv) * (2.0 / n) - 1.0
        xn, yn, _ = _dir_to_normalized(_face_dirs(frame, None, u, v), layout)
        # Each sub-direction stands for its sub-cell's solid angle, (1 + u^2 + v^2)^(-3/2) du dv, not an
        # equal share of the texel: the density varies ~10 % across a texel of a small face, which
        # would move a sun's energy.
        density = (1.0 + u * u + v * v) ** -1.5
        wts = (density / density.sum(axis=1, keepdims=True)).astype(np.float32)[..., None]
        h, w = cur.values.shape[:2]
        value = np.einsum("tsc,tsc->tc", _bilinear(cur, xn * w, yn * h, wrap_x, use_weights), wts)
        a = frac[s0:s0 + step, None]
        if coarser is not None and np.any(a > 0.0):
            h, w = coarser.values.shape[:2]
            blur = np.einsum("tsc,tsc->tc", _bilinear(coarser, xn * w, yn * h, wrap_x, use_weights), wts)
            value = (1.0 - a) * value + a * blur
        face_out[rows[s0:s0 + step], cols[s0:s0 + step]] = value


def cube_to_latlong(cube: np.ndarray, h: int, w: int) -> np.ndarray:
    """Lat-long image float32 (h, w, C) of a cube (6, F, F, C), by seamless bilinear lookups (previews, tests)."""
    cube = np.asarray(cube)
    if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[1] != cube.shape[2]:
        raise InvalidInputError(f"expected a cube of shape (6, F, F, C), got {cube.shape}")
    out = np.empty((h, w, cube.shape[3]), np.float32)
    xs = np.arange(w) + 0.5
    band = max(1, (1 << 18) // max(1, w))
    for r0 in range(0, h, band):
        ys = np.arange(r0, min(h, r0 + band)) + 0.5
        d, _ = image_to_dir(xs[None, :], ys[:, None], Layout.LATLONG, h, w)
        out[r0:r0 + ys.size] = sample_bilinear(cube, d)
    return out
