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
normal, the normal, the view, and angles between), that leaves the least error. A joint nonlinear
least-squares refinement of all lobes follows (our addition; the greedy error is kept beside it).
Last, the paper's energy correction scales the weights so that the lobes reflect, over the upper
hemisphere, exactly what the slice does: its hemispherical reflectivity.

Orientation: the view lies in the x-z plane at elevation theta_v from the normal n = +z, v =
(sin theta_v, 0, cos theta_v).
"""

from __future__ import annotations

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
    the energy correction) and the relative RMS error of the fit over the hemisphere (after the joint
refinement; greedy_rel_rms: the paper's greedy lobes alone, also energy-corrected)."""

    lobes: tuple[Lobe, ...]
    reflectivity: float
    rel_rms: float
    greedy_rel_rms: float = float("nan")


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


def lobe_values(lobes, dirs: np.ndarray) -> np.ndarray:
    """The sum of the lobes at `dirs` (..., 3), 0 below the horizon."""
    out = np.zeros(dirs.shape[:-1])
    for w, s, axis in lobes:
        out += w * phong_profile(np.arccos(np.clip(dirs @ axis, -1.0, 1.0)), s)
    return np.where(dirs @ N > 0.0, out, 0.0)


def axis_at(psi: float) -> np.ndarray:
    """The unit direction at angle psi from the normal in the plane of n and v, positive towards v:
    the mirror direction r is psi = -theta_v, the normal 0, the view +theta_v (the paper's section 6
    places, and every direction between them)."""
    return np.array([np.sin(psi), 0.0, np.cos(psi)])


def candidate_axes(theta_v: float, steps: int = 12) -> list[float]:
    """The angles psi (see `axis_at`) a greedy lobe is tried at: r, n and v themselves, and `steps`
    + 1 angles across the whole plane from one horizon to the other (the off-specular tilts of a
    microfacet lobe towards the normal, the back-scattering of sheen near the view)."""
    psis = np.concatenate([[-theta_v, 0.0, theta_v], np.linspace(-0.5 * np.pi, 0.5 * np.pi, steps + 1)])
    return [float(p) for p in np.unique(np.round(psis, 12))]


# Bounds of the refinement: an exponent from wider than a cosine to a near mirror; an axis anywhere
# in the plane of n and v above the horizon.
_LOG_S = (np.log(0.05), np.log(2.0e6))


def judge_grid(theta_v: float) -> PolarGrid:
    """The grid the error and the energy are judged on: polar about the mirror direction, where GGX
    lobes are narrowest (its first cells are 1e-5 rad wide, so a near-mirror lobe is resolved; a
    Fibonacci sphere of 2e5 points is spaced 0.45 degrees)."""
    v = view_direction(theta_v)
    return PolarGrid.about(2.0 * (v @ N) * N - v, n_theta=320, n_phi=96)


def _lobe_sum(params: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """`lobe_values` of the fit's parameters, (log w, log s, psi) per lobe."""
    return lobe_values([(np.exp(lw), np.exp(ls), axis_at(psi)) for lw, ls, psi in params.reshape(-1, 3)], dirs)


def fit_lobes(fn: Callable, theta_v: float, count: int = 1, kind: str = "average", axis: np.ndarray | None = None,
              refine: bool = True, **material) -> Fit:
    """`count` lobes fitted to the slice of `fn` at view elevation theta_v (radians), then the energy
    correction.

    The paper's greedy fit first: each lobe fits the `kind` profile of what the ones before left, on
    `axis` when given, else at whichever of `candidate_axes` leaves the least error. Then (refine)
    all lobes' weights, exponents and (without `axis`) angles together by nonlinear least squares
    over the hemisphere, started from the greedy lobes: the greedy fit never revisits a lobe, so the
    first one, fitted alone, is too wide once a second takes the tail. `greedy_rel_rms` keeps the
    paper's own error."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    v = view_direction(theta_v)
    judge = judge_grid(theta_v)
    cell = np.broadcast_to(judge.d_omega, judge.dirs.shape[:-1])
    target = fn(N, v, judge.dirs, **material).mean(axis=-1)      # the slice (0 below the horizon)
    reflectivity = float(np.sum(target * cell))
    norm = max(float(np.sum(target ** 2 * cell)), 1e-300)
    if axis is not None:
        axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
        psis = [float(np.arctan2(axis[0], axis[2]))]
    else:
        psis = candidate_axes(theta_v)
    grids = [PolarGrid.about(axis_at(p), n_theta=256, n_phi=64) for p in psis]
    on_grid = [[fn(N, v, g.dirs, **material).mean(axis=-1), np.zeros(g.dirs.shape[:-1])] for g in grids]
    params: list[float] = []
    fitted = np.zeros(target.shape)
    for _ in range(count):
        best = None
        for psi, grid, (values, so_far) in zip(psis, grids, on_grid):
            residual = np.maximum(values - so_far, 0.0)
            w, s = fit_profile(grid.theta, grid.d_omega[:, 0] * len(grid.phi), profile(residual, kind))
            if w <= 0.0:
                continue
            lobe = [np.log(w), np.log(s), psi]
            trial = fitted + _lobe_sum(np.array(lobe), judge.dirs)
            err = float(np.sum((trial - target) ** 2 * cell))
            if best is None or err < best[0]:
                best = (err, lobe, trial)
        if best is None:   # nothing left to fit
            break
        _, lobe, fitted = best
        params += lobe
        for grid, pair in zip(grids, on_grid):
            pair[1] = pair[1] + _lobe_sum(np.array(lobe), grid.dirs)
    if not params:
        return Fit((), reflectivity, 1.0, 1.0)
    x0 = np.array(params)
    greedy_rms = _corrected_rms(x0, judge.dirs, target, cell, reflectivity, norm)
    if refine:
        x0 = _refine(x0, judge.dirs, target, cell, reflectivity, fixed_axis=axis is not None)
    scaled = x0.reshape(-1, 3).copy()
    energy = float(np.sum(_lobe_sum(x0, judge.dirs) * cell))
    scaled[:, 0] += np.log(reflectivity / energy) if energy > 0 and reflectivity > 0 else 0.0
    rms = _corrected_rms(x0, judge.dirs, target, cell, reflectivity, norm)
    # Narrowest first: the same order at every view and roughness, so that tables interpolate.
    order = np.argsort(-scaled[:, 1])
    lobes = tuple(Lobe(float(np.exp(lw)), float(np.exp(ls)), tuple(float(c) for c in axis_at(psi)))
                  for lw, ls, psi in scaled[order])
    return Fit(lobes, reflectivity, rms, greedy_rms)


def _corrected_rms(x, dirs, target, cell, reflectivity, norm) -> float:
    """The relative RMS error over the hemisphere after the energy correction."""
    fitted = _lobe_sum(x, dirs)
    energy = float(np.sum(fitted * cell))
    scale = reflectivity / energy if energy > 0 else 0.0
    return float(np.sqrt(np.sum((scale * fitted - target) ** 2 * cell) / norm))


def _refine(x0: np.ndarray, dirs, target, cell, reflectivity: float, fixed_axis: bool) -> np.ndarray:
    """The lobes' parameters that minimize the error *after* the energy correction (so the weights'
    common scale is free; the relative weights, exponents and angles are what is fitted)."""
    from scipy.optimize import least_squares

    up = dirs[..., 2] > 0.0
    d, t, c = dirs[up], target[up], cell[up]
    sw = np.sqrt(c)
    k = len(x0) // 3
    free = np.ones(len(x0), bool)
    if fixed_axis:
        free[2::3] = False
    lo = np.tile([-60.0, _LOG_S[0], -0.5 * np.pi], k)
    hi = np.tile([10.0, _LOG_S[1], 0.5 * np.pi], k)
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)

    def residual(y):
        x = x0.copy()
        x[free] = y
        fitted = _lobe_sum(x, d)
        energy = float(np.sum(fitted * c))
        return sw * ((reflectivity / energy if energy > 0 else 0.0) * fitted - t)

    res = least_squares(residual, x0[free], bounds=(lo[free], hi[free]), x_scale="jac", max_nfev=200)
    x = x0.copy()
    x[free] = res.x
    return x if np.sum(residual(res.x) ** 2) <= np.sum(residual(x0[free]) ** 2) else x0
