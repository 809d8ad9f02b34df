"""Materials: a diffuse part and one glossy lobe (Knuth et al. 2014, sec. 3.2), per vertex or from
texture maps, because woven and knitted fabrics mix yarns of different sheen."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError


def _finite(name: str, a: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"material {name} has NaN or Inf values")
    if np.any(a < lo) or np.any(a > hi):
        raise InvalidInputError(f"material {name} must lie in [{lo}, {hi}], got range [{a.min()}, {a.max()}]")
    return a


@dataclass(frozen=True)
class Material:
    """albedo: diffuse reflectance, linear RGB, (3,) or per vertex (V, 3), in [0, 1].
    specular: weight of the glossy lobe, scalar or (V,), >= 0.
    glossiness: the paper's g in [0, 1] (0 diffuse lobe, 1 mirror), scalar or (V,).
    albedo_map: optional (H, W, 3) linear RGB texture that multiplies albedo (needs mesh UVs).
    gloss_map: optional (H, W, 2) texture of (specular, glossiness) that replaces the two values.
    """

    albedo: tuple | np.ndarray = (0.8, 0.8, 0.8)
    specular: float | np.ndarray = 0.0
    glossiness: float | np.ndarray = 0.5
    albedo_map: np.ndarray | None = None
    gloss_map: np.ndarray | None = None

    def has_glossy_lobe(self) -> bool:
        """Whether any fragment can have a specular weight above 0 (from the values or the gloss map)."""
        if self.gloss_map is not None:
            return bool((np.asarray(self.gloss_map, np.float64)[..., 0] > 0).any())
        return bool((np.asarray(self.specular, np.float64) > 0).any())

    def max_glossiness(self) -> float:
        """The glossiest lookup this material can make (0 when it has no glossy lobe anywhere): what
        decides the finest PEM level a scene needs. Specular and glossiness are interpolated (between
        vertices, between texels), so a fragment can pair any g with a nonzero specular weight: the
        maximum is over all of g as soon as any specular weight is positive."""
        if not self.has_glossy_lobe():
            return 0.0
        if self.gloss_map is not None:
            return float(np.asarray(self.gloss_map, np.float64)[..., 1].max())
        return float(np.max(np.asarray(self.glossiness, np.float64)))

    def vertex_arrays(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """(albedo (V, 3), material (V, 2) = (specular, glossiness)) float32, validated."""
        albedo = np.asarray(self.albedo, np.float32)
        if albedo.shape == (3,):
            albedo = np.broadcast_to(albedo, (n_vertices, 3))
        if albedo.shape != (n_vertices, 3):
            raise InvalidInputError(f"albedo must have shape (3,) or ({n_vertices}, 3), got {albedo.shape}")
        _finite("albedo", albedo, 0.0, 1.0)
        out = np.empty((n_vertices, 2), np.float32)
        for k, (name, value, hi) in enumerate((("specular", self.specular, 1e3), ("glossiness", self.glossiness, 1.0))):
            v = np.asarray(value, np.float32)
            if v.ndim == 0:
                v = np.broadcast_to(v, (n_vertices,))
            if v.shape != (n_vertices,):
                raise InvalidInputError(f"{name} must be a scalar or have shape ({n_vertices},), got {v.shape}")
            out[:, k] = _finite(name, v, 0.0, hi)
        return np.ascontiguousarray(albedo), out

    def maps(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        am, gm = self.albedo_map, self.gloss_map
        if am is not None:
            am = np.asarray(am, np.float32)
            if am.ndim != 3 or am.shape[2] != 3:
                raise InvalidInputError(f"albedo_map must be (H, W, 3), got {am.shape}")
            _finite("albedo_map", am, 0.0, 1.0)
        if gm is not None:
            gm = np.asarray(gm, np.float32)
            if gm.ndim != 3 or gm.shape[2] != 2:
                raise InvalidInputError(f"gloss_map must be (H, W, 2) = (specular, glossiness), got {gm.shape}")
            _finite("gloss_map", gm, 0.0, 1.0)
        return am, gm
