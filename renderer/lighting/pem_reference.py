"""Slow, exact numpy version of the PEM MIP-chain build; the GPU build is tested against it and the
glossiness calibration runs on it (it needs no GL context).

Level 0 is the (partial) map itself: the mirror lobe. Level L+1 = F5x5(M2x2(level L)), where M2x2
is the classic 2x2 mean of MIP mapping and F5x5 the separable normalized filter of `filters.py`,
evaluated as the full 25-tap outer product so that taps beyond a face edge read the neighbouring
face (cube.neighbour_texel): no seams, and the result does not depend on the pass order.
"""

from __future__ import annotations

import functools

import numpy as np

from ..envmap.cube import neighbour_texel
from .filters import Filter, taps_1d


def mip_levels(face_size: int) -> int:
    """Number of levels of a full chain down to 1x1 faces."""
    return face_size.bit_length()


def downsample_2x2(cube: np.ndarray) -> np.ndarray:
    """(6, n, n, C) -> (6, n/2, n/2, C) by the 2x2 mean (cube texels of one level have nearly equal
    solid angles within a 2x2 block; the plain mean is what GL's MIP mapping does too)."""
    n = cube.shape[1]
    return cube.reshape(6, n // 2, 2, n // 2, 2, -1).mean(axis=(2, 4))


@functools.lru_cache(maxsize=32)
def _tap_indices(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f, r, c = np.meshgrid(np.arange(6), np.arange(n), np.arange(n), indexing="ij")
    out = [neighbour_texel(f, r + dy, c + dx, n) for dy in range(-2, 3) for dx in range(-2, 3)]
    return tuple(np.stack([o[k] for o in out]) for k in range(3))  # each (25, 6, n, n)


def filter_5x5(cube: np.ndarray, kind: Filter | str) -> np.ndarray:
    """Apply the 5x5 filter to every face of cube (6, n, n, C), crossing face edges."""
    kind = Filter.parse(kind)
    if kind is Filter.NONE:
        return cube.copy()
    w1 = taps_1d(kind)
    w2 = np.outer(w1, w1).reshape(25)
    fi, ri, ci = _tap_indices(cube.shape[1])
    out = np.zeros_like(cube, dtype=np.float64)
    for k in range(25):
        out += w2[k] * cube[fi[k], ri[k], ci[k]]
    return out


def pem_chain(cube: np.ndarray, kind: Filter | str, levels: int | None = None) -> list[np.ndarray]:
    """The MIP chain of one (partial) environment map: list of (6, n_l, n_l, C) float64 arrays."""
    levels = mip_levels(cube.shape[1]) if levels is None else levels
    chain = [np.asarray(cube, np.float64)]
    for _ in range(1, levels):
        chain.append(filter_5x5(downsample_2x2(chain[-1]), kind))
    return chain
