"""Importance sampling of a cube-map environment for the Monte Carlo reference (numpy only).

The map is piecewise constant: the radiance along w is the value of the texel containing w
(`cube.dir_to_texel`). Sampling is two-stage (Pharr, Jakob & Humphreys, PBRT 3rd ed., sec. 14.2.4,
done on the cube's texels instead of a lat-long image):

1. pick texel t with probability P_t = (1 - a) * Y_t Omega_t / sum(Y Omega) + a * Omega_t / 4 pi,
   Y the Rec. 709 luminance, Omega_t the exact solid angle of the texel and a = `uniform_share` a
   floor that gives every texel (black ones included) a nonzero probability, so the estimator stays
   unbiased where the map is black but the scene has something to say (MIS with BRDF sampling
   covers those too, the floor is a safety net);
2. pick (u, v) uniformly in the texel's square on the face plane. The face point (u, v, 1) maps to
   the sphere with dOmega = du dv / (1 + u^2 + v^2)^(3/2) (the projected-area element, the same one
   `cube.texel_solid_angles` integrates), so the solid-angle density is exactly

       p(w) = P_t / (2 / F)^2 * (1 + u^2 + v^2)^(3/2).

   This is not uniform in solid angle within a texel, but it is the exact density of what is
   sampled, so L / p is unbiased; within a texel it varies by less than (2/F) * 3 / 2 relative.
"""

from __future__ import annotations

import numpy as np

from ..envmap.cube import cube_solid_angles, dir_to_face_uv, dir_to_texel, face_uv_to_dir
from ..errors import InvalidInputError

# Rec. 709 / sRGB primaries, linear RGB -> relative luminance Y.
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])


def check_cube(cube: np.ndarray) -> np.ndarray:
    """Validate a cube map (6, F, F, 3) of finite, non-negative radiance; returns float64 (read-only)."""
    c = np.asarray(cube)
    if c.ndim != 4 or c.shape[0] != 6 or c.shape[1] != c.shape[2] or c.shape[1] < 1 or c.shape[3] != 3:
        raise InvalidInputError(f"environment cube must have shape (6, F, F, 3); got {c.shape}")
    if c.dtype.kind not in "fiu":
        raise InvalidInputError(f"environment cube must be numeric; got dtype {c.dtype}")
    c = np.array(c, np.float64)
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise InvalidInputError("environment cube has NaN, Inf or negative texels; repair the map first "
                                "(load_environment(..., repair=True))")
    c.setflags(write=False)
    return c


class EnvironmentSampler:
    """The texel distribution of one cube map (build once per map; immutable).

    cube: (6, F, F, 3) linear RGB radiance, OpenGL cube convention (`renderer/envmap/cube.py`).
    uniform_share: the share a of the uniform (by solid angle) floor, in (0, 1].
    """

    def __init__(self, cube: np.ndarray, uniform_share: float = 0.05):
        if not 0.0 < uniform_share <= 1.0:
            raise InvalidInputError(f"uniform_share must be in (0, 1], got {uniform_share}")
        self.cube = check_cube(cube)
        self.face_size = n = self.cube.shape[1]
        self._radiance_flat = self.cube.reshape(-1, 3)
        omega = np.array(cube_solid_angles(n))
        energy = np.maximum(self.cube @ LUMINANCE_RGB, 0.0) * omega
        floor = omega / omega.sum()
        total = energy.sum()
        prob = floor if total <= 0 else (1.0 - uniform_share) * energy / total + uniform_share * floor
        prob /= prob.sum()
        prob.setflags(write=False)
        self.texel_prob = prob  # (6, F, F), sums to 1
        self._prob_flat = prob.reshape(-1)
        self._cdf = np.cumsum(self._prob_flat)
        self._cdf /= self._cdf[-1]
        # (F / 2)^2: the density per unit (u, v) area of a texel's square, whose side is 2 / F.
        self._uv_density = (n / 2.0) ** 2

    def integral(self) -> np.ndarray:
        """Exact integral of the piecewise-constant map over the sphere: float64 (3,), radiance * sr."""
        return (self.cube * np.asarray(cube_solid_angles(self.face_size))[..., None]).sum(axis=(0, 1, 2))

    def sample(self, n: int, rng: np.random.Generator,
               u_texel: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """n directions drawn from the distribution: (dirs float64 (n, 3) unit, pdf float64 (n,) per sr).

        u_texel: optional uniform numbers in [0, 1) (n,) that choose the texels (through the CDF), e.g.
        stratified ones; by default they come from rng like the rest.
        """
        f = self.face_size
        xi = rng.random((n, 3))
        if u_texel is not None:
            xi[:, 0] = u_texel
        texel = np.minimum(np.searchsorted(self._cdf, xi[:, 0], side="right"), self._cdf.size - 1)
        face, rem = np.divmod(texel, f * f)
        row, col = np.divmod(rem, f)
        u = (col + xi[:, 1]) * (2.0 / f) - 1.0
        v = (row + xi[:, 2]) * (2.0 / f) - 1.0
        d = face_uv_to_dir(face, u, v)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        pdf = self._prob_flat[texel] * self._uv_density * (1.0 + u * u + v * v) ** 1.5
        return d, pdf

    def texel_index(self, dirs: np.ndarray) -> np.ndarray:
        """Flat index (face * F + row) * F + col of the texel containing each direction (..., 3)."""
        f = self.face_size
        face, row, col = dir_to_texel(dirs, f)
        return (face * f + row) * f + col

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """L(w): the radiance of the texel containing each direction (..., 3) -> float64 (..., 3)."""
        return self._radiance_flat[self.texel_index(dirs)]

    def pdf(self, dirs: np.ndarray) -> np.ndarray:
        """Solid-angle density of `sample` at unit directions (..., 3) -> float64 (...)."""
        return self.radiance_pdf(dirs)[1]

    def radiance_pdf(self, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(radiance(dirs) float64 (..., 3), pdf(dirs) float64 (...)) with one texel lookup."""
        texel = self.texel_index(dirs)
        _, u, v = dir_to_face_uv(dirs)
        return self._radiance_flat[texel], self._prob_flat[texel] * self._uv_density * (1.0 + u * u + v * v) ** 1.5
