"""Slow, exact numpy version of the PEM MIP-chain build; the GPU build is tested against it and the
glossiness calibration runs on it (it needs no GL context).

Level 0 is the (partial) map itself: the mirror lobe. Level L+1 = F5x5(M2x2(level L)), where M2x2
is the classic 2x2 mean of MIP mapping and F5x5 the separable normalized filter of `filters.py`,
evaluated as the full 25-tap outer product so that taps beyond a face edge read the neighbouring
face (cube.neighbour_texel): no seams, and the result does not depend on the pass order.

Solid-angle weighting. A cube texel at a face corner covers about a fifth of the solid angle of one at
the face centre, but M2x2 and F5x5 weight texels equally. Filtering radiance directly therefore does not
conserve energy: at the diffuse level of a 128^2 chain a small sun at a face centre keeps 44 % of its
energy and one near a corner gains about twice its energy (measured: the studio scene's key light sits
near a cube corner and the image came out 1.27x too bright). So the chain filters the texels' energy
weights instead: A = chain(L * w) and B = chain(w), w the texel solid angle relative to the face
centre's, and a lookup returns A / B. B does not depend on the map (one small chain per face size and
filter, shared by all regions), the result is still linear in L (so the PEMs of all regions still sum
to the filtered full map) and a constant map stays exactly constant (the furnace test).
"""

from __future__ import annotations

import functools

import numpy as np

from ..envmap.cube import neighbour_texel, texel_solid_angles
from .filters import Filter, taps_1d


def mip_levels(face_size: int) -> int:
    """Number of levels of a full chain down to 1x1 faces."""
    return face_size.bit_length()


def downsample_2x2(cube: np.ndarray) -> np.ndarray:
    """(6, n, n, C) -> (6, n/2, n/2, C) by the 2x2 mean (cube texels of one level have nearly equal
    solid angles within a 2x2 block; the plain mean is what GL's MIP mapping does too)."""
    n = cube.shape[1]
    return cube.reshape(6, n // 2, 2, n // 2, 2, -1).mean(axis=(2, 4))


PAD = 2   # the 5x5 filter's reach beyond a face's edge


@functools.lru_cache(maxsize=32)
def _ring(n: int) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """Where the texels of each face's border ring (PAD wide, outside the face) lie on the cube:
    (face, row, col) in the padded face, and the (face, row, col) they are read from
    (cube.neighbour_texel). O(n) indices, where a gather of all 25 taps of every texel took 25 x 6 n^2
    (3.8 GB at a 1024^2 level)."""
    f, r, c = np.meshgrid(np.arange(6), np.arange(-PAD, n + PAD), np.arange(-PAD, n + PAD), indexing="ij")
    outside = (r < 0) | (r >= n) | (c < 0) | (c >= n)
    f, r, c = f[outside], r[outside], c[outside]
    return (f, r + PAD, c + PAD), neighbour_texel(f, r, c, n)


def filter_5x5(cube: np.ndarray, kind: Filter | str) -> np.ndarray:
    """Apply the 5x5 filter to every face of cube (6, n, n, C), crossing face edges: each face padded by
    the texels beyond its edges (the k-th texel beyond an edge is the k-th into the neighbouring face),
    then the separable taps along rows and columns."""
    kind = Filter.parse(kind)
    if kind is Filter.NONE:
        return cube.copy()
    w1 = taps_1d(kind)
    n = cube.shape[1]
    cube = np.asarray(cube, np.float64)
    padded = np.empty((6, n + 2 * PAD, n + 2 * PAD) + cube.shape[3:], np.float64)
    padded[:, PAD:PAD + n, PAD:PAD + n] = cube
    at, source = _ring(n)
    padded[at] = cube[source]
    rows = sum(w1[k] * padded[:, :, k:k + n] for k in range(2 * PAD + 1))      # (6, n + 2 PAD, n, C)
    return sum(w1[k] * rows[:, k:k + n] for k in range(2 * PAD + 1))


def texel_weights(face_size: int) -> np.ndarray:
    """w: texel solid angle relative to the face centre's, float64 (6, n, n, 1), in (0.19, 1]."""
    omega = texel_solid_angles(face_size)
    return np.broadcast_to((omega / omega.max())[None, :, :, None], (6, face_size, face_size, 1)).copy()


def unweighted_chain(cube: np.ndarray, kind: Filter | str, levels: int | None = None) -> list[np.ndarray]:
    """The plain MIP chain (2x2 mean + F5x5 per level) of any (6, n, n, C) array: float64 levels."""
    levels = mip_levels(cube.shape[1]) if levels is None else levels
    chain = [np.asarray(cube, np.float64)]
    for _ in range(1, levels):
        chain.append(filter_5x5(downsample_2x2(chain[-1]), kind))
    return chain


@functools.lru_cache(maxsize=32)
def weight_chain(face_size: int, kind: Filter | str, levels: int | None = None) -> tuple[np.ndarray, ...]:
    """B = chain(w) (see the module doc): the normalizer of every level, float64 (6, n_l, n_l, 1).
    Cached per process and in the user's cache folder (user_cache.py)."""
    from .. import user_cache

    kind = Filter.parse(kind)
    stored = user_cache.cached_arrays(
        user_cache.user_cache_dir("weight-chains"), f"{face_size}-{kind.value}-{levels}",
        (__name__, "renderer.envmap.cube", "renderer.lighting.filters"),
        lambda: {f"level_{i}": a for i, a in enumerate(unweighted_chain(texel_weights(face_size), kind, levels))})
    chain = [stored[f"level_{i}"] for i in range(len(stored))]
    for level in chain:
        level.setflags(write=False)
    return tuple(chain)


def pem_chain(cube: np.ndarray, kind: Filter | str, levels: int | None = None) -> list[np.ndarray]:
    """The solid-angle weighted MIP chain of one (partial) environment map, A / B at the texel centres:
    list of (6, n_l, n_l, C) float64 arrays."""
    cube = np.asarray(cube, np.float64)
    n = cube.shape[1]
    norm = weight_chain(n, Filter.parse(kind), levels)
    return [a / b for a, b in zip(unweighted_chain(cube * texel_weights(n), kind, levels), norm)]
