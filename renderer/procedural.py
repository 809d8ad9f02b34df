"""Procedural scenes that need no asset: a draped skirt, a body it hangs on, spheres and a floor.

All deterministic (no randomness), Y-up, metres, counter-clockwise faces with outward normals
(the conventions of `renderer.mesh`). Surfaces of revolution are built as a grid of rings around
the Y axis: ring i is at height y_i, column j at angle theta_j, with x = r cos(theta),
z = r sin(theta). With rings ordered top to bottom and theta increasing, the quad (i, j) splits
into (a, b, c) = (P[i,j], P[i,j+1], P[i+1,j]) and (b, d, c) with d = P[i+1,j+1]: cross(b - a, c - a)
= cross(d_theta, d_down) points away from the axis.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InvalidInputError
from .mesh import Mesh, concatenate

# Body proxy dimensions (metres): a standing figure about 1.75 m tall, feet at y = 0, facing +Z.
_TORSO = ((0.0, 1.25, 0.0), (0.16, 0.28, 0.11))  # ellipsoid centre, radii
_HIPS = ((0.0, 0.92, 0.0), (0.17, 0.12, 0.12))
_HEAD = ((0.0, 1.64, 0.0), (0.09, 0.11, 0.10))
_NECK = ((0.0, 1.46, 0.0), (0.0, 1.56, 0.0), 0.05)  # capsule end points, radius
_LEGS = (((-0.09, 0.065, 0.0), (-0.09, 0.86, 0.0), 0.065), ((0.09, 0.065, 0.0), (0.09, 0.86, 0.0), 0.065))

# Skirt dimensions (metres). The waistband (radius 0.15 at y = 1.08) clears the torso (x radius
# 0.127 at that height), and the flare clears the hips: r(0.92 m) = 0.21 > 0.17.
_WAIST_Y = 1.08
_LENGTH = 1.0
_WAIST_R = 0.15
_HEM_R = 0.45
_N_FOLDS = 9
_FOLD_AMPLITUDE = 0.04  # at the hem; grows as t**1.5 from 0 at the waistband
_SWING = 0.05  # sideways (+X) drift of the hem, grows as t**2: the asymmetric drape
_HEM_DIP = 0.04  # the hem hangs this much lower on the side the skirt swings to


def _check_int(value: int, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise InvalidInputError(f"{name} must be an integer in {lo}..{hi}; got {value!r}")
    return int(value)


def _check_positive(value: float, name: str) -> float:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value > 0):
        raise InvalidInputError(f"{name} must be a finite number > 0; got {value!r}")
    return float(value)


def _grid_faces(n_rows: int, n_cols: int, wrap: bool) -> np.ndarray:
    """Two triangles per quad of a row-major (n_rows, n_cols) vertex grid; `wrap` joins the last
    column to the first. Winding as in the module docstring. Returns int64 (2 * quads, 3)."""
    cols = n_cols if wrap else n_cols - 1
    i, j = np.meshgrid(np.arange(n_rows - 1), np.arange(cols), indexing="ij")
    j1 = (j + 1) % n_cols
    a, b = i * n_cols + j, i * n_cols + j1
    c, d = (i + 1) * n_cols + j, (i + 1) * n_cols + j1
    tri = np.stack([np.stack([a, b, c], -1), np.stack([b, d, c], -1)], axis=2)  # (rows, cols, 2, 3)
    return tri.reshape(-1, 3)


def _closed_revolution(ring_r: np.ndarray, ring_y: np.ndarray, top_y: float, bottom_y: float, n_lon: int):
    """A closed surface of revolution: rings (radius, height) from top to bottom plus two poles.
    Longitudes wrap without a duplicated seam, so the result is watertight. Returns (V, 3), (F, 3)."""
    n_rings = len(ring_r)
    theta = 2.0 * np.pi * np.arange(n_lon) / n_lon
    rings = np.stack(
        [np.outer(ring_r, np.cos(theta)), np.repeat(ring_y[:, None], n_lon, 1), np.outer(ring_r, np.sin(theta))],
        axis=-1,
    ).reshape(-1, 3)
    top, bottom = n_rings * n_lon, n_rings * n_lon + 1
    positions = np.concatenate([rings, [[0.0, top_y, 0.0], [0.0, bottom_y, 0.0]]])
    j = np.arange(n_lon)
    j1 = (j + 1) % n_lon
    last = (n_rings - 1) * n_lon
    # Pole fans are the grid rule with the pole as a ring whose vertices all coincide.
    top_fan = np.stack([np.full(n_lon, top), j1, j], -1)
    bottom_fan = np.stack([last + j, last + j1, np.full(n_lon, bottom)], -1)
    faces = np.concatenate([top_fan, _grid_faces(n_rings, n_lon, wrap=True), bottom_fan])
    return positions, faces


def _ellipsoid(centre, radii, n_lat: int, n_lon: int):
    phi = np.pi * np.arange(1, n_lat) / n_lat  # polar angle of the rings, poles excluded
    p, f = _closed_revolution(np.sin(phi), np.cos(phi), 1.0, -1.0, n_lon)
    return p * np.asarray(radii, np.float64) + np.asarray(centre, np.float64), f


def _capsule(p0, p1, radius: float, n_lat: int, n_lon: int):
    """A capsule around the segment p0 -> p1, which must be parallel to Y (enough for a body proxy)."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    if not np.allclose((p1 - p0)[[0, 2]], 0.0):
        raise InvalidInputError("capsule axis must be parallel to Y")
    half = 0.5 * abs(p1[1] - p0[1])
    phi = 0.5 * np.pi * np.arange(1, n_lat // 2 + 1) / (n_lat // 2)  # (0, pi/2]: pole to equator
    # Upper hemisphere rings down to its equator, then the lower one from its equator: the
    # straight part of the capsule is the band between the two equators.
    ring_r = radius * np.concatenate([np.sin(phi), np.sin(phi[::-1])])
    ring_y = np.concatenate([half + radius * np.cos(phi), -half - radius * np.cos(phi[::-1])])
    p, f = _closed_revolution(ring_r, ring_y, half + radius, -half - radius, n_lon)
    return p + 0.5 * (p0 + p1), f


def _union(parts, name: str, uvs=None) -> Mesh:
    return Mesh.from_arrays(*concatenate(parts), uvs, name=name)


def uv_sphere(radius: float = 1.0, n_lat: int = 32, n_lon: int = 64, centre=(0.0, 0.0, 0.0)) -> Mesh:
    """A watertight latitude-longitude sphere (no UVs: the seam would need split vertices).

    n_lat: bands from pole to pole (>= 2); n_lon: segments around Y (>= 3). centre: (3,) metres.
    """
    radius = _check_positive(radius, "radius")
    n_lat = _check_int(n_lat, "n_lat", 2, 4096)
    n_lon = _check_int(n_lon, "n_lon", 3, 8192)
    p, f = _ellipsoid(centre, (radius,) * 3, n_lat, n_lon)
    return Mesh.from_arrays(p, f, name="sphere")


def ground_plane(size: float = 4.0, y: float = 0.0, subdivisions: int = 1) -> Mesh:
    """A square floor of side `size` metres in the XZ plane at height y, centred on the Y axis, facing +Y.

    UVs run 0..1 along +X (u) and -Z (v). `subdivisions` quads per side (more helps per-vertex effects).
    """
    size = _check_positive(size, "size")
    if not (isinstance(y, (int, float, np.floating, np.integer)) and np.isfinite(y)):
        raise InvalidInputError(f"y must be a finite number; got {y!r}")
    n = _check_int(subdivisions, "subdivisions", 1, 4096) + 1
    s = np.linspace(0.0, 1.0, n)
    # Grid winding gives normal cross(column step, row step); columns step along +X, so rows must
    # step along -Z for cross(+X, -Z) = +Y.
    v, u = np.meshgrid(s, s, indexing="ij")
    x = (u - 0.5) * size
    z = (0.5 - v) * size
    positions = np.stack([x, np.full_like(x, float(y)), z], -1).reshape(-1, 3)
    uvs = np.stack([u, v], -1).reshape(-1, 2)
    return Mesh.from_arrays(positions, _grid_faces(n, n, wrap=False), uvs, name="ground")


def procedural_garment(resolution: int = 64) -> Mesh:
    """A draped skirt: an open, flared tube from a waistband at y = 1.08 m to a hem about 1 m below.

    Sinusoidal folds grow from nothing at the waistband to 4 cm at the hem, twisting slightly; the hem
    swings towards +X and dips on that side (the asymmetric drape). The waistband is centred on the Y
    axis. resolution: segments around (>= 8); rows are resolution // 2. UVs: u around (0..1, seam at
    -X, where the seam vertices are duplicated), v from 1 at the waistband to 0 at the hem.
    """
    n_around = _check_int(resolution, "resolution", 8, 4096)
    n_rows = max(4, n_around // 2)
    t = np.linspace(0.0, 1.0, n_rows + 1)[:, None]  # 0 at the waistband, 1 at the hem
    u = np.linspace(0.0, 1.0, n_around + 1)[None, :]
    theta = np.pi * (2.0 * u - 1.0)  # seam at theta = +-pi (the -X side)

    # Bell-shaped flare: quick over the hips, then nearly conical. Smooth at the waistband.
    flare = 0.6 * np.sin(0.5 * np.pi * t) + 0.4 * t
    r = _WAIST_R + (_HEM_R - _WAIST_R) * flare
    r = r + _FOLD_AMPLITUDE * t**1.5 * np.sin(_N_FOLDS * theta + 0.6 * t)
    x = r * np.cos(theta) + _SWING * t**2
    z = r * np.sin(theta)
    y = _WAIST_Y - _LENGTH * t - _HEM_DIP * t**2 * 0.5 * (1.0 + np.cos(theta))
    grid = np.stack(np.broadcast_arrays(x, y, z), -1)  # (rows, columns, 3)
    grid[:, -1] = grid[:, 0]  # theta = +pi and -pi: make the seam's two columns coincide exactly
    positions = grid.reshape(-1, 3)
    uvs = np.stack(np.broadcast_arrays(u, 1.0 - t), -1).reshape(-1, 2)
    faces = _grid_faces(n_rows + 1, n_around + 1, wrap=False)
    return Mesh.from_arrays(positions, faces, uvs, name="procedural_garment")


def procedural_body(n_lat: int = 24, n_lon: int = 32) -> Mesh:
    """A standing body proxy, 1.75 m tall, feet at y = 0: overlapping closed ellipsoids and capsules
    (torso, hips, neck, head, legs). Each part is watertight; the union is not merged into one surface."""
    n_lat = _check_int(n_lat, "n_lat", 4, 1024)
    n_lon = _check_int(n_lon, "n_lon", 3, 2048)
    parts = [_ellipsoid(c, r, n_lat, n_lon) for c, r in (_TORSO, _HIPS, _HEAD)]
    parts += [_capsule(a, b, r, n_lat, n_lon) for a, b, r in (_NECK, *_LEGS)]
    return _union(parts, "procedural_body")


# The bundled default scene: a dress sewn from two panels and draped on a mannequin by the project's
# cloth simulation, the mannequin's smooth render mesh and a floor (`python -m simulation.dress --store`).
DEFAULT_SCENE_FILE = Path(__file__).parent / "data" / "default_scene.npz"


def floor_under(meshes: list[Mesh], margin: float = 2.0) -> Mesh:
    """A ground plane under `meshes` (Y up): at their lowest point, centred under their box and
    `margin` times its largest side wide (at least 1 m), for a shadow catcher where no floor is given."""
    from .mesh import bounds

    lo, hi = bounds(meshes)
    side = max(float(np.max(hi - lo)) * margin, 1.0)
    floor = ground_plane(side, float(lo[1]))
    centre = np.array([(lo[0] + hi[0]) / 2, 0.0, (lo[2] + hi[2]) / 2])
    return Mesh.from_arrays(floor.positions + centre, floor.faces, floor.uvs, name="shadow floor")


def default_scene() -> tuple[list[Mesh], list[bool]]:
    """The meshes of the bundled default scene (garment, body, floor; metres, Y-up, the floor at
    y = 0, the figure facing +Z) and which cast shadows: the floor only receives them, so that the
    shadow maps are fitted to the dress and the body."""
    with np.load(DEFAULT_SCENE_FILE) as z:
        meshes = [Mesh.from_arrays(z["garment_positions"], z["garment_faces"], z["garment_uvs"], name="dress"),
                  Mesh.from_arrays(z["body_positions"], z["body_faces"], name="mannequin"),
                  Mesh.from_arrays(z["floor_positions"], z["floor_faces"], name="floor")]
    return meshes, [True, True, False]
