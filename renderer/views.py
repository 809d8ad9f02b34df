"""Turntables, named views and contact sheets (Renderer.render_views): one frame seen from several
cameras, the shadow maps drawn once for all of them."""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .errors import InvalidInputError

# Directions from the garment to the camera, Y up, the garment facing +Z (as the default camera sees it).
NAMED_VIEWS = {"front": (0.0, 0.2, 1.0), "back": (0.0, 0.2, -1.0), "left": (1.0, 0.2, 0.0), "right": (-1.0, 0.2, 0.0),
               "three-quarter": (-0.8, 0.3, 0.6), "top": (0.0, 1.0, 0.05)}
VIEW_NAMES = tuple(NAMED_VIEWS)
MAX_VIEWS = 64   # cameras in one request: each is a geometry and a lighting pass and an image


def _check_count(n: int, what: str) -> None:
    if not 1 <= n <= MAX_VIEWS:
        raise InvalidInputError(f"{what} has 1 to {MAX_VIEWS} views, got {n}")


def turntable(camera: Camera, n: int) -> list[Camera]:
    """n cameras: `camera` turned about the vertical axis through its target in equal steps, the
    first `camera` itself (the garment turns on a turntable in front of it)."""
    _check_count(n, "a turntable")
    eye, target = np.asarray(camera.eye, np.float64), np.asarray(camera.target, np.float64)
    d = eye - target
    out = []
    for k in range(n):
        a = 2.0 * np.pi * k / n
        c, s = np.cos(a), np.sin(a)
        r = np.array([d[0] * c + d[2] * s, d[1], -d[0] * s + d[2] * c])
        out.append(Camera(tuple(target + r), camera.target, camera.up, camera.fov_y_deg))
    return out


def orbit(camera: Camera, azimuth_deg: float, elevation_deg: float) -> Camera:
    """`camera` moved on the sphere about its target: turned `azimuth_deg` about the vertical axis
    (counter-clockwise seen from above, as a turntable's steps) and raised `elevation_deg` (-89..89 in
    all, its height above the target's level included)."""
    for name, value in (("azimuth", azimuth_deg), ("elevation", elevation_deg)):
        if not np.isfinite(value):
            raise InvalidInputError(f"orbit {name} must be a finite number of degrees, got {value!r}")
    eye, target = np.asarray(camera.eye, np.float64), np.asarray(camera.target, np.float64)
    d = eye - target
    dist = float(np.linalg.norm(d))
    horizontal = float(np.hypot(d[0], d[2]))
    up = float(np.degrees(np.arctan2(d[1], horizontal))) + float(elevation_deg)
    up = float(np.clip(up, -89.0, 89.0))
    a = np.arctan2(d[0], d[2]) + np.radians(float(azimuth_deg))
    e = np.radians(up)
    r = dist * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    return Camera(tuple(target + r), camera.target, camera.up, camera.fov_y_deg)


def named_views(camera: Camera, names: list[str]) -> list[Camera]:
    """Cameras at `camera`'s distance from its target, from each named direction (NAMED_VIEWS)."""
    unknown = [v for v in names if v not in NAMED_VIEWS]
    if unknown:
        raise InvalidInputError(f"unknown view(s) {', '.join(unknown)}; the views are {', '.join(VIEW_NAMES)}")
    _check_count(len(names), "a request")
    target = np.asarray(camera.target, np.float64)
    dist = float(np.linalg.norm(np.asarray(camera.eye, np.float64) - target))
    out = []
    for v in names:
        d = np.asarray(NAMED_VIEWS[v], np.float64)
        out.append(Camera(tuple(target + dist * d / np.linalg.norm(d)), camera.target, camera.up, camera.fov_y_deg))
    return out


def sheet_columns(n_images: int, n_variants: int) -> int:
    """A contact sheet's columns: one per colourway (a row per view), or a turntable alone in rows of
    up to 6."""
    return n_variants if n_variants > 1 else min(n_images, 6)


def contact_sheet(images: list[np.ndarray], columns: int, gap: int = 2) -> np.ndarray:
    """Images of one size (H, W, C) in a grid of `columns`, row by row, `gap` pixels apart (zeros)."""
    if not images:
        raise InvalidInputError("a contact sheet needs at least one image")
    h, w, c = images[0].shape
    if any(im.shape != (h, w, c) for im in images):
        raise InvalidInputError("a contact sheet's images must share one size")
    columns = max(1, min(columns, len(images)))
    rows = -(-len(images) // columns)
    sheet = np.zeros((rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, c), images[0].dtype)
    for k, im in enumerate(images):
        r, q = divmod(k, columns)
        sheet[r * (h + gap):r * (h + gap) + h, q * (w + gap):q * (w + gap) + w] = im
    return sheet


def label_tiles(rgba8: np.ndarray, labels: list[str], tile_hw: tuple[int, int], columns: int,
                gap: int = 2) -> np.ndarray:
    """A contact sheet (H, W, 3 or 4) uint8, as `contact_sheet` laid it out, with each tile's label
    written in its top-left corner, white on a dark box (Pillow's default font)."""
    from PIL import Image, ImageDraw, ImageFont

    im = Image.fromarray(np.ascontiguousarray(rgba8))
    draw = ImageDraw.Draw(im, "RGBA")
    font = ImageFont.load_default()
    h, w = tile_hw
    for k, text in enumerate(labels):
        r, q = divmod(k, columns)
        x, y = q * (w + gap) + 2, r * (h + gap) + 1
        draw.rectangle(draw.textbbox((x, y), text, font=font), fill=(0, 0, 0, 160))
        draw.text((x, y), text, fill=(255, 255, 255, 255), font=font)
    return np.asarray(im)


def view_labels(n_views: int, names: list[str] | None, colourways: list[str]) -> list[str]:
    """Each image's label, view by view, each view's colourways in turn: the view's name (or its
    turntable angle) and the colourway's, where there are several."""
    views = names if names is not None else [f"{round(360 * k / n_views)} deg" for k in range(n_views)]
    return [v if len(colourways) == 1 else f"{v} / {c}" for v in views for c in colourways]
