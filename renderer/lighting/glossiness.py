"""Glossiness g -> fractional MIP level, calibrated by lobe volume (Knuth et al. 2014, section 5).

Model (Eq. 3, 4): g in [0, 1], Phong exponent s = 1 / (1 - g); the lobe around the reflection
direction r is cos^s(angle(r, w)) on the hemisphere (s = 1: diffuse, s -> inf: mirror).

Approximation: the response of the PEM MIP chain to an impulse (a black map with one white texel)
at a fractional level l (trilinear lookup = linear blend of two levels, each bilinear) is a lobe
around the impulse direction. Both lobes are scaled to peak 1 and compared by the volume of their
3D radial plot, V = (1/3) * integral of r(w)^3 dw (the solid enclosed by the surface at radius
r(w)). For the cosine lobe this is closed-form:

    V_target(s) = (1/3) * 2*pi / (3 s + 1) = 2*pi*(1 - g) / (3 * (4 - g))

written in g so that g = 1 (s = inf) gives V = 0 and the mirror level without a division by zero.
The calibration tabulates V(l) on a fine grid of l for each face size and filter and inverts it.
The paper's relative lobe error (Fig. 5) is the volume of the symmetric difference of the two
radial solids at equal volume, in percent of the target volume.

A second calibration, "l2" (the renderer's default): the level whose kernel, normalized to integrate
to 1 as the lookup applies it, is closest in L2 over the sphere to the normalized Phong lobe
(s + 1) / (2 pi) max(0, cos)^s that the reference integrates. Volume matching of peak-1 lobes ignores
the kernel's peak height and tails, which are what a small bright region sees; against the Monte Carlo
reference (docs/sweep.md) the l2 levels are deeper for mid glossiness (g = 0.8 at 128^2: 4.4
instead of 3.9) and every target scene's error drops. Where the lobe gets too narrow for the
evaluation grid (s above ~2 / (4 texels)^2), the l2 level joins the volume level smoothly, and the
mirror stays level 0.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..envmap.cube import face_uv_to_dir, sample_bilinear, texel_directions, texel_solid_angles
from ..errors import InvalidInputError
from .filters import Filter
from .pem_reference import mip_levels, pem_chain

STEPS_PER_LEVEL = 32  # finer steps matter: within a level most volume growth is in its last eighth
_EVAL_FACE_MAX = 128  # the evaluation grid; finer than any lobe above level 0 at these sizes


class Calibration(str, Enum):
    """How g becomes a MIP level (see the module doc)."""

    VOLUME = "volume"  # the paper's section 5: equal radial-plot volume of peak-1 lobes
    L2 = "l2"          # the closest normalized kernel to the normalized Phong lobe

    @classmethod
    def parse(cls, value: Calibration | str) -> Calibration:
        try:
            return cls(value)
        except ValueError:
            raise InvalidInputError(f"calibration must be one of {', '.join(c.value for c in cls)}, got {value!r}") from None


def check_glossiness(g: float) -> float:
    g = float(g)
    if not np.isfinite(g) or g < 0.0 or g > 1.0:
        raise InvalidInputError(f"glossiness must be a number in [0, 1] (0 diffuse, 1 mirror), got {g}")
    return g


def phong_exponent(g: float) -> float:
    """s = 1 / (1 - g) (Eq. 3); +inf at g = 1."""
    g = check_glossiness(g)
    return np.inf if g >= 1.0 else 1.0 / (1.0 - g)


def target_volume(g: np.ndarray | float) -> np.ndarray:
    """Radial-plot volume of the peak-1 cosine lobe of glossiness g (see module doc)."""
    one_minus_g = 1.0 - np.asarray(g, np.float64)
    return 2.0 * np.pi * one_minus_g / (3.0 * (3.0 + one_minus_g))


def cosine_lobe(cos_angle: np.ndarray, s: float) -> np.ndarray:
    """Peak-1 cosine lobe max(0, cos)^s; s = inf gives the mirror delta (1 at cos = 1 only)."""
    c = np.clip(cos_angle, 0.0, 1.0)
    if np.isinf(s):
        return (c >= 1.0).astype(np.float64)
    return c ** s


@dataclass(frozen=True)
class LobeTable:
    """Impulse responses of one (face size, filter) chain, evaluated on a sphere grid."""

    face_size: int
    filter: Filter
    impulse_dir: np.ndarray          # (3,)
    eval_dirs: np.ndarray            # (M, 3)
    eval_omega: np.ndarray           # (M,) solid angles of the evaluation points
    responses: np.ndarray            # (levels, M), raw response of each integer level
    levels_grid: np.ndarray          # (K,) fractional levels
    volumes: np.ndarray              # (K,) peak-1 radial volume at each fractional level
    l2_log_s: np.ndarray = None      # (J,) log of the exponents s where the l2 calibration is tabulated
    l2_levels: np.ndarray = None     # (J,) its levels (non-increasing in s)
    # The integer levels' inner products the l2 distance is made of (`_l2_terms`): where the best level
    # jumps between two tabulated exponents (near an integer level), the level of an exponent between
    # them is found from these directly, not interpolated (a level between the two sides is worse than
    # both).
    l2_terms: tuple | None = None

    @property
    def n_levels(self) -> int:
        return self.responses.shape[0]

    def lobe(self, level: float) -> np.ndarray:
        """Peak-1 response (M,) at a fractional level, as a trilinear lookup would give it."""
        level = float(np.clip(level, 0.0, self.n_levels - 1))
        lo = int(np.floor(level))
        hi = min(lo + 1, self.n_levels - 1)
        t = level - lo
        r = (1.0 - t) * self.responses[lo] + t * self.responses[hi]
        return r / max(r.max(), 1e-300)

    def level_for_glossiness(self, g: float, calibration: Calibration | str = Calibration.VOLUME) -> float:
        """Fractional MIP level of glossiness g: equal lobe volume (the paper) or the l2 calibration."""
        v = float(target_volume(check_glossiness(g)))
        volume_level = float(np.interp(v, self.volumes, self.levels_grid))
        if Calibration.parse(calibration) is Calibration.VOLUME or self.l2_levels is None:
            return volume_level
        if g >= 1.0:
            return 0.0
        log_s = -np.log(1.0 - g)
        if log_s <= self.l2_log_s[-1]:
            j = int(np.clip(np.searchsorted(self.l2_log_s, log_s), 1, len(self.l2_log_s) - 1))
            lo, hi = self.l2_levels[j], self.l2_levels[j - 1]   # non-increasing in s
            if hi - lo <= 2.0 / STEPS_PER_LEVEL:
                return float(np.interp(log_s, self.l2_log_s, self.l2_levels))
            # Between the two tabulated exponents the best level jumps: found for this one, kept
            # within the two (the table is non-increasing in s).
            exact = float(_l2_best(self.l2_terms, self.levels_grid, np.array([np.exp(log_s)]))[0])
            return float(np.clip(exact, lo, hi))
        # Beyond the resolved range: the volume level plus the offset at the last resolved s, shrinking
        # with the volume level so that the mirror stays level 0.
        g_last = 1.0 - np.exp(-self.l2_log_s[-1])
        vol_last = float(np.interp(float(target_volume(g_last)), self.volumes, self.levels_grid))
        offset = self.l2_levels[-1] - vol_last
        return float(max(volume_level + offset * volume_level / max(vol_last, 1e-12), 0.0))

    def relative_error(self, g: float) -> float:
        """Volume of the symmetric difference between target and calibrated lobe / target volume."""
        g = check_glossiness(g)
        s = phong_exponent(g)
        approx = self.lobe(self.level_for_glossiness(g))
        target = cosine_lobe(self.eval_dirs @ self.impulse_dir, s)
        vt = float(target_volume(g))
        if vt <= 0:
            return float("nan")
        return float((np.abs(approx ** 3 - target ** 3) * self.eval_omega).sum() / 3.0 / vt)


_TABLE_FIELDS = ("impulse_dir", "eval_dirs", "eval_omega", "responses", "levels_grid", "volumes", "l2_log_s",
                 "l2_levels")


@functools.lru_cache(maxsize=16)
def lobe_table(face_size: int, kind: Filter | str = Filter.SQRT_COSINE) -> LobeTable:
    """Calibrate one (face size, filter) pair. Deterministic, cached per process and in the user's
    cache folder (user_cache.py; about 1 s to build at 128^2, a few ms to read)."""
    kind = Filter.parse(kind)
    if face_size < 2 or face_size & (face_size - 1):
        raise InvalidInputError(f"face size must be a power of two >= 2, got {face_size}")
    from .. import user_cache

    def build() -> dict[str, np.ndarray]:
        t = _build_lobe_table(face_size, kind)
        arrays = {k: np.asarray(getattr(t, k)) for k in _TABLE_FIELDS}
        arrays.update({f"l2_terms_{i}": np.asarray(a) for i, a in enumerate(t.l2_terms)})
        return arrays

    code = (__name__, "renderer.envmap.cube", "renderer.lighting.filters", "renderer.lighting.pem_reference")
    a = user_cache.cached_arrays(user_cache.user_cache_dir("lobe-tables"), f"{face_size}-{kind.value}", code, build)
    terms = tuple(a[f"l2_terms_{i}"] for i in range(sum(k.startswith("l2_terms_") for k in a)))
    return LobeTable(face_size, kind, *(a[k] for k in _TABLE_FIELDS), terms)


def _build_lobe_table(face_size: int, kind: Filter) -> LobeTable:
    # Impulse at the texel just below-right of the +Z face centre (face 4).
    face, row, col = 4, face_size // 2, face_size // 2
    impulse = np.zeros((6, face_size, face_size, 1))
    impulse[face, row, col, 0] = 1.0
    chain = pem_chain(impulse, kind)
    centre = (np.array([col, row]) + 0.5) * (2.0 / face_size) - 1.0       # the texel's (u, v), as texel_directions
    impulse_dir = face_uv_to_dir(face, centre[0], centre[1])
    impulse_dir = impulse_dir / np.linalg.norm(impulse_dir)

    m = min(face_size, _EVAL_FACE_MAX)
    dirs = texel_directions(m).reshape(-1, 3)
    omega = np.broadcast_to(texel_solid_angles(m), (6, m, m)).reshape(-1)
    # Level 0 is evaluated on the texel grid itself when it is finer than the evaluation grid.
    responses = np.stack([sample_bilinear(level, dirs)[..., 0] for level in chain])

    n_levels = len(chain)
    grid = np.linspace(0.0, n_levels - 1, (n_levels - 1) * STEPS_PER_LEVEL + 1)
    table = LobeTable(face_size, kind, impulse_dir, dirs, omega, responses, grid, np.zeros(0))
    vols = np.array([(table.lobe(level) ** 3 * omega).sum() / 3.0 for level in grid])
    vols = np.maximum.accumulate(vols)  # volume grows with blur; make the inverse well defined
    log_s, l2, terms = _l2_calibration(responses, dirs @ impulse_dir, omega, grid, m)
    return LobeTable(face_size, kind, impulse_dir, dirs, omega, responses, grid, vols, log_s, l2, terms)


def _l2_calibration(responses: np.ndarray, cos_to_impulse: np.ndarray, omega: np.ndarray, grid: np.ndarray,
                    eval_face: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The l2 levels (module doc) for exponents s from 1 to the finest lobe the evaluation grid resolves.

    With K = ((1 - f) R_lo + f R_hi) / a the normalized kernel at level lo + f (a its integral),
    ||K - T||^2 = <K, K> - 2 <K, T> + const, and both terms come from the integer levels' inner
    products, so every (s, level) pair costs O(1) after O(levels * M) work per s.
    """
    texel = 0.5 * np.pi / eval_face
    s_max = 2.0 / (4.0 * texel) ** 2  # lobe width sqrt(2 / s) >= 4 evaluation texels
    exps = np.geomspace(1.0, s_max, 96)
    terms = _l2_terms(responses, cos_to_impulse, omega)
    return np.log(exps), np.minimum.accumulate(_l2_best(terms, grid, exps)), terms


def _l2_terms(responses: np.ndarray, cos_to_impulse: np.ndarray, omega: np.ndarray) -> tuple:
    rw = responses * omega                                   # (L, M)
    n_lev = len(responses)
    q_same = (rw * responses).sum(axis=1)                    # <R_l, R_l>
    q_next = np.array([(rw[k] * responses[min(k + 1, n_lev - 1)]).sum() for k in range(n_lev)])
    return rw, rw.sum(axis=1), q_same, q_next, np.clip(cos_to_impulse, 0.0, 1.0)


def _l2_best(terms: tuple, grid: np.ndarray, exps: np.ndarray) -> np.ndarray:
    """For each exponent, the level of `grid` whose normalized kernel is closest to the lobe."""
    rw, a, q_same, q_next, c = terms
    n_lev = len(a)
    with np.errstate(under="ignore"):
        p = np.stack([rw @ ((s + 1.0) / (2.0 * np.pi) * c ** s) for s in exps], axis=1)   # (L, S): <R_l, T_s>
    lo = np.minimum(np.floor(grid).astype(int), n_lev - 1)
    hi = np.minimum(lo + 1, n_lev - 1)
    f = (grid - lo)[:, None]
    norm = (1.0 - f[:, 0]) * a[lo] + f[:, 0] * a[hi]
    # A grid point whose kernel has no weight on the sampled directions (the mirror level of a large
    # face, narrower than the samples) cannot be fitted: it is left out rather than divided by zero.
    ok = norm > 0
    safe = np.where(ok, norm, 1.0)
    kk = ((1.0 - f[:, 0]) ** 2 * q_same[lo] + 2 * f[:, 0] * (1.0 - f[:, 0]) * q_next[lo]
          + f[:, 0] ** 2 * q_same[hi]) / safe ** 2
    kt = ((1.0 - f) * p[lo] + f * p[hi]) / safe[:, None]     # (K, S)
    cost = np.where(ok[:, None], kk[:, None] - 2.0 * kt, np.inf)
    return grid[np.argmin(cost, axis=0)]


def level_for_glossiness(g: float, face_size: int, kind: Filter | str = Filter.SQRT_COSINE) -> float:
    return lobe_table(face_size, Filter.parse(kind)).level_for_glossiness(g)


def diffuse_level(face_size: int, kind: Filter | str = Filter.SQRT_COSINE) -> float:
    """The level of the s = 1 cosine lobe: where the diffuse term is looked up."""
    return level_for_glossiness(0.0, face_size, kind)


def levels_needed(face_size: int, kind: Filter | str, glossiness_range: tuple[float, float]) -> int:
    """Number of MIP levels (from 0) a scene needs to look up every g in the range and the diffuse lobe."""
    lo_g, hi_g = glossiness_range
    deepest = max(diffuse_level(face_size, kind), level_for_glossiness(min(lo_g, hi_g), face_size, kind))
    return min(mip_levels(face_size), int(np.ceil(deepest)) + 1)
