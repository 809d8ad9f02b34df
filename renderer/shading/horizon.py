"""The share of a glossy lobe above the surface's tangent plane.

The reference (renderer/reference/montecarlo.py) does not clip the Phong lobe around r at the horizon
of n: the part of the lobe below the surface is blocked by visibility wherever geometry lies behind
the surface (a closed body, or the body under a garment). A PEM lookup along r has no such loss, and a
shadow map cannot see it either (the surface is its own first occluder only for lights behind it).
At grazing view angles r skims the tangent plane and up to half of the lobe is below it: measured on
the hard-sun scene, the silhouettes were the brightest errors (docs/benchmarks.md).

Two corrections, `FrameSettings.glossy_horizon`: "lights" (the default) multiplies each light's glossy
term by the share of its disc above the triangle's own plane (right at region granularity; it removes
a sun below the surface, which a shadow map misses at the terminator); "lobe" multiplies the glossy
term by F below, the share of the lobe above the shading normal's plane (right for an environment that
is uniform across the horizon); "both" applies the two, which overlap. Measured on the five benchmark
scenes (docs/benchmarks.md, the glossy_horizon rows).

F(mu, g) = integral over {w : n.w > 0} of T_s(r.w) dw / integral of T_s, with mu = n.r (>= 0: the
renderer flips n to face the camera, and r is the mirror of the view about n), T_s the normalized
Phong lobe of s = 1 / (1 - g). It depends on mu and g only, so it is tabulated once and the shading
pass multiplies the glossy term by one lookup per pixel.
"""

from __future__ import annotations

import functools

import numpy as np

N_MU, N_G = 64, 65
_STRATA = 96  # quadrature: _STRATA x _STRATA stratified lobe samples per entry
MAX_EXPONENT = 1e5  # beyond this the lobe is narrower than any texel: the mirror


@functools.lru_cache(maxsize=1)
def horizon_table() -> np.ndarray:
    """F(mu, g), float32 (N_G, N_MU): row k is g = k / (N_G - 1), column j is mu = j / (N_MU - 1)."""
    u = (np.arange(_STRATA) + 0.5) / _STRATA
    phi = 2.0 * np.pi * u
    mu = np.linspace(0.0, 1.0, N_MU)
    sin_b = mu                          # r's elevation above the tangent plane: sin = n.r
    cos_b = np.sqrt(1.0 - mu * mu)
    out = np.empty((N_G, N_MU), np.float32)
    for k, g in enumerate(np.linspace(0.0, 1.0, N_G)):
        s = min(1.0 / max(1.0 - g, 1e-12), MAX_EXPONENT)
        cos_t = u ** (1.0 / (s + 1.0))  # Phong-lobe samples around r (CDF of cos is cos^(s + 1))
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        # n . w for w at angle t from r, azimuth phi measured from the plane containing n and r:
        # with r = (cos_b, 0, sin_b) and n = z, n.w = cos_t sin_b + sin_t cos(phi) cos_b (sign: the
        # tilt towards n at phi = 0).
        ct, st, cp = cos_t[:, None, None], sin_t[:, None, None], np.cos(phi)[None, :, None]
        nw = ct * sin_b[None, None, :] + st * cp * cos_b[None, None, :]
        out[k] = (nw > 0.0).mean(axis=(0, 1))
    return out
