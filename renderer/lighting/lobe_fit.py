"""Kautz and McCool's approximation of a BRDF by radially symmetric lobes ("Approximation of Glossy
Reflection with Prefiltered Environment Maps", GI 2000, section 3), in numpy.

For one view elevation, the BRDF slice p(l) = f(v, l) (n.l) (renderer/shading/brdf.py) is sampled on a
polar grid about a lobe axis (the mirror direction r of v by default). A radially symmetric lobe
depends only on the angle theta to that axis, so the slice is reduced to a profile curve over theta:
its peak (the largest value at each theta over the azimuth), its average, or its minimum. The profile
is fitted, in the least-squares sense over the sphere, by a normalized Phong lobe

    w (s + 1) / (2 pi) cos(theta)^s,

which is exactly the kind of lobe a PEM level prefilters (renderer/lighting/glossiness.py maps an
exponent to a level). Greedily, each further lobe fits what the ones before left (the residual
slice), on the axis, among the paper's section 6 places (the mirror direction, tilts towards the
normal, the normal, the view), that leaves the least error. Last, the paper's energy correction scales the weights so that the lobes reflect, over the
upper hemisphere, exactly what the slice does: its hemispherical reflectivity.

Orientation: the view lies in the x-z plane at elevation theta_v from the normal n = +z, v =
(sin theta_v, 0, cos theta_v).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

N = np.array([0.0, 0.0, 1.0])
PROFILES = ("peak", "average", "minimum")
# Exponents the fit chooses among (then refined): from a lobe wider than the cosine to a near mirror.
_EXPONENTS = np.geomspace(0.05, 2.0e4, 400)


@dataclass(frozen=True)
class Lobe:
    """weight: the lobe's scale w (its energy over the whole sphere); exponent: s; axis: the unit
    direction (3,) the lobe is symmetric about."""

    weight: float
    exponent: float
    axis: tuple[float, float, float]


@dataclass(frozen=True)
class Fit:
    """The lobes of one slice, the slice's hemispherical reflectivity (what the lobes reflect after
    the energy correction) and the relative RMS error of the fit over the hemisphere."""

    lobes: tuple[Lobe, ...]
    reflectivity: float
    rel_rms: float


def view_direction(theta_v: float) -> np.ndarray:
    return np.array([np.sin(theta_v), 0.0, np.cos(theta_v)])


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t = np.cross(helper, axis)
    t /= np.linalg.norm(t)
    return t, np.cross(axis, t)


@dataclass(frozen=True)
class PolarGrid:
    """Directions about an axis: theta (T,) denser near the axis, phi (P,), dirs (T, P, 3) and the
    solid angle of each cell (T, 1)."""

    axis: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    dirs: np.ndarray
    d_omega: np.ndarray

    @classmethod
    def about(cls, axis: np.ndarray, n_theta: int = 384, n_phi: int = 96) -> PolarGrid:
        axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
        edges = np.pi * np.linspace(0.0, 1.0, n_theta + 1) ** 2   # fine near the axis, where lobes peak
        theta = 0.5 * (edges[1:] + edges[:-1])
        phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
        t, b = _frame(axis)
        st, ct = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
        dirs = st * (np.cos(phi)[None, :, None] * t + np.sin(phi)[None, :, None] * b) + ct * axis
        d_omega = ((np.cos(edges[:-1]) - np.cos(edges[1:])) * 2.0 * np.pi / n_phi)[:, None]
        return cls(axis, theta, phi, dirs, d_omega)


def profile(values: np.ndarray, kind: str) -> np.ndarray:
    """The slice reduced to a curve over theta (T,): its peak, average or minimum over the azimuth."""
    if kind == "peak":
        return values.max(axis=1)
    if kind == "average":
        return values.mean(axis=1)
    if kind == "minimum":
        return values.min(axis=1)
    raise ValueError(f"profile must be one of {PROFILES}, got {kind!r}")


def phong_profile(theta: np.ndarray, exponent: float) -> np.ndarray:
    with np.errstate(under="ignore"):
        return (exponent + 1.0) / (2.0 * np.pi) * np.clip(np.cos(theta), 0.0, 1.0) ** exponent


def fit_profile(theta: np.ndarray, d_theta_omega: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """The (weight, exponent) of the normalized Phong lobe closest to `target` (T,) in L2 over the
    sphere (cell solid angles summed over the azimuth, d_theta_omega (T,)): for each exponent the best
    weight is <target, lobe> / <lobe, lobe>; the exponent minimizes the remaining error, searched on a
    log grid and refined by golden section."""
    def error(s: float) -> tuple[float, float]:
        lobe = phong_profile(theta, s)
        ll = float(np.sum(lobe * lobe * d_theta_omega))
        w = max(float(np.sum(target * lobe * d_theta_omega)) / ll, 0.0) if ll > 0 else 0.0
        return float(np.sum((target - w * lobe) ** 2 * d_theta_omega)), w

    errs = np.array([error(s)[0] for s in _EXPONENTS])
    k = int(np.argmin(errs))
    lo, hi = np.log(_EXPONENTS[max(k - 1, 0)]), np.log(_EXPONENTS[min(k + 1, len(_EXPONENTS) - 1)])
    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    for _ in range(40):
        if error(np.exp(a))[0] < error(np.exp(b))[0]:
            hi, b = b, a
            a = hi - g * (hi - lo)
        else:
            lo, a = a, b
            b = lo + g * (hi - lo)
    s = float(np.exp(0.5 * (lo + hi)))
    return error(s)[1], s


def fibonacci_sphere(count: int = 200_000) -> tuple[np.ndarray, float]:
    """Nearly uniform directions (count, 3), each standing for 4 pi / count sr."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1), 4.0 * np.pi / count


@functools.cache
def _sphere() -> tuple[np.ndarray, float]:
    """The directions the fit's error and energy are judged on, made on first use (4.8 MB)."""
    dirs, d_omega = fibonacci_sphere()
    dirs.setflags(write=False)
    return dirs, d_omega


def lobe_values(lobes, dirs: np.ndarray) -> np.ndarray:
    """The sum of the lobes at `dirs` (..., 3), 0 below the horizon."""
    out = np.zeros(dirs.shape[:-1])
    for w, s, axis in lobes:
        out += w * phong_profile(np.arccos(np.clip(dirs @ axis, -1.0, 1.0)), s)
    return np.where(dirs @ N > 0.0, out, 0.0)


def candidate_axes(theta_v: float, steps: int = 4) -> list[np.ndarray]:
    """Where a lobe may sit (the paper's section 6): on the great circle from the mirror direction r
    of the view to the normal (r itself, off-specular tilts towards n, n), and on the view itself (the
    back-scattering of sheen at grazing angles)."""
    v = view_direction(theta_v)
    r = 2.0 * (v @ N) * N - v
    axes = []
    for t in np.linspace(0.0, 1.0, steps + 1):
        a = (1.0 - t) * r + t * N
        axes.append(a / np.linalg.norm(a))
    axes.append(v)
    return axes


def fit_lobes(fn: Callable, theta_v: float, count: int = 1, kind: str = "average", axis: np.ndarray | None = None,
              **material) -> Fit:
    """`count` lobes fitted greedily to the slice of `fn` at view elevation theta_v (radians), with
    the energy correction. Each lobe sits on `axis` when given, else on whichever of
    `candidate_axes` leaves the least error over the hemisphere."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    v = view_direction(theta_v)
    dirs, d_omega = _sphere()
    target = fn(N, v, dirs, **material).mean(axis=-1)       # the slice on the sphere (0 below the horizon)
    reflectivity = float(target.sum() * d_omega)
    axes = [np.asarray(axis, np.float64) / np.linalg.norm(axis)] if axis is not None else candidate_axes(theta_v)
    # Each axis's grid, the slice on it and the lobes so far there: made once, not once per lobe.
    grids = [PolarGrid.about(a) for a in axes]
    on_grid = [[fn(N, v, g.dirs, **material).mean(axis=-1), np.zeros(g.dirs.shape[:-1])] for g in grids]
    lobes: list[tuple[float, float, np.ndarray]] = []
    fitted = np.zeros(len(dirs))                             # the lobes so far on the sphere
    for _ in range(count):
        best = None
        for a, grid, (values, so_far) in zip(axes, grids, on_grid):
            residual = np.maximum(values - so_far, 0.0)
            w, s = fit_profile(grid.theta, grid.d_omega[:, 0] * len(grid.phi), profile(residual, kind))
            trial = fitted + lobe_values([(w, s, a)], dirs)
            err = float(np.sum((trial - target) ** 2))
            if best is None or err < best[0]:
                best = (err, (w, s, a), trial)
        _, lobe, fitted = best
        lobes.append(lobe)
        for grid, pair in zip(grids, on_grid):
            pair[1] = pair[1] + lobe_values([lobe], grid.dirs)
    # The paper's energy correction: the lobes reflect over the hemisphere what the slice does.
    energy = float(fitted.sum() * d_omega)
    scale = reflectivity / energy if energy > 0 else 0.0
    rms = np.sqrt(np.sum((scale * fitted - target) ** 2) / max(float(np.sum(target ** 2)), 1e-300))
    return Fit(tuple(Lobe(w * scale, s, tuple(float(c) for c in a)) for w, s, a in lobes), reflectivity, float(rms))
