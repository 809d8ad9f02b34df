"""The exact BRDFs of the fabrics the renderer models, in numpy: written once, used by the lobe fit,
the Monte Carlo reference and the tests (issue: fabric as fabric).

Every function takes unit vectors n (the shading normal), v (towards the viewer) and lt (l in the
formulas: towards the light), arrays (..., 3) that broadcast, and returns the *cosine-weighted* reflectance
f(v, l) * max(n.l, 0), the density that is integrated against the incident radiance:
L_o(v) = integral of L(l) f(v, l) (n.l) dl. Below either horizon (n.v <= 0 or n.l <= 0) it is 0.
Colours are linear RGB, the result (..., 3).

- `lambert`: base / pi.
- `phong`: the renderer's glossy lobe, (s + 1) / (2 pi) max(r.l, 0)^s about the mirror direction r
  (the paper's Eq. 3: already a density over the sphere, so it is *not* multiplied by n.l again; its
  integral over the sphere is 1), scaled by the specular weight.
- `ggx`: the glTF 2.0 metallic-roughness model (the specification's appendix B): a Trowbridge-Reitz
  (GGX) microfacet specular term D * V * F with the height-correlated Smith visibility, alpha =
  roughness^2, Schlick's Fresnel from F0 = mix(0.04, base, metallic), over a Lambert diffuse of
  (1 - F) (1 - metallic) base / pi. That split is glTF's, mixing by F(v.h) per direction: a white
  dielectric reflects at most 1 head-on, but up to 1.45 at an 85 degree view (roughness 0.2), where
  the specular albedo grows while the diffuse keeps (1 - F) of nearly every direction.
  With an anisotropy a in [0, 1] and a unit tangent t (the direction the highlight stretches along), D
  and the Smith terms are the anisotropic GGX's (Heitz 2014, Eqs. 80 and 86) with alpha_t = alpha /
  k and alpha_b = alpha k, k = sqrt(1 - 0.9 a) (Burley 2012's aspect, Autodesk Standard Surface's and
  U3M's reading of a satin's anisotropy): their product stays alpha^2, a = 0 is the isotropic model.
- `sheen`: the "Charlie" sheen of KHR_materials_sheen (Estevez and Kulla, "Production Friendly
  Microfacet Sheen BRDF", 2017): D = (2 + 1/a) sin(theta_h)^(1/a) / (2 pi), a = sheen roughness^2,
  with Neubelt and Pettineo's visibility 1 / (4 (n.l + n.v - n.l n.v)) ("Crafting a Next-Gen Material
  Pipeline for The Order: 1886", 2013) in place of Estevez and Kulla's fitted one: both peak where the
  fabric is seen or lit at grazing angles, the reason velvet looks like velvet.
"""

from __future__ import annotations

import numpy as np

# A roughness is clamped here, so that alpha = roughness^2 stays a normal float and D finite.
MIN_ROUGHNESS = 1e-3
# glTF's reflectance of a dielectric at normal incidence (an index of refraction of 1.5).
DIELECTRIC_F0 = 0.04


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _cosines(n, v, lt):
    n, v, lt = (np.asarray(x, np.float64) for x in (n, v, lt))
    return n, v, lt, _dot(n, v), _dot(n, lt)


def _rgb(c) -> np.ndarray:
    return np.broadcast_to(np.asarray(c, np.float64), (3,)) if np.ndim(c) == 0 else np.asarray(c, np.float64)


def half_vector(v: np.ndarray, lt: np.ndarray) -> np.ndarray:
    """The unit half vector of v and l (..., 3)."""
    h = v + lt
    return h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)


def lambert(n, v, lt, base) -> np.ndarray:
    """base / pi * n.l (..., 3)."""
    _, _, _, nv, nl = _cosines(n, v, lt)
    w = np.where((nv > 0) & (nl > 0), nl / np.pi, 0.0)
    return w[..., None] * _rgb(base)


def phong(n, v, lt, specular, exponent) -> np.ndarray:
    """The renderer's lobe: specular (s + 1) / (2 pi) max(r.l, 0)^s, r the mirror of v about n (..., 3)."""
    n, v, lt, nv, nl = _cosines(n, v, lt)
    r = 2.0 * nv[..., None] * n - v
    s = np.asarray(exponent, np.float64)
    rl = np.clip(_dot(r, lt), 0.0, 1.0)
    with np.errstate(under="ignore"):
        lobe = (s + 1.0) / (2.0 * np.pi) * rl ** s
    w = np.where((nv > 0) & (nl > 0), lobe, 0.0)
    return (w * np.asarray(specular, np.float64))[..., None] * np.ones(3)


def ggx_distribution(n_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Trowbridge-Reitz D(h) = a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2); integrates (with n.h) to 1."""
    a2 = alpha * alpha
    d = n_h * n_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * d * d)


def smith_visibility(n_v: np.ndarray, n_l: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Height-correlated Smith G2 / (4 n.v n.l) for GGX (Heitz 2014, Eq. 99; glTF's V_GGX)."""
    a2 = alpha * alpha
    gv = n_l * np.sqrt(n_v * n_v * (1.0 - a2) + a2)
    gl = n_v * np.sqrt(n_l * n_l * (1.0 - a2) + a2)
    return 0.5 / np.maximum(gv + gl, 1e-300)


def anisotropic_alphas(roughness, anisotropy) -> tuple[np.ndarray, np.ndarray]:
    """(alpha_t, alpha_b): GGX's widths along the anisotropy's direction and across it (module doc)."""
    alpha = np.maximum(np.asarray(roughness, np.float64), MIN_ROUGHNESS) ** 2
    k = np.sqrt(1.0 - 0.9 * np.clip(np.asarray(anisotropy, np.float64), 0.0, 1.0))
    return alpha / k, alpha * k


def tangent_frame(n: np.ndarray, tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, b): `tangent` made unit and perpendicular to n, and b = n x t (..., 3)."""
    t = tangent - _dot(tangent, n)[..., None] * n
    t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-300)
    return t, np.cross(n, t)


def ggx_distribution_anisotropic(h_t, h_b, h_n, alpha_t, alpha_b) -> np.ndarray:
    """D(h) = 1 / (pi a_t a_b ((h.t / a_t)^2 + (h.b / a_b)^2 + (h.n)^2)^2); integrates (with n.h) to 1."""
    d = (h_t / alpha_t) ** 2 + (h_b / alpha_b) ** 2 + h_n * h_n
    return 1.0 / (np.pi * alpha_t * alpha_b * d * d)


def smith_lambda_anisotropic(w_t, w_b, w_n, alpha_t, alpha_b) -> np.ndarray:
    """Smith's Lambda of a direction with n.w = w_n > 0: (sqrt(1 + (a_t^2 w_t^2 + a_b^2 w_b^2) / w_n^2) - 1) / 2."""
    return 0.5 * (np.sqrt(1.0 + ((alpha_t * w_t) ** 2 + (alpha_b * w_b) ** 2) / np.maximum(w_n * w_n, 1e-300)) - 1.0)


def schlick(f0: np.ndarray, v_h: np.ndarray) -> np.ndarray:
    """F = F0 + (1 - F0) (1 - v.h)^5 (..., 3)."""
    return f0 + (1.0 - f0) * (1.0 - np.clip(v_h, 0.0, 1.0))[..., None] ** 5


def ggx(n, v, lt, base, metallic, roughness, tangent=None, anisotropy=None) -> np.ndarray:
    """glTF metallic-roughness: (1 - F)(1 - metallic) base / pi + F D V, times n.l (..., 3); with a
    `tangent` (..., 3) and an `anisotropy`, the anisotropic GGX (module doc)."""
    n, v, lt, nv, nl = _cosines(n, v, lt)
    base = _rgb(base)
    metallic = np.asarray(metallic, np.float64)
    alpha = np.maximum(np.asarray(roughness, np.float64), MIN_ROUGHNESS) ** 2
    h = half_vector(v, lt)
    nh, vh = np.clip(_dot(n, h), 0.0, 1.0), _dot(v, h)
    f0 = DIELECTRIC_F0 * (1.0 - metallic)[..., None] + base * metallic[..., None]
    f = schlick(f0, vh)
    up = (nv > 0) & (nl > 0)
    cv, cl = np.where(up, nv, 1.0), np.where(up, nl, 1.0)
    if tangent is None:
        dv = ggx_distribution(nh, alpha) * smith_visibility(cv, cl, alpha)
    else:
        at, ab = anisotropic_alphas(roughness, anisotropy)
        t, b = tangent_frame(n, np.asarray(tangent, np.float64))
        lam_v = smith_lambda_anisotropic(_dot(v, t), _dot(v, b), cv, at, ab)
        lam_l = smith_lambda_anisotropic(_dot(lt, t), _dot(lt, b), cl, at, ab)
        dv = ggx_distribution_anisotropic(_dot(h, t), _dot(h, b), nh, at, ab) / (4.0 * cv * cl * (1.0 + lam_v + lam_l))
    specular = f * dv[..., None]
    diffuse = (1.0 - f) * ((1.0 - metallic)[..., None] * base / np.pi)
    return np.where(up[..., None], (specular + diffuse) * nl[..., None], 0.0)


def charlie_distribution(n_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Estevez and Kulla's D(h) = (2 + 1/a) sin(theta_h)^(1/a) / (2 pi)."""
    sin2 = np.clip(1.0 - n_h * n_h, 0.0, 1.0)
    inv = 1.0 / alpha
    with np.errstate(under="ignore"):
        return (2.0 + inv) * sin2 ** (0.5 * inv) / (2.0 * np.pi)


def sheen(n, v, lt, colour, roughness) -> np.ndarray:
    """KHR_materials_sheen's layer: colour D_charlie V_neubelt, times n.l (..., 3)."""
    n, v, lt, nv, nl = _cosines(n, v, lt)
    alpha = np.maximum(np.asarray(roughness, np.float64), MIN_ROUGHNESS) ** 2
    nh = np.clip(_dot(n, half_vector(v, lt)), 0.0, 1.0)
    up = (nv > 0) & (nl > 0)
    cv, cl = np.where(up, nv, 1.0), np.where(up, nl, 1.0)
    vis = 1.0 / (4.0 * (cl + cv - cl * cv))
    w = np.where(up, charlie_distribution(nh, alpha) * vis * nl, 0.0)
    return w[..., None] * _rgb(colour)


def pbr(n, v, lt, base, metallic, roughness, sheen_colour, sheen_roughness, sheen_albedo, tangent=None,
        anisotropy=None) -> np.ndarray:
    """A glTF material with KHR_materials_sheen: the Charlie layer over the metallic-roughness model,
    which the extension scales by 1 - max(sheen colour) E(n.v) (E, `sheen_albedo`: the layer's
    directional albedo with colour 1 at this view, from renderer/lighting/material_lobes.py), times
    n.l (..., 3). `tangent` and `anisotropy`: the GGX layer's (`ggx`)."""
    sheen_colour = np.asarray(sheen_colour, np.float64)
    strength = sheen_colour if sheen_colour.ndim == 0 else sheen_colour.max(axis=-1)
    below = 1.0 - strength * np.asarray(sheen_albedo, np.float64)
    return sheen(n, v, lt, sheen_colour, sheen_roughness) + np.asarray(below)[..., None] * ggx(
        n, v, lt, base, metallic, roughness, tangent, anisotropy)


def smith_g1(n_v: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """GGX's Smith masking of one direction, 2 n.v / (n.v + sqrt(a^2 + (1 - a^2) (n.v)^2))."""
    a2 = alpha * alpha
    return 2.0 * n_v / np.maximum(n_v + np.sqrt(a2 + (1.0 - a2) * n_v * n_v), 1e-300)


def sample_ggx_visible_normals(v_local: np.ndarray, alpha: np.ndarray, u1: np.ndarray,
                               u2: np.ndarray, alpha_y: np.ndarray | None = None) -> np.ndarray:
    """Heitz's sampling of GGX's distribution of visible normals ("Sampling the GGX Distribution of
    Visible Normals", JCGT 2018), in the frame whose z is the normal: v_local (M, 3) with z > 0,
    uniform u1, u2 (M,); returns the microfacet normals h (M, 3), whose density is
    D_v(h) = G1(v) max(v.h, 0) D(h) / n.v. With `alpha_y`, the anisotropic GGX of widths alpha along
    x and alpha_y along y."""
    a = alpha[:, None]
    ay = a if alpha_y is None else alpha_y[:, None]
    vh = v_local * np.concatenate([a, ay, np.ones_like(a)], axis=1)
    vh /= np.linalg.norm(vh, axis=1, keepdims=True)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    safe = np.where(lensq > 0, lensq, 1.0)
    t1 = np.where((lensq > 0)[:, None], np.stack([-vh[:, 1], vh[:, 0], np.zeros(len(vh))], 1) / np.sqrt(safe)[:, None],
                  np.array([1.0, 0.0, 0.0]))
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    nh = p1[:, None] * t1 + p2[:, None] * t2 + np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))[:, None] * vh
    h = nh * np.concatenate([a, ay, np.ones_like(a)], axis=1)
    h[:, 2] = np.maximum(h[:, 2], 1e-12)
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def ggx_reflection_pdf(n_v: np.ndarray, n_h: np.ndarray, v_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The density over l = reflect(-v, h) of h drawn by `sample_ggx_visible_normals`:
    D_v(h) / (4 v.h) = G1(v) D(h) / (4 n.v)."""
    ok = (n_v > 0) & (v_h > 0)
    return np.where(ok, smith_g1(np.where(ok, n_v, 1.0), alpha) * ggx_distribution(n_h, alpha)
                    / (4.0 * np.where(ok, n_v, 1.0)), 0.0)


def ggx_reflection_pdf_anisotropic(v_local: np.ndarray, h_local: np.ndarray, alpha_t: np.ndarray,
                                   alpha_b: np.ndarray) -> np.ndarray:
    """`ggx_reflection_pdf` of the anisotropic GGX, v and h in the frame (t, b, n) (M, 3):
    G1(v) D(h) / (4 n.v), G1 = 1 / (1 + Lambda(v))."""
    nv, vh = v_local[:, 2], np.sum(v_local * h_local, axis=1)
    ok = (nv > 0) & (vh > 0) & (h_local[:, 2] > 0)
    cv = np.where(ok, nv, 1.0)
    g1 = 1.0 / (1.0 + smith_lambda_anisotropic(v_local[:, 0], v_local[:, 1], cv, alpha_t, alpha_b))
    d = ggx_distribution_anisotropic(h_local[:, 0], h_local[:, 1], h_local[:, 2], alpha_t, alpha_b)
    return np.where(ok, g1 * d / (4.0 * cv), 0.0)
