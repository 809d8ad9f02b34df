"""Nine-coefficient spherical-harmonic irradiance (Ramamoorthi and Hanrahan 2001, "An efficient
representation for irradiance environment maps"; lecture seed 002).

The radiance of a set of regions is projected onto the real spherical harmonics of order <= 2,
L_lm = sum over texels of L(w) Y_lm(w) dw (exact texel solid angles), and the irradiance of a normal n
is E(n) = sum A_l L_lm Y_lm(n) with A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4: the clamped cosine's own
coefficients. Order 2 keeps the cosine lobe to within a few percent on smooth lighting and cannot hold
a sun; the renderer uses it only for the lights that get no shadow map (the dim ones), where it
replaces one PEM lookup per light and pixel by nine multiply-adds per pixel.
"""

from __future__ import annotations

import numpy as np

from ..envmap.cube import cube_solid_angles, texel_directions

# Cosine-lobe convolution factors per band.
A_BAND = np.array([np.pi, 2.0 * np.pi / 3.0, 2.0 * np.pi / 3.0, 2.0 * np.pi / 3.0,
                   np.pi / 4.0, np.pi / 4.0, np.pi / 4.0, np.pi / 4.0, np.pi / 4.0])


def sh_basis(d: np.ndarray) -> np.ndarray:
    """Real SH basis Y_lm of unit directions d (..., 3) -> (..., 9), order (0,0), (1,-1), (1,0), (1,1),
    (2,-2), (2,-1), (2,0), (2,1), (2,2); shaders/shading/lighting.frag evaluates the same."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([
        np.full_like(x, 0.282095),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0), 1.092548 * x * z,
        0.546274 * (x * x - y * y),
    ], axis=-1)


def region_sh(cube: np.ndarray, labels: np.ndarray, n_regions: int) -> np.ndarray:
    """Radiance SH coefficients of every region: float64 (N, 9, 3). cube (6, F, F, 3), labels (6, F, F)."""
    n = cube.shape[1]
    weights = (sh_basis(texel_directions(n)) * cube_solid_angles(n)[..., None]).reshape(-1, 9)  # (T, 9)
    rgb = np.asarray(cube[..., :3], np.float64).reshape(-1, 3)
    flat = labels.reshape(-1)
    out = np.empty((n_regions, 9, 3))
    for k in range(9):
        for c in range(3):
            out[:, k, c] = np.bincount(flat, weights=weights[:, k] * rgb[:, c], minlength=n_regions)
    return out


def irradiance_coefficients(radiance_sh: np.ndarray) -> np.ndarray:
    """(9, 3) radiance coefficients -> (9, 3) coefficients c with E(n) = sum c_lm Y_lm(n)."""
    return radiance_sh * A_BAND[:, None]


def irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """E(n) for unit normals (..., 3) from irradiance coefficients (9, 3): (..., 3)."""
    return sh_basis(normals) @ coeffs
