"""Analytic environment maps for tests, demos and a default look: a photo studio and a clear sky.

Both are lat-long float32 (width/2, width, 3) in linear radiance, deterministic (no randomness), in the
conventions of `layouts` (image centre -Z, top +Y). "Front" is +Z: the side of a camera on the +Z axis
looking down -Z at a garment facing it; the camera's left is -X.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.envmap.layouts import Layout, image_to_dir, latlong_row_solid_angles
from renderer.errors import InvalidInputError

_WARM_GREY = np.array([0.60, 0.55, 0.50])


def studio_environment(width: int = 512) -> np.ndarray:
    """A photo studio: dim warm-grey walls brightening upwards, a darker floor, a slightly blue overhead,
    a lit seamless backdrop (radiance ~2, light grey behind a subject seen from the front), and three
    softboxes: key (radiance ~50) upper front-left, fill (~10) low front-right, rim (~25) high behind
    the subject. float32 (width/2, width, 3)."""
    h, w = _check_width(width)
    d = _pixel_dirs(h, w)
    y = d[..., 1:2]
    walls = _WARM_GREY * (0.25 + 0.20 * np.clip(y, 0.0, 1.0))
    floor = _WARM_GREY * (0.05 + 0.07 * np.clip(1.0 + y, 0.0, 1.0))  # darkest straight down
    overhead = np.array([0.30, 0.34, 0.42])
    up = _smoothstep(0.6, 0.9, y)
    img = np.where(y >= 0.0, (1.0 - up) * walls + up * overhead, floor)
    # The backdrop: a paper roll behind the subject (-Z) curving into the floor, lit evenly, its edges
    # soft (the light falls off over ~15 degrees). What a camera in front sees behind the garment.
    azimuth = np.degrees(np.arctan2(d[..., 0:1], -d[..., 2:3]))           # 0 behind the subject
    elevation = np.degrees(np.arcsin(np.clip(y, -1.0, 1.0)))
    backdrop = _smoothstep(70.0, 55.0, np.abs(azimuth)) * _smoothstep(-40.0, -25.0, elevation) \
        * _smoothstep(60.0, 45.0, elevation)
    img = (1.0 - backdrop) * img + backdrop * (2.0 * _WARM_GREY / _WARM_GREY.mean())

    # (azimuth phi, elevation, width, height in degrees, radiance RGB); phi as in `layouts`:
    # phi = 0 is -Z (behind the subject), +-180 is +Z (front), -90 is -X (camera left).
    softboxes = (
        (-135.0, 35.0, 30.0, 40.0, 50.0 * np.array([1.00, 0.97, 0.92])),  # key, upper front-left
        (120.0, 10.0, 40.0, 30.0, 10.0 * np.array([0.95, 0.97, 1.00])),   # fill, low front-right
        (20.0, 40.0, 12.0, 45.0, 25.0 * np.array([1.00, 1.00, 1.00])),    # rim strip, behind and above
    )
    pixel_angle = math.pi / h
    for phi, elev, width_deg, height_deg, radiance in softboxes:
        cover = _rectangle_coverage(d, _direction(phi, elev), math.radians(width_deg), math.radians(height_deg),
                                    pixel_angle)[..., None]
        img = (1.0 - cover) * img + cover * radiance
    return img.astype(np.float32)


def sky_environment(width: int = 512) -> np.ndarray:
    """A clear sky: blue gradient (deeper at the zenith), dark ground, and a sun disc 0.5 degrees across at
    40 degrees elevation with radiance ~5e4, which holds most (about 60 %) of the energy. float32 (width/2, width, 3).

    The sun is smaller than a texel at usual widths: it is drawn by pixel coverage and scaled so that its
    energy is exactly L_sun * solid_angle(disc), so texel values there are below L_sun.
    """
    h, w = _check_width(width)
    d = _pixel_dirs(h, w)
    y = d[..., 1:2]
    zenith = np.array([0.06, 0.13, 0.32])
    horizon = np.array([0.30, 0.35, 0.42])
    t = np.clip(y, 0.0, 1.0) ** 0.5
    sky = (1.0 - t) * horizon + t * zenith
    ground = np.array([0.09, 0.08, 0.07]) * (0.5 + 0.5 * np.clip(1.0 + y, 0.0, 1.0))
    img = np.where(y >= 0.0, sky, ground)

    sun_dir = _direction(-135.0, 40.0)  # front-left, lighting the front of a garment
    sun_radius = math.radians(0.25)
    sun_radiance = 5.0e4 * np.array([1.00, 0.93, 0.82])
    img += _disc_texels(sun_dir, sun_radius, h, w)[..., None] * sun_radiance
    return img.astype(np.float32)


def _check_width(width: int) -> tuple[int, int]:
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 4 or width % 2:
        raise InvalidInputError(f"width must be an even integer >= 4, got {width!r}")
    return int(width) // 2, int(width)


def _pixel_dirs(h: int, w: int) -> np.ndarray:
    d, _ = image_to_dir((np.arange(w) + 0.5)[None, :], (np.arange(h) + 0.5)[:, None], Layout.LATLONG, h, w)
    return d


def _direction(phi_deg: float, elev_deg: float) -> np.ndarray:
    # The lat-long formula of `layouts`: (sin(phi) cos(theta), sin(theta), -cos(phi) cos(theta)).
    phi, theta = math.radians(phi_deg), math.radians(elev_deg)
    return np.array([math.sin(phi) * math.cos(theta), math.sin(theta), -math.cos(phi) * math.cos(theta)])


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _rectangle_coverage(d, centre, width, height, pixel_angle):
    """Coverage in [0, 1] of a planar rectangle facing the origin (angular size width x height, its long
    sides vertical), with edges antialiased over one pixel."""
    right = np.cross(centre, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, centre)
    tx, ty = math.tan(width / 2), math.tan(height / 2)
    t = d @ centre
    ts = np.where(t > 0.1, t, 1.0)
    x = np.abs(d @ right) / ts
    y = np.abs(d @ up) / ts
    # Distances to the edges in the tangent plane, over the pixel's size there (d tan / d angle = 1/t^2);
    # only near the rectangle, where that linearization holds.
    near = (t > 0.1) & (x < 2.0 * tx) & (y < 2.0 * ty)
    px = pixel_angle / (ts * ts)
    cx = np.clip((tx - x) / px + 0.5, 0.0, 1.0)
    cy = np.clip((ty - y) / px + 0.5, 0.0, 1.0)
    return np.where(near, cx * cy, 0.0)


def _disc_texels(centre: np.ndarray, radius: float, h: int, w: int, sub: int = 16) -> np.ndarray:
    """(h, w) weights such that sum(weight * texel solid angle) = solid angle of the disc, 2 pi (1 - cos r),
    spread over the texels by their coverage (sub x sub samples each)."""
    disc_sr = 2.0 * math.pi * (1.0 - math.cos(radius))
    out = np.zeros((h, w))
    x_c = (math.atan2(centre[0], -centre[2]) / (2 * math.pi) + 0.5) * w
    y_c = (0.5 - math.asin(centre[1]) / math.pi) * h
    row_sr = latlong_row_solid_angles(h, w)
    # Texels within the disc's reach (in longitude the reach grows by 1 / cos(latitude)).
    reach_y = radius / (math.pi / h) + 2
    reach_x = radius / (2 * math.pi / w) / max(math.cos(math.asin(centre[1])), 1e-3) + 2
    rows = np.arange(max(0, int(y_c - reach_y)), min(h, int(y_c + reach_y) + 1))
    cols = np.arange(int(x_c - reach_x), int(x_c + reach_x) + 1)
    s = (np.arange(sub) + 0.5) / sub
    ys = (rows[:, None, None, None] + s[None, None, :, None]) + 0.0 * s[None, None, None, :]
    xs = (cols[None, :, None, None] + s[None, None, None, :]) + 0.0 * s[None, None, :, None]
    d, _ = image_to_dir(np.mod(xs, w), ys, Layout.LATLONG, h, w)
    cover = (d @ centre >= math.cos(radius)).mean(axis=(2, 3))  # (rows, cols)
    energy = (cover * row_sr[rows, None]).sum()
    if energy > 0:
        np.add.at(out, (rows[:, None], np.mod(cols, w)[None, :]), cover * disc_sr / energy)
    else:  # the disc fell between the samples: put it all in the texel holding its centre
        r, c = min(h - 1, int(y_c)), int(x_c) % w
        out[r, c] = disc_sr / row_sr[r]
    return out
