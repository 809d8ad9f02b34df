"""A U3M fabric on a garment: its textures at their physical size, through the renderer's
physically based material (`material_from_u3m`).

Physical size. A U3M image covers `width_mm` x `height_mm` of fabric; a garment's UVs are in whatever
unit its pattern tool wrote. The metres a unit of u (and of v) spans are measured on the mesh itself
(`uv_metres`): each triangle's gradient of position along u and along v (the 3 x 2 Jacobian of its
UV-to-surface map), their lengths' medians weighted by the triangles' areas, so that a few
degenerate UV triangles do not move them; or given (`uv_scale`). A texture is then placed by the
affine map (TextureSet.placement) uv -> diag(1 / W, 1 / H) R(-rotation) diag(su, sv) uv: a 5 cm check
is 5 cm on the garment whatever the UV layout, turned by the image's rotation (degrees, counter-
clockwise on the fabric). A mirrored repeat is the image beside its mirror image, one tile twice as
wide (or tall): a sampler's plain wrap then mirrors every other repeat. Tangent frames for the normal
map follow each map's own UVs (gbuffer.frag, and the reference's same frame from the triangle's edges).

The fields, onto glTF's metallic-roughness model with KHR_materials_sheen (`shading/brdf.py`):
basecolor (texture or constant, linear) is the base colour; metalness and roughness the metallic-
roughness map's two channels (textures of one size and rotation, or a texture and a constant); the
normal map as a tangent-space map, its U3M scale applied; sheen_value s and sheen_tint t the sheen
colour s ((1 - t) white + t tint), the tint the base colour's hue at unit luminance (the mean colour of
a texture), with a sheen roughness of SHEEN_ROUGHNESS (U3M names none); anisotropy_value and
anisotropy_rotation GGX's anisotropy and its direction (Material.anisotropy: turns from the UVs' u, as
U3M 1.1 measures them); alpha (a constant, or a texture at its size: TextureSet.alpha_map) and
transmission the sheet's (Material.alpha, .transmission: the outside visualisation's, for both sides).
What the model does not carry yet (a textured transmission, clearcoat, displacement, subsurface, a
specular level other than glTF's 4 %, a textured sheen or anisotropy, the cut edge's visualisation) is
named in the warnings that come with the material, never dropped silently. Front and back: the front's visualisation on the side the
mesh's winding faces (its normals' side), the back's behind it (Material.back, chosen per pixel by
the side the camera sees), the front's on both where the back is null.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import MaterialError
from ..mesh import Mesh
from ..shading.material import Material, TextureSet
from .material import (
    ColorTexture,
    Face,
    NormalConstant,
    NormalTexture,
    ScalarConstant,
    ScalarTexture,
    Texture,
    U3MMaterial,
    Visualisation,
)

SHEEN_ROUGHNESS = 0.5
# glTF's dielectric reflectance at normal incidence (4 %) is U3M's specular_value 0.5 ([0, 1] for 0-8 %).
GLTF_SPECULAR_VALUE = 0.5
# Triangles whose UV area is below this share of the mesh's mean do not judge the UVs' scale.
_DEGENERATE_UV_SHARE = 1e-6


def uv_metres(mesh: Mesh) -> tuple[float, float]:
    """Metres of surface a unit of u and a unit of v span on `mesh` (module doc); MaterialError for a
    mesh without UVs or whose UVs cover no area."""
    if mesh.uvs is None:
        raise MaterialError(f"mesh {mesh.name!r} has no UVs: a fabric's textures need them (give the mesh UVs, "
                            "or a material without textures)")
    p = np.asarray(mesh.positions, np.float64)[mesh.faces]
    t = np.asarray(mesh.uvs, np.float64)[mesh.faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    area3 = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    ok = (np.abs(det) > _DEGENERATE_UV_SHARE * max(float(np.mean(np.abs(det))), 1e-300)) & (area3 > 0)
    if not ok.any():
        raise MaterialError(f"mesh {mesh.name!r}: its UVs cover no area (every triangle's UVs are on a line); a "
                            "fabric's textures cannot be placed on it")
    inv = 1.0 / det[ok]
    # The Jacobian's columns: dP/du = (e1 d2.y - e2 d1.y) / det, dP/dv = (e2 d1.x - e1 d2.x) / det.
    dpdu = (e1[ok] * d2[ok, 1:2] - e2[ok] * d1[ok, 1:2]) * inv[:, None]
    dpdv = (e2[ok] * d1[ok, 0:1] - e1[ok] * d2[ok, 0:1]) * inv[:, None]
    w = area3[ok]
    return _weighted_median(np.linalg.norm(dpdu, axis=1), w), _weighted_median(np.linalg.norm(dpdv, axis=1), w)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def placement(texture: Texture, uv_scale: tuple[float, float]) -> np.ndarray:
    """The (2, 3) affine map from the mesh's UVs to `texture`'s (module doc), for the image as
    `tiled` lays it out (a mirrored repeat's tile twice as wide or tall)."""
    if not (texture.width_mm > 0 and texture.height_mm > 0):
        raise MaterialError(f"texture {texture.path!r} has no physical size ({texture.width_mm} x "
                            f"{texture.height_mm} mm)")
    w_m = texture.width_mm / 1000.0 * (2 if texture.repeat.mirror_x else 1)
    h_m = texture.height_mm / 1000.0 * (2 if texture.repeat.mirror_y else 1)
    a = math.radians(texture.rotation_deg)
    turn = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])   # R(-rotation)
    linear = np.diag([1.0 / w_m, 1.0 / h_m]) @ turn @ np.diag(uv_scale)
    return np.hstack([linear, np.zeros((2, 1))])


def tiled(texture: Texture, image: np.ndarray) -> np.ndarray:
    """`image` (H, W, C) as one tile of the texture's repeat: beside its mirror image where the repeat
    mirrors in x, above its mirror image where it mirrors in y."""
    if texture.repeat.mirror_x:
        image = np.concatenate([image, image[:, ::-1]], axis=1)
    if texture.repeat.mirror_y:
        image = np.concatenate([image, image[::-1]], axis=0)
    return np.ascontiguousarray(image)


def _same_layout(a: Texture, b: Texture) -> bool:
    return (a.image.shape[:2] == b.image.shape[:2] and a.width_mm == b.width_mm and a.height_mm == b.height_mm
            and a.rotation_deg == b.rotation_deg and a.repeat == b.repeat)


def _scalar(field) -> float | None:
    return float(field.value) if isinstance(field, ScalarConstant) else None


def material_from_u3m(u3m: U3MMaterial, mesh: Mesh, face: Face | str = Face.FRONT,
                      uv_scale: tuple[float, float] | None = None) -> tuple[Material, list[str]]:
    """The renderer's Material for `mesh` in `u3m` (module doc): the visualisation of `face` on the
    side the mesh's winding faces and, where the document has its own, the other one's behind it
    (Material.back: the front's visualisation is the back's too when the back is null, as the spec
    says), each texture at its physical size; and what it does not carry, one line each."""
    face = Face(face)
    scale = uv_scale if uv_scale is not None else uv_metres(mesh)
    if not all(np.isfinite(scale)) or min(scale) <= 0:
        raise MaterialError(f"{u3m.file}: the UV scale must be positive metres a UV unit, got {scale}")
    other = Face.BACK if face is not Face.BACK else Face.FRONT
    warnings = _not_carried(u3m, u3m.visualisation(face), face)
    outside = _side_material(u3m, face, mesh, scale, warnings)
    if getattr(u3m, other.value) is None:
        return outside, warnings
    for line in _not_carried(u3m, u3m.visualisation(other), other, others=False):
        warnings.append(f"{other.value}: {line}")
    return replace(outside, back=_side_material(u3m, other, mesh, scale, warnings)), warnings


def _side_material(u3m: U3MMaterial, face: Face, mesh: Mesh, scale: tuple[float, float],
                   warnings: list[str]) -> Material:
    """One side's Material: the visualisation of `face` (module doc)."""
    vis: Visualisation = u3m.visualisation(face)
    where = f"{u3m.file}: {face.value}"

    sets: dict = {}
    albedo = (1.0, 1.0, 1.0)
    if isinstance(vis.basecolor, ColorTexture):
        colour = np.clip(vis.basecolor.values(), 0.0, 1.0)
        sets["albedo_map"] = tiled(vis.basecolor, colour)
        sets["albedo_placement"] = placement(vis.basecolor, scale)
        mean_colour = colour.reshape(-1, 3).mean(axis=0)
    else:
        albedo = tuple(float(c) for c in np.clip(vis.basecolor.rgb, 0.0, 1.0))
        mean_colour = np.asarray(albedo)

    metallic, roughness = _scalar(vis.metalness), _scalar(vis.roughness)
    textures = [f for f in (vis.metalness, vis.roughness) if isinstance(f, ScalarTexture)]
    if textures:
        if len(textures) == 2 and not _same_layout(*textures):
            raise MaterialError(f"{where}: metalness and roughness are textures of different sizes, rotations or "
                                "repeats; the renderer reads them as one metallic-roughness map (give them one layout)")
        ref = textures[0]
        h, w = ref.image.shape[:2]

        def channel(field) -> np.ndarray:
            if isinstance(field, ScalarTexture):
                return np.clip(field.values(), 0.0, 1.0)
            return np.full((h, w), np.clip(field.value, 0.0, 1.0), np.float32)

        sets["metallic_roughness_map"] = tiled(ref, np.stack([channel(vis.metalness), channel(vis.roughness)], -1))
        sets["second_placement"] = placement(ref, scale)
        metallic = roughness = 1.0   # the map multiplies them

    if isinstance(vis.normal, NormalTexture):
        sets["normal_map"] = tiled(vis.normal, np.clip(vis.normal.values() * 0.5 + 0.5, 0.0, 1.0))
        sets["normal_placement"] = placement(vis.normal, scale)
    elif isinstance(vis.normal, NormalConstant) and not np.allclose(vis.normal.xyz, (0.0, 0.0, 1.0)):
        warnings.append(f"normal: a constant normal {vis.normal.xyz} that is not (0, 0, 1) is not carried")

    sheen_colour = (0.0, 0.0, 0.0)
    s, tint = _constants(vis, ("sheen_value", "sheen_tint"), warnings)
    if s > 0:
        lum = float(np.dot(mean_colour, (0.2126, 0.7152, 0.0722)))
        hue = mean_colour / lum if lum > 1e-6 else np.ones(3)
        sheen_colour = tuple(float(c) for c in np.clip(s * ((1.0 - tint) + tint * hue), 0.0, 1.0))

    anisotropy, rotation = _constants(vis, ("anisotropy_value", "anisotropy_rotation"), warnings)
    alpha = 1.0
    if isinstance(vis.alpha, ScalarTexture):   # a lace's holes: the map, at its size, multiplies alpha
        sets["alpha_map"] = tiled(vis.alpha, np.clip(vis.alpha.values(), 0.0, 1.0)[..., None])
        sets["alpha_placement"] = placement(vis.alpha, scale)
    else:
        alpha = float(vis.alpha.value)
    transmission = _constants(vis, ("transmission",), warnings)[0]
    if anisotropy > 1.0:
        warnings.append(f"anisotropy_value: {anisotropy:g} is beyond the renderer's 1 (the most stretched "
                        "highlight); 1 is used")
    return Material(albedo, model="pbr", metallic=float(np.clip(metallic, 0, 1)),
                    roughness=float(np.clip(roughness, 0, 1)), sheen_colour=sheen_colour,
                    sheen_roughness=SHEEN_ROUGHNESS, anisotropy=float(np.clip(anisotropy, 0.0, 1.0)),
                    anisotropy_rotation=float(rotation), alpha=float(np.clip(alpha, 0.0, 1.0)),
                    transmission=float(np.clip(transmission, 0.0, 1.0)), texture_sets=(TextureSet(**sets),),
                    texture_set=np.zeros(mesh.n_vertices, np.int32))


def _constants(vis: Visualisation, names: tuple[str, ...], warnings: list[str]) -> list[float]:
    """Scalar fields the material carries as constants only: a texture's mean, said in `warnings`."""
    values = [_scalar(getattr(vis, name)) for name in names]
    if any(v is None for v in values):
        warnings.append(f"{' / '.join(names)}: textures are not carried; their mean is used")
    return [float(np.mean(getattr(vis, name).values())) if v is None else v for name, v in zip(names, values)]


def _not_carried(u3m: U3MMaterial, vis: Visualisation, face, others: bool = True) -> list[str]:
    """The fields of `vis` (and, with `others`, the cut edge's visualisation) the renderer's material
    does not carry yet."""
    out = []

    def off(name: str, default: float) -> bool:
        field = getattr(vis, name)
        return not isinstance(field, ScalarConstant) or abs(field.value - default) > 1e-6

    for name, default, what in (("clearcoat_value", 0.0, "no clear coat"),
                                ("subsurface_value", 0.0, "no subsurface scattering"),
                                ("specular_value", GLTF_SPECULAR_VALUE, "glTF's 4 % reflectance is used")):
        if off(name, default):
            out.append(f"{name}: not carried yet ({what})")
    if isinstance(vis.displacement, ScalarTexture):
        out.append("displacement: not carried (the surface is the mesh's)")
    if others and u3m.side is not None:
        out.append("side: the cut edge's visualisation is not drawn (a garment's mesh is a sheet, without one)")
    return out
