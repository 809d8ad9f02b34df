"""A garment's material from its glTF / GLB file: glTF 2.0's metallic-roughness (base colour,
metallic, roughness, their textures) and the KHR_materials_sheen extension (sheen colour and
roughness), as a `Material(model="pbr")`.

The factors and the extension come from the file's JSON (trimesh keeps the core material only, and
quantizes its colours to 8 bits), the textures from the file's own images. The base
colour texture is sRGB-encoded (the specification), decoded to linear here; the metallic-roughness
texture is linear, roughness in its green and metallic in its blue channel, each multiplying its
factor; the normal texture is tangent-space, its scale kept (Material.normal_map: the tangent frame
is the triangle's, not MikkTSpace's).

The sheen extension's textures (sheenColorTexture, sRGB; sheenRoughnessTexture, its alpha) become
the Material's sheen_map, read from the file's own images. Not read, and said so by a warning: the
occlusion texture (the renderer's shadows stand for it). A file whose pieces use several materials
(a shirt and its buttons) gives their factors per vertex and, where their textures differ, one
texture set per distinct set (Material.texture_sets: one draw of the geometry pass each), at most
MAX_TEXTURE_SETS.
"""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError
from .material import MAX_TEXTURE_SETS, Material, TextureSet

GLB_MAGIC = b"glTF"
SHEEN = "KHR_materials_sheen"


def gltf_json(path: Path) -> dict:
    """The JSON of a .gltf file or of a .glb's first chunk."""
    path = Path(path)
    data = path.read_bytes()
    try:
        if data[:4] == GLB_MAGIC:
            length, kind = struct.unpack_from("<I4s", data, 12)
            if kind != b"JSON":
                raise ValueError("its first chunk is not JSON")
            return json.loads(data[20:20 + length])
        return json.loads(data)
    except (ValueError, struct.error) as e:
        raise InvalidInputError(f"cannot read the glTF JSON of '{path}': {e}") from None


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _factors(spec: dict) -> dict:
    """A glTF material's factors (and the sheen extension's) as Material fields."""
    pbr = spec.get("pbrMetallicRoughness", {})
    sheen = spec.get("extensions", {}).get(SHEEN, {})
    return {"albedo": np.clip(np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), np.float64)[:3], 0.0, 1.0),
            "metallic": float(pbr.get("metallicFactor", 1.0)), "roughness": float(pbr.get("roughnessFactor", 1.0)),
            "sheen_colour": np.asarray(sheen.get("sheenColorFactor", [0.0, 0.0, 0.0]), np.float64),
            "sheen_roughness": float(sheen.get("sheenRoughnessFactor", 0.0))}


def _texture_set(spec: dict) -> tuple:
    """The textures a material reads (base colour, metallic-roughness, normal, sheen colour, sheen
    roughness, then the normal map's scale): equal sets read alike."""
    pbr = spec.get("pbrMetallicRoughness", {})
    sheen = spec.get("extensions", {}).get(SHEEN, {})
    return (pbr.get("baseColorTexture", {}).get("index"), pbr.get("metallicRoughnessTexture", {}).get("index"),
            spec.get("normalTexture", {}).get("index"), sheen.get("sheenColorTexture", {}).get("index"),
            sheen.get("sheenRoughnessTexture", {}).get("index"), float(spec.get("normalTexture", {}).get("scale", 1.0)))


class _GltfFile:
    """One glTF/GLB file as the material reader needs it: its JSON (read once), and, only when asked
    for, its pygltflib reading (for images in buffer views and the positions of its primitives), its
    buffers, its decoded textures (each texture once, however many materials share it) and trimesh's
    reading of its pieces in `load_mesh`'s order."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.doc = gltf_json(self.path)
        self._gltf = None
        self._buffers: dict = {}
        self._textures: dict = {}
        self._scene = None

    @property
    def gltf(self):
        from ..gltf_morph import _load

        if self._gltf is None:
            self._gltf = _load(self.path)
        return self._gltf

    @property
    def scene(self):
        import trimesh

        if self._scene is None:
            self._scene = trimesh.load_scene(self.path, process=False, maintain_order=True)
        return self._scene

    def accessor(self, index: int) -> np.ndarray:
        from ..gltf_morph import _accessor

        return _accessor(self.gltf, self.path, index, self._buffers)

    def image(self, info: dict, what: str, mode: str) -> np.ndarray:
        """The texture a material's texture info names, as float64 (H, W, len(mode)) in [0, 1]
        (PIL mode "RGB" or "RGBA"), from the GLB's binary chunk (a buffer view), a data URI or a
        file beside the glTF."""
        if info.get("texCoord", 0) != 0:
            raise InvalidInputError(f"'{self.path}': the {what} texture reads UV set {info['texCoord']}; the renderer "
                                    "has one UV set (TEXCOORD_0)")
        key = (info.get("index"), mode)
        if key not in self._textures:
            self._textures[key] = np.asarray(self._pil(info.get("index")).convert(mode), np.float64) / 255.0
        return self._textures[key]

    def _pil(self, texture):
        import base64
        import io

        from PIL import Image

        from ..gltf_morph import _view_bytes

        doc, path = self.doc, self.path
        try:
            image = doc["images"][doc["textures"][texture]["source"]]
        except (KeyError, IndexError, TypeError):
            raise InvalidInputError(f"'{path}': texture {texture} names no image") from None
        if "bufferView" in image:
            view, data = _view_bytes(self.gltf, path, image["bufferView"], self._buffers)
            start = view.byteOffset or 0
            blob = data[start:start + view.byteLength]
        elif str(image.get("uri", "")).startswith("data:"):
            blob = base64.b64decode(image["uri"].split(",", 1)[1])
        else:
            file = path.parent / str(image.get("uri", ""))
            if not file.is_file():
                raise InvalidInputError(f"'{path}': texture {texture}'s image {image.get('uri')!r} is missing")
            blob = file.read_bytes()
        try:
            img = Image.open(io.BytesIO(blob))
            img.load()
            return img
        except Exception as e:   # PIL raises several kinds for an unreadable image
            raise InvalidInputError(f"'{path}': texture {texture}'s image cannot be read: {e}") from None


def _sheen_map(f: _GltfFile, sheen: dict) -> np.ndarray | None:
    """KHR_materials_sheen's textures as one (H, W, 4) map: the colour texture's rgb (sRGB-encoded,
    decoded to linear) and the roughness texture's alpha (linear), at the colour texture's size (the
    roughness resampled bilinearly where the two differ); a missing one is white."""
    colour = sheen.get("sheenColorTexture")
    rough = sheen.get("sheenRoughnessTexture")
    if colour is None and rough is None:
        return None
    rgb = srgb_to_linear(f.image(colour, "sheen colour", "RGB")) if colour is not None else None
    alpha = None
    if rough is not None:
        alpha = f.image(rough, "sheen roughness", "RGBA")[..., 3]
        if rgb is not None and alpha.shape != rgb.shape[:2]:
            alpha = _resized(alpha, rgb.shape[:2])
    shape = (rgb if rgb is not None else alpha).shape[:2]
    out = np.ones(shape + (4,), np.float32)
    if rgb is not None:
        out[..., :3] = rgb
    if alpha is not None:
        out[..., 3] = alpha
    return out


def _resized(channel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """One channel in [0, 1] resampled bilinearly to (H, W) (PIL, at float precision)."""
    from PIL import Image

    img = Image.fromarray(np.asarray(channel, np.float32), mode="F").resize((shape[1], shape[0]), Image.BILINEAR)
    return np.asarray(img, np.float64)


def _textures(f: _GltfFile, spec: dict) -> TextureSet:
    """A glTF material's textures: the base colour (sRGB, decoded to linear), the metallic-roughness
    (linear: metallic in blue, roughness in green), the normal texture and its scale, the sheen's."""
    pbr = spec.get("pbrMetallicRoughness", {})
    albedo_map = mr_map = normal_map = None
    if "baseColorTexture" in pbr:
        albedo_map = srgb_to_linear(f.image(pbr["baseColorTexture"], "base colour", "RGB")).astype(np.float32)
    if "metallicRoughnessTexture" in pbr:
        rgb = f.image(pbr["metallicRoughnessTexture"], "metallic-roughness", "RGB")
        mr_map = np.ascontiguousarray(np.stack([rgb[..., 2], rgb[..., 1]], axis=-1), np.float32)
    if "normalTexture" in spec:
        normal_map = f.image(spec["normalTexture"], "normal", "RGB").astype(np.float32)
    return TextureSet(albedo_map=albedo_map, metallic_roughness_map=mr_map, normal_map=normal_map,
                      normal_scale=_texture_set(spec)[-1],
                      sheen_map=_sheen_map(f, spec.get("extensions", {}).get(SHEEN, {})))


def material_from_gltf(path: str | Path) -> Material | None:
    """The file's material as a physically based Material, or None when its meshes name none. A file
    whose pieces use several materials gives one Material whose factors are per vertex (each
    vertex its piece's, in `load_mesh`'s vertex order) and, where the materials' textures differ,
    one texture set per distinct set of textures (Material.texture_sets)."""
    f = _GltfFile(Path(path))
    doc = f.doc
    used = sorted({p["material"] for m in doc.get("meshes", []) for p in m.get("primitives", []) if "material" in p})
    if not used:
        return None
    specs = {i: doc["materials"][i] for i in used}
    left_out = sorted({name for s in specs.values() for name in ("occlusionTexture",) if name in s})
    if left_out:
        warnings.warn(f"'{path}': not read: {', '.join(left_out)} (docs/materials.md)", stacklevel=2)
    # The distinct texture sets, in the order of the materials that first use them.
    keys = list(dict.fromkeys(_texture_set(specs[i]) for i in used))
    if len(keys) > MAX_TEXTURE_SETS:
        raise InvalidInputError(f"'{path}' uses {len(keys)} different texture sets (base colour, metallic-roughness, "
                                f"normal, sheen colour, sheen roughness) over {len(used)} materials; the renderer "
                                f"takes at most {MAX_TEXTURE_SETS} per mesh: share textures between materials "
                                "(an atlas), or export the pieces as separate files")
    if len(used) == 1:
        factors, vertex_material = _factors(specs[used[0]]), None
    else:
        factors, vertex_material = _per_vertex_factors(f)
    for name in ("albedo", "sheen_colour"):   # one colour for the whole mesh: a plain tuple
        if np.ndim(factors[name]) == 1:
            factors[name] = tuple(float(c) for c in factors[name])
    first_of = {key: next(i for i in used if _texture_set(specs[i]) == key) for key in keys}
    if len(keys) == 1:
        ts = _textures(f, specs[used[0]])
        return Material(model="pbr", albedo_map=ts.albedo_map, metallic_roughness_map=ts.metallic_roughness_map,
                        normal_map=ts.normal_map, normal_scale=ts.normal_scale, sheen_map=ts.sheen_map, **factors)
    sets = [_textures(f, specs[first_of[key]]) for key in keys]
    set_of_material = {i: keys.index(_texture_set(specs[i])) for i in used}
    if (vertex_material < 0).any():   # a primitive that names no material: glTF's default, no textures
        empty = (None,) * 5 + (1.0,)
        if empty not in keys:
            keys.append(empty)
            sets.append(TextureSet())
        set_of_material[-1] = keys.index(empty)
    lookup = np.full(max(used) + 2, -1, np.int32)
    for i, k in set_of_material.items():
        lookup[i] = k
    return Material(model="pbr", texture_sets=tuple(sets), texture_set=lookup[vertex_material], **factors)


def _per_vertex_factors(f: _GltfFile) -> tuple[dict, np.ndarray]:
    """Each vertex's material factors, and its material (-1: none), for the vertices as `load_mesh`
    stacks the file's pieces: each piece (a trimesh geometry) is matched to the primitive whose
    POSITION values it holds."""
    from ..mesh import triangle_parts

    doc, path, positions = f.doc, f.path, {}
    primitives = [(p["attributes"]["POSITION"], p.get("material")) for m in doc.get("meshes", [])
                  for p in m.get("primitives", []) if "POSITION" in p.get("attributes", {})]

    def material_of(vertices: np.ndarray) -> int | None:
        found = set()
        for acc, material in primitives:
            if f.gltf.accessors[acc].count != len(vertices):
                continue
            if acc not in positions:
                positions[acc] = f.accessor(acc)
            if np.array_equal(positions[acc], vertices):
                found.add(material)
        if len(found) != 1:
            raise InvalidInputError(f"'{path}': cannot tell which material a piece of {len(vertices)} vertices uses "
                                    f"({'no primitive holds its positions' if not found else 'primitives of several materials hold them'})")
        return found.pop()

    default = {"albedo": np.ones(3), "metallic": 1.0, "roughness": 1.0, "sheen_colour": np.zeros(3),
               "sheen_roughness": 0.0}   # glTF's default material, for a primitive that names none
    pieces, which = [], []
    for geom, _ in triangle_parts(f.scene):
        material = material_of(np.asarray(geom.vertices, np.float64))
        values = default if material is None else _factors(doc["materials"][material])
        pieces.append({k: np.broadcast_to(np.asarray(v, np.float64), (len(geom.vertices),) + np.shape(v))
                       for k, v in values.items()})
        which.append(np.full(len(geom.vertices), -1 if material is None else material, np.int64))
    return ({k: np.ascontiguousarray(np.concatenate([p[k] for p in pieces]), np.float32) for k in pieces[0]},
            np.concatenate(which))
