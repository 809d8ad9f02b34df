"""Materials: a diffuse part and one glossy lobe (Knuth et al. 2014, sec. 3.2), per vertex or from
texture maps, because woven and knitted fabrics mix yarns of different sheen; or glTF's metallic-
roughness model under a Charlie sheen layer (model "pbr": renderer/shading/brdf.py, shaded through
Kautz and McCool's fitted lobes, renderer/lighting/material_lobes.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidInputError
from . import fields


def _finite(name: str, a: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"material {name} has NaN or Inf values")
    if np.any(a < lo) or np.any(a > hi):
        raise InvalidInputError(f"material {name} must lie in [{lo}, {hi}], got range [{a.min()}, {a.max()}]")
    return a


MODELS = fields.MODELS


def _per_vertex(name: str, value, n_vertices: int, hi: float = 1.0) -> np.ndarray:
    v = np.asarray(value, np.float32)
    if v.ndim == 0:
        v = np.broadcast_to(v, (n_vertices,))
    if v.shape != (n_vertices,):
        raise InvalidInputError(f"{name} must be a scalar or have shape ({n_vertices},), got {v.shape}")
    return _finite(name, v, 0.0, hi)


def _per_vertex_rgb(name: str, value, n_vertices: int) -> np.ndarray:
    """A colour (3,) or per vertex (V, 3) in [0, 1], as float32 (V, 3)."""
    rgb = np.asarray(value, np.float32)
    if rgb.shape == (3,):
        rgb = np.broadcast_to(rgb, (n_vertices, 3))
    if rgb.shape != (n_vertices, 3):
        raise InvalidInputError(f"{name} must have shape (3,) or ({n_vertices}, 3), got {rgb.shape}")
    return np.ascontiguousarray(_finite(name, rgb, 0.0, 1.0))


def _texture(name: str, value, channels: int, meaning: str = "") -> np.ndarray | None:
    """A texture (H, W, channels) in [0, 1] as float32, validated; None stays None."""
    if value is None:
        return None
    tex = np.asarray(value, np.float32)
    if tex.ndim != 3 or tex.shape[2] != channels:
        raise InvalidInputError(f"{name} must be (H, W, {channels}){meaning}, got {tex.shape}")
    return _finite(name, tex, 0.0, 1.0)


# A texture's placement: the affine map from a mesh's UVs to the texture's own (2, 3): texture uv =
# A[:, :2] @ uv + A[:, 2], repeating; the identity reads the texture once over the UV square.
IDENTITY_PLACEMENT = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# The maps of a set, each with its placement (TextureSet.placement): the second is the gloss or the
# metallic-roughness map.
MAP_NAMES = ("albedo", "second", "normal", "sheen", "alpha")


def _placement(name: str, value) -> np.ndarray:
    if value is None:
        return IDENTITY_PLACEMENT.copy()
    a = np.asarray(value, np.float64)
    if a.shape != (2, 3) or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name}_placement must be a finite (2, 3) affine map of UVs, got {a.shape}")
    if abs(np.linalg.det(a[:, :2])) < 1e-12:
        raise InvalidInputError(f"{name}_placement maps the UV plane onto a line (its 2 x 2 part is singular)")
    return a


@dataclass(frozen=True, eq=False)
class TextureSet:
    """One set of a material's textures (the fields of Material of the same names): what the
    triangles of one part of a mesh read, where the parts of a garment use different textures (a
    shirt's fabric and its buttons, each material of a glTF file with its own images).

    albedo_placement, second_placement (the gloss or metallic-roughness map's), normal_placement,
    sheen_placement, alpha_placement: each map's affine map from the mesh's UVs to the texture's (2, 3),
    None for the identity; a fabric's textures each at their own physical size and rotation
    (renderer/u3m/place.py).
    alpha_map: optional (H, W, 1) texture in [0, 1] that multiplies the material's alpha (a lace's
    holes, a mesh fabric's open cells: U3M's alpha texture); read on the front's sets only (the sheet's
    alpha is its front's, Material.alpha)."""

    albedo_map: np.ndarray | None = None
    gloss_map: np.ndarray | None = None
    metallic_roughness_map: np.ndarray | None = None
    normal_map: np.ndarray | None = None
    normal_scale: float = 1.0
    sheen_map: np.ndarray | None = None
    albedo_placement: np.ndarray | None = None
    second_placement: np.ndarray | None = None
    normal_placement: np.ndarray | None = None
    sheen_placement: np.ndarray | None = None
    alpha_map: np.ndarray | None = None
    alpha_placement: np.ndarray | None = None

    def placement(self, name: str) -> np.ndarray:
        """The (2, 3) affine map of one of MAP_NAMES, validated (the identity when none is given)."""
        if name not in MAP_NAMES:
            raise ValueError(f"no map {name!r}: the maps are {', '.join(MAP_NAMES)}")
        return _placement(name, getattr(self, f"{name}_placement"))

    def check(self, model: str) -> None:
        if model == "pbr" and self.gloss_map is not None:
            raise InvalidInputError("a gloss_map (specular, glossiness) belongs to the phong model, not pbr")
        if model != "pbr" and self.metallic_roughness_map is not None:
            raise InvalidInputError("a metallic_roughness_map belongs to the pbr model, not phong")
        if model != "pbr" and self.sheen_map is not None:
            raise InvalidInputError("a sheen_map belongs to the pbr model, not phong")
        if not (np.isfinite(self.normal_scale) and 0.0 <= self.normal_scale <= 10.0):
            raise InvalidInputError(f"normal_scale must lie in [0, 10], got {self.normal_scale}")
        for name in MAP_NAMES:
            self.placement(name)

    def maps(self, is_pbr: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(albedo map, second map): the gloss map of a Phong material, the metallic-roughness map of
        a pbr one (both (H, W, 2) in [0, 1]), validated."""
        second = ("metallic_roughness_map", self.metallic_roughness_map, " = (metallic, roughness)") if is_pbr \
            else ("gloss_map", self.gloss_map, " = (specular, glossiness)")
        return _texture("albedo_map", self.albedo_map, 3), _texture(second[0], second[1], 2, second[2])

    def normal_texture(self) -> np.ndarray | None:
        """The normal map (H, W, 3) float32 in [0, 1], validated (None without one)."""
        return _texture("normal_map", self.normal_map, 3)

    def sheen_texture(self) -> np.ndarray | None:
        """The sheen map (H, W, 4) float32 in [0, 1] = (sheen colour, sheen roughness), validated."""
        return _texture("sheen_map", self.sheen_map, 4, " = (sheen colour rgb, sheen roughness)")

    def alpha_texture(self) -> np.ndarray | None:
        """The alpha map (H, W, 1) float32 in [0, 1], validated (None without one)."""
        return _texture("alpha_map", self.alpha_map, 1)

    def has_textures(self, is_pbr: bool) -> bool:
        return any(m is not None for m in (*self.maps(is_pbr), self.normal_texture(), self.sheen_texture(),
                                           self.alpha_texture()))


MAX_TEXTURE_SETS = 16   # one geometry-pass draw each: a garment's materials, not a texture per triangle


@dataclass(frozen=True)
class Material:
    """model: "phong" (albedo, specular, glossiness: the paper's model) or "pbr" (glTF 2.0
    metallic-roughness with KHR_materials_sheen: albedo is the base colour).
    albedo: diffuse reflectance (the base colour for "pbr"), linear RGB, (3,) or per vertex (V, 3), in [0, 1].
    specular: weight of the glossy lobe, scalar or (V,), >= 0 ("phong").
    glossiness: the paper's g in [0, 1] (0 diffuse lobe, 1 mirror), scalar or (V,) ("phong").
    metallic, roughness: glTF's, in [0, 1], scalar or (V,) ("pbr"; a roughness below the lobe
    tables' first node, 0.05, shades as 0.05).
    sheen_colour: (3,) or (V, 3) in [0, 1], black for no sheen; sheen_roughness: [0, 1] ("pbr").
    albedo_map: optional (H, W, 3) linear RGB texture that multiplies albedo (needs mesh UVs).
    gloss_map: optional (H, W, 2) texture of (specular, glossiness) that replaces the two values ("phong").
    metallic_roughness_map: optional (H, W, 2) texture of (metallic, roughness) in [0, 1] that
    multiplies the two values, as glTF's metallicRoughnessTexture does ("pbr").
    sheen_map: optional (H, W, 4) texture in [0, 1] whose rgb multiplies sheen_colour and whose a
    multiplies sheen_roughness, as KHR_materials_sheen's sheenColorTexture (linear here) and
    sheenRoughnessTexture (its alpha) do ("pbr").
    normal_map: optional (H, W, 3) tangent-space normal texture in [0, 1] (glTF's normalTexture:
    x = 2 r - 1 along the direction of growing u, y along growing v, z along the normal), any model;
    normal_scale scales its x and y. The tangent frame is the triangle's own (the surface gradients
    of u and v, as the geometry pass's screen derivatives give them), not MikkTSpace's.
    texture_sets, texture_set: several sets of the five textures above (TextureSet, at most
    MAX_TEXTURE_SETS) and, per vertex (V,), the one its triangles read (a triangle's three corners
    read the same); the fields above then name no texture.
    anisotropy: GGX's anisotropy in [0, 1] ("pbr"; 0: isotropic), a satin's or a silk's highlight
    stretched along one direction of the cloth (renderer/shading/brdf.py: alpha_t = alpha /
    sqrt(1 - 0.9 a), alpha_b = alpha sqrt(1 - 0.9 a)); anisotropy_rotation: that direction, in turns
    (1 = 360 degrees, U3M's unit) counter-clockwise from the direction of growing u towards growing v
    (the mesh's own UVs; a mesh without UVs: from the world's up axis projected onto the surface).
    alpha: the share of the cloth's area that is fibre, in [0, 1] (U3M's alpha; 1: opaque): light and
    sight pass the rest (1 - alpha) straight, the open weave of a voile or a mesh. transmission: the
    share of the light reaching the fibres that they pass on diffusely to the other side, in [0, 1]
    (U3M's transmission): a fibre reflects (1 - transmission) of what the model above says and passes
    on transmission x its base colour (the albedo; x (1 - metallic) for "pbr") of the light from behind,
    Lambertian about the other side's normal (a thin sheet: renderer/reference/montecarlo.py). Both
    belong to the sheet, not to a side: a back's own are not read.
    back: the material of the cloth's other side (a fabric's back, U3M's back visualisation), of the
    same model, itself without a back; None: both sides alike. The front is the side a triangle's
    winding faces (counter-clockwise as seen, the side its normal points to): each pixel takes the
    material of the side the camera sees there.
    """

    albedo: tuple | np.ndarray = (0.8, 0.8, 0.8)
    specular: float | np.ndarray = 0.0
    glossiness: float | np.ndarray = 0.5
    albedo_map: np.ndarray | None = None
    gloss_map: np.ndarray | None = None
    model: str = "phong"
    metallic: float | np.ndarray = 0.0
    roughness: float | np.ndarray = 0.5
    sheen_colour: tuple | np.ndarray = (0.0, 0.0, 0.0)
    sheen_roughness: float | np.ndarray = 0.5
    metallic_roughness_map: np.ndarray | None = None
    normal_map: np.ndarray | None = None
    normal_scale: float = 1.0
    sheen_map: np.ndarray | None = None
    texture_sets: tuple[TextureSet, ...] = ()
    texture_set: np.ndarray | None = None
    anisotropy: float = 0.0
    anisotropy_rotation: float = 0.0
    alpha: float = 1.0
    transmission: float = 0.0
    back: Material | None = None

    def __post_init__(self):
        for name in ("anisotropy", "anisotropy_rotation", "alpha", "transmission"):   # the registry's scalar-only fields
            fields.BY_NAME[name].check(getattr(self, name))
        if float(self.anisotropy) > 0.0 and self.model != "pbr":
            raise InvalidInputError("anisotropy belongs to the pbr model's GGX layer, not phong")
        if self.back is not None:
            if not isinstance(self.back, Material):
                raise InvalidInputError(f"back must be a Material, got {type(self.back).__name__}")
            if self.back.back is not None:
                raise InvalidInputError("a material's back has no back of its own")
            if self.back.model != self.model:
                raise InvalidInputError(f"a material's back has its model: {self.model}, got {self.back.model}")
        if self.model not in MODELS:
            raise InvalidInputError(f"material model must be one of {', '.join(MODELS)}, got {self.model!r}")
        own = self._own_set()
        own.check(self.model)
        if self.texture_sets:
            if any(getattr(own, f) is not None for f in ("albedo_map", "gloss_map", "metallic_roughness_map",
                                                          "normal_map", "sheen_map")):
                raise InvalidInputError("a material with texture_sets names its textures there, not in its own maps")
            if not 1 <= len(self.texture_sets) <= MAX_TEXTURE_SETS:
                raise InvalidInputError(f"texture_sets: at most {MAX_TEXTURE_SETS} sets, got {len(self.texture_sets)}")
            if self.texture_set is None:
                raise InvalidInputError("texture_sets need texture_set: the set each vertex reads, (V,)")
            for k, ts in enumerate(self.texture_sets):
                if not isinstance(ts, TextureSet):
                    raise InvalidInputError(f"texture_sets[{k}] must be a TextureSet, got {type(ts).__name__}")
                ts.check(self.model)
        elif self.texture_set is not None:
            raise InvalidInputError("texture_set names sets of texture_sets, and the material has none")

    def _own_set(self) -> TextureSet:
        return TextureSet(self.albedo_map, self.gloss_map, self.metallic_roughness_map, self.normal_map,
                          self.normal_scale, self.sheen_map)

    def texture_groups(self) -> tuple[TextureSet, ...]:
        """The material's texture sets: its texture_sets, or its own maps as the one set."""
        return self.texture_sets or (self._own_set(),)

    def vertex_texture_sets(self, n_vertices: int) -> np.ndarray:
        """Each vertex's texture set (V,) int32, validated (zeros with one set)."""
        if not self.texture_sets:
            return np.zeros(n_vertices, np.int32)
        k = np.asarray(self.texture_set)
        if k.shape != (n_vertices,) or not np.issubdtype(k.dtype, np.integer):
            raise InvalidInputError(f"texture_set must be integers of shape ({n_vertices},), got {k.dtype} {k.shape}")
        if k.size and (k.min() < 0 or k.max() >= len(self.texture_sets)):
            raise InvalidInputError(f"texture_set must lie in [0, {len(self.texture_sets) - 1}] (one per set), got "
                                    f"[{k.min()}, {k.max()}]")
        return k.astype(np.int32)

    def face_texture_sets(self, faces: np.ndarray, n_vertices: int) -> np.ndarray:
        """Each triangle's texture set (T,) int32: its corners', which must agree."""
        per_vertex = self.vertex_texture_sets(n_vertices)
        corners = per_vertex[np.asarray(faces)]
        mixed = np.flatnonzero((corners != corners[:, :1]).any(axis=1))
        if mixed.size:
            raise InvalidInputError(f"texture_set: {mixed.size} triangles have corners of different sets (the first, "
                                    f"triangle {mixed[0]}, reads {sorted(set(corners[mixed[0]].tolist()))}); a triangle "
                                    "reads one set")
        return corners[:, 0].copy() if corners.size else np.zeros(0, np.int32)

    @property
    def is_pbr(self) -> bool:
        return self.model == "pbr"

    def sides(self) -> tuple[Material, ...]:
        """The material of each side it draws: itself, and its back when it has one."""
        return (self,) if self.back is None else (self, self.back)

    @property
    def is_sheer(self) -> bool:
        """Some light and sight pass the sheet straight (alpha < 1, or an alpha map)."""
        return float(self.alpha) < 1.0 or any(ts.alpha_map is not None for ts in self.texture_groups())

    def mean_alpha(self) -> float:
        """The sheet's alpha over its area: alpha times the mean of its sets' alpha maps (a set without
        one counts as 1), each set weighted alike."""
        means = [1.0 if ts.alpha_map is None else float(np.mean(ts.alpha_texture())) for ts in self.texture_groups()]
        return float(self.alpha) * float(np.mean(means))

    @property
    def transmits(self) -> bool:
        """The fibres pass light on to the other side (transmission > 0)."""
        return float(self.transmission) > 0.0

    def has_sheen(self) -> bool:
        return any(m.is_pbr and bool((np.asarray(m.sheen_colour, np.float64) > 0).any()) for m in self.sides())

    def pbr_arrays(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """(pbr (V, 4) = (metallic, roughness, sheen roughness, 1 + anisotropy), sheen colour (V, 3))
        float32, validated; zeros for a Phong material (its pixels' flag is 0)."""
        if not self.is_pbr:
            return np.zeros((n_vertices, 4), np.float32), np.zeros((n_vertices, 3), np.float32)
        out = np.full((n_vertices, 4), 1.0 + float(self.anisotropy), np.float32)
        for k, name in enumerate(("metallic", "roughness", "sheen_roughness")):
            out[:, k] = _per_vertex(name, getattr(self, name), n_vertices)
        return out, _per_vertex_rgb("sheen_colour", self.sheen_colour, n_vertices)

    def has_glossy_lobe(self) -> bool:
        """Whether any fragment of either side can have a specular weight above 0 (from the values or
        the gloss map; always for "pbr": a dielectric reflects at least 4 % head-on)."""
        if self.back is not None and self.back._own_glossy_lobe():
            return True
        return self._own_glossy_lobe()

    def _own_glossy_lobe(self) -> bool:
        if self.is_pbr:
            return True
        maps = [ts.gloss_map for ts in self.texture_groups() if ts.gloss_map is not None]
        if maps:   # a gloss map replaces the values where it is read
            return any(bool((np.asarray(m, np.float64)[..., 0] > 0).any()) for m in maps) \
                or (len(maps) < len(self.texture_groups()) and bool((np.asarray(self.specular, np.float64) > 0).any()))
        return bool((np.asarray(self.specular, np.float64) > 0).any())

    def max_glossiness(self) -> float:
        """The glossiest lookup this material can make (0 when it has no glossy lobe anywhere): what
        decides the finest PEM level a scene needs. Specular and glossiness are interpolated (between
        vertices, between texels), so a fragment can pair any g with a nonzero specular weight: the
        maximum is over all of g as soon as any specular weight is positive."""
        if self.back is not None:
            return max(self.back._own_max_glossiness(), self._own_max_glossiness())
        return self._own_max_glossiness()

    def _own_max_glossiness(self) -> float:
        if not self._own_glossy_lobe():
            return 0.0
        if self.is_pbr:
            return 1.0   # the fitted lobes reach the finest levels (a smooth metal's)
        maps = [ts.gloss_map for ts in self.texture_groups() if ts.gloss_map is not None]
        values = [float(np.asarray(m, np.float64)[..., 1].max()) for m in maps]
        if len(maps) < len(self.texture_groups()):   # a set without one reads the values
            values.append(float(np.max(np.asarray(self.glossiness, np.float64))))
        return max(values)

    def vertex_arrays(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """(albedo (V, 3), material (V, 2) = (specular, glossiness)) float32, validated."""
        albedo = _per_vertex_rgb("albedo", self.albedo, n_vertices)
        out = np.empty((n_vertices, 2), np.float32)
        for k, name in enumerate(("specular", "glossiness")):
            out[:, k] = _per_vertex(name, getattr(self, name), n_vertices, fields.BY_NAME[name].hi)
        if self.is_pbr:
            out[:] = 0.0   # the pbr model's pixels read their lobes from the tables
        return albedo, out

    def maps(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The own set's (albedo map, second map) (TextureSet.maps), validated."""
        return self._own_set().maps(self.is_pbr)

    def normal_texture(self) -> np.ndarray | None:
        """The own set's normal map (H, W, 3) float32 in [0, 1], validated (None without one)."""
        return self._own_set().normal_texture()

    def sheen_texture(self) -> np.ndarray | None:
        """The own set's sheen map (H, W, 4) float32 in [0, 1], validated."""
        return self._own_set().sheen_texture()

    def has_textures(self) -> bool:
        """Whether any texture is read (then the mesh needs UVs); validates every set's maps."""
        return any([ts.has_textures(m.is_pbr) for m in self.sides() for ts in m.texture_groups()])
