"""Cube-map conventions, texel directions and exact texel solid angles (numpy only).

The one place where the cube convention is pinned. It is OpenGL's (GL 4.5 spec, table 8.19), so a
numpy array of shape (6, N, N, C) uploads to a GL cube map with no flips:

    face index : 0=+X  1=-X  2=+Y  3=-Y  4=+Z  5=-Z
    array index: cube[face, row, col]; col runs along the texture coordinate s, row along t,
                 both from 0 at the first texel in memory. u = 2s - 1, v = 2t - 1 in [-1, 1].

    face   direction of (u, v)          face seen from the centre of the cube
    +X     ( 1, -v, -u)                         +----+
    -X     (-1, -v,  u)                         | +Y |
    +Y     ( u,  1,  v)                    +----+----+----+----+
    -Y     ( u, -1, -v)                    | -X | +Z | +X | -Z |   (GL's layout: t grows downwards)
    +Z     ( u, -v,  1)                    +----+----+----+----+
    -Z     (-u, -v, -1)                         | -Y |
                                                +----+

World space is right-handed and Y-up. Directions are unit vectors pointing *away* from the scene
(the direction light arrives from).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

FACE_NAMES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")


def face_uv_to_dir(face: np.ndarray | int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unnormalized direction of face coordinates (u, v) in [-1, 1] (values outside extend the face plane).

    Returns float64 array of shape broadcast(face, u, v) + (3,).
    """
    face, u, v = np.broadcast_arrays(np.asarray(face), np.asarray(u, np.float64), np.asarray(v, np.float64))
    one = np.ones_like(u)
    out = np.empty(u.shape + (3,), np.float64)
    table = (
        (one, -v, -u),
        (-one, -v, u),
        (u, one, v),
        (u, -one, -v),
        (u, -v, one),
        (-u, -v, -one),
    )
    for f, (x, y, z) in enumerate(table):
        m = face == f
        if np.any(m):
            out[m, 0], out[m, 1], out[m, 2] = x[m], y[m], z[m]
    return out


def dir_to_face_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face index and (u, v) in [-1, 1] of directions d (..., 3); the inverse of `face_uv_to_dir`.

    Ties between major axes go to X, then Y, then Z, as in the GL selection rule for |x| >= |y|, |z|.
    """
    d = np.asarray(d, np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
    use_x = (ax >= ay) & (ax >= az)
    use_y = ~use_x & (ay >= az)
    face = np.where(use_x, np.where(x >= 0, 0, 1), np.where(use_y, np.where(y >= 0, 2, 3), np.where(z >= 0, 4, 5)))
    ma = np.where(use_x, ax, np.where(use_y, ay, az))
    ma = np.where(ma > 0, ma, 1.0)
    # sc, tc per face (GL spec table 8.19)
    sc = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-z, z, x, x, x], -x)
    tc = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-y, -y, z, -z, -y], -y)
    return face.astype(np.int64), sc / ma, tc / ma


def texel_centers_uv(n: int) -> np.ndarray:
    """Face coordinate (u or v) of the centres of n texels along one axis, in [-1, 1]."""
    return (np.arange(n, dtype=np.float64) + 0.5) * (2.0 / n) - 1.0


def texel_directions(n: int) -> np.ndarray:
    """Unit directions of all texel centres of a cube of face size n: float64 (6, n, n, 3), read-only
    (made once per size: every PEM build's median cut reads them)."""
    return _texel_directions(int(n))


@lru_cache(maxsize=3)   # 151 MB at 1024^2 faces: the few sizes a process uses
def _texel_directions(n: int) -> np.ndarray:
    c = texel_centers_uv(n)
    v, u = np.meshgrid(c, c, indexing="ij")  # v along rows (t), u along columns (s)
    d = face_uv_to_dir(np.arange(6)[:, None, None], u[None], v[None])
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d.setflags(write=False)
    return d


def _area_element(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # Solid angle of the face rectangle [0, x] x [0, y] at distance 1:
    # A(x, y) = atan(x*y / sqrt(x^2 + y^2 + 1))  (integral of (1 + u^2 + v^2)^(-3/2) du dv).
    return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))


def texel_solid_angles(n: int) -> np.ndarray:
    """Exact solid angle (steradians) of every texel of a face of size n: float64 (n, n), same for all faces.

    Integrates the projected-area element exactly over each texel's square, so the sum over the
    six faces is 4*pi to rounding error.
    """
    e = np.linspace(-1.0, 1.0, n + 1)
    y0, x0 = np.meshgrid(e[:-1], e[:-1], indexing="ij")
    y1, x1 = np.meshgrid(e[1:], e[1:], indexing="ij")
    return _area_element(x1, y1) - _area_element(x0, y1) - _area_element(x1, y0) + _area_element(x0, y0)


def cube_solid_angles(n: int) -> np.ndarray:
    """Texel solid angles (steradians) of all six faces: float64 (6, n, n)."""
    return np.broadcast_to(texel_solid_angles(n), (6, n, n))


def dir_to_texel(d: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face, row and column of the texel of a face-size-n cube that contains each direction."""
    face, u, v = dir_to_face_uv(d)
    col = np.clip(np.floor((u + 1.0) * 0.5 * n), 0, n - 1).astype(np.int64)
    row = np.clip(np.floor((v + 1.0) * 0.5 * n), 0, n - 1).astype(np.int64)
    return face, row, col


def neighbour_texel(face: np.ndarray, row: np.ndarray, col: np.ndarray, n: int):
    """Resolve texel indices that may lie outside their face (row or col in [-n, 2n)) to the texel
    of the cube they fall on, by going through the direction of the (extended) texel centre.

    This is how filters cross face edges without seams: the k-th texel beyond an edge is the k-th
    texel into the neighbouring face. Taps outside in both axes (beyond a corner, where only three
    faces meet) land on whichever face their direction points into. Returns (face, row, col) arrays of int64, all inside [0, n).
    """
    face, row, col = np.broadcast_arrays(np.asarray(face), np.asarray(row), np.asarray(col))
    inside = (row >= 0) & (row < n) & (col >= 0) & (col < n)
    if np.all(inside):
        return face.astype(np.int64), row.astype(np.int64), col.astype(np.int64)
    u = (col + 0.5) * (2.0 / n) - 1.0
    v = (row + 0.5) * (2.0 / n) - 1.0
    d = face_uv_to_dir(face, u, v)
    f2, r2, c2 = dir_to_texel(d, n)
    return (np.where(inside, face, f2).astype(np.int64), np.where(inside, row, r2).astype(np.int64),
            np.where(inside, col, c2).astype(np.int64))


def sample_bilinear(cube: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Seamless bilinear lookup of cube (6, n, n, C) along directions d (..., 3), as GL does with
    seamless cube filtering: the 2x2 footprint crosses face edges. Returns (..., C) float64.
    """
    n = cube.shape[1]
    face, u, v = dir_to_face_uv(d)
    x = (u + 1.0) * 0.5 * n - 0.5
    y = (v + 1.0) * 0.5 * n - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    out = 0.0
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            f, r, c = neighbour_texel(face, y0 + dy, x0 + dx, n)
            out = out + wy * wx * cube[f, r, c]
    return out
