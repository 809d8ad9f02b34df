"""The cloth: a square sheet on a regular grid, optionally with a round hole in the middle, and its
springs: structural (grid neighbours), shear (both diagonals of each quad) and bend (every second
vertex along rows and columns), as in Provot's mass-spring cloth (Graphics Interface 1995).

Metres, Y-up; the sheet starts flat and horizontal at height `height`, centred over the Y axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Springs:
    """Pairs of vertices (E, 2) int32 and their rest lengths (E,) float64 (metres)."""

    pairs: np.ndarray
    rest_m: np.ndarray


@dataclass(frozen=True)
class ClothMesh:
    """positions (V, 3) float64 start state; faces (F, 3) int32 counter-clockwise seen from the
    cloth's outer side (+Y for a sheet, away from the body for a garment); uvs (V, 2) in [0, 1];
    structural, shear and bend springs; seams: pairs of vertices that sewing joins (rest length 0),
    None for a single piece of cloth; tethers: (vertex, anchor) pairs whose distance may not exceed
    the rest length (the geodesic distance on the pattern), None for none."""

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    structural: Springs
    shear: Springs
    bend: Springs
    seams: Springs | None = None
    tethers: Springs | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.positions)


def sheet(resolution: int = 56, size_m: float = 1.4, hole_radius_m: float = 0.0, height_m: float = 1.95,
           centre_xz: tuple[float, float] = (0.0, 0.0)) -> ClothMesh:
    """A square sheet `size_m` wide with `resolution` x `resolution` vertices, less those inside a
    centred hole of `hole_radius_m` (0: no hole), flat at `height_m`. Dropped on the mannequin it
    drapes over the head and shoulders like a cape. (A neck hole that the head passes through makes
    a poncho, but the ring around it then carries the whole cloth's weight, more than this solver's
    few iterations hold without stretching it over the shoulders.)

    Faces alternate their diagonal in a checkerboard, so the sheet has no preferred shear direction.
    """
    n = int(resolution)
    if n < 4:
        raise ValueError(f"resolution must be >= 4; got {resolution}")
    if not (size_m > 0 and hole_radius_m >= 0 and 2 * hole_radius_m < size_m):
        raise ValueError("size_m must be > 0 and the hole must fit in the sheet")
    s = np.linspace(0.0, 1.0, n)
    row, col = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    # Rows run along +Z, columns along +X; the +Y facing winding of a quad (a, b, c, d) with
    # a = (r, c), b = (r, c+1), c = (r+1, c), d = (r+1, c+1) is (a, c, b), as cross(+Z, +X) = +Y.
    x = (s[col] - 0.5) * size_m + centre_xz[0]
    z = (s[row] - 0.5) * size_m + centre_xz[1]
    grid = np.stack([x, np.full_like(x, height_m), z], -1).reshape(-1, 3)
    uv = np.stack([s[col], 1.0 - s[row]], -1).reshape(-1, 2)
    keep = np.hypot(x - centre_xz[0], z - centre_xz[1]).reshape(-1) >= hole_radius_m if hole_radius_m > 0 \
        else np.ones(n * n, bool)

    idx = (row * n + col)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    even = ((row[:-1, :-1] + col[:-1, :-1]) % 2 == 0)
    # Even quads split along a-d, odd quads along b-c.
    t1 = np.where(even[..., None], np.stack([a, c, d], -1), np.stack([a, c, b], -1))
    t2 = np.where(even[..., None], np.stack([a, d, b], -1), np.stack([b, c, d], -1))
    faces = np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])

    def pairs(p, q):
        return np.stack([p.reshape(-1), q.reshape(-1)], -1)

    structural = np.concatenate([pairs(idx[:, :-1], idx[:, 1:]), pairs(idx[:-1, :], idx[1:, :])])
    shear = np.concatenate([pairs(a, d), pairs(b, c)])
    bend = np.concatenate([pairs(idx[:, :-2], idx[:, 2:]), pairs(idx[:-2, :], idx[2:, :])])

    # Drop what touches the hole and renumber the kept vertices.
    new_index = np.full(n * n, -1, np.int64)
    new_index[keep] = np.arange(int(keep.sum()))
    positions = grid[keep]

    def kept(e: np.ndarray) -> np.ndarray:
        e = e[np.all(keep[e], axis=1)]
        return new_index[e].astype(np.int32)

    def springs(e: np.ndarray) -> Springs:
        e = kept(e)
        return Springs(e, np.linalg.norm(positions[e[:, 0]] - positions[e[:, 1]], axis=1))

    return ClothMesh(positions=positions, faces=kept(faces), uvs=uv[keep], structural=springs(structural),
                     shear=springs(shear), bend=springs(bend))
