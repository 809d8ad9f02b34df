"""A garment's material from its glTF / GLB file: glTF 2.0's metallic-roughness (base colour,
metallic, roughness, their textures) and the KHR_materials_sheen extension (sheen colour and
roughness), as a `Material(model="pbr")`.

The factors and the extension come from the file's JSON (trimesh keeps the core material only, and
quantizes its colours to 8 bits); the textures from trimesh's reading of the same file. The base
colour texture is sRGB-encoded (the specification), decoded to linear here; the metallic-roughness
texture is linear, roughness in its green and metallic in its blue channel, each multiplying its
factor; the normal texture is tangent-space, its scale kept (Material.normal_map: the tangent frame
is the triangle's, not MikkTSpace's).

The sheen extension's textures (sheenColorTexture, sRGB; sheenRoughnessTexture, its alpha) become
the Material's sheen_map, read from the file's own images. Not read, and said so by a warning: the
occlusion texture (the renderer's shadows stand for it). A file whose pieces use several materials
(a shirt and its buttons) gives their factors per vertex; their textures, if any, must be one set
(a shared atlas), else the file is refused with the materials and their textures named.
"""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError
from .material import Material

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


def _image(img, channels: int) -> np.ndarray:
    a = np.asarray(img.convert("RGB" if channels == 3 else "RGBA"), np.float64) / 255.0
    return a[..., :3]


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


def _gltf_image(path: Path, doc: dict, texture: int):
    """The PIL image a glTF texture samples: its source from the GLB's binary chunk (a buffer view),
    a data URI or a file beside the glTF."""
    import base64
    import io

    from PIL import Image

    from ..gltf_morph import _load, _view_bytes

    try:
        image = doc["images"][doc["textures"][texture]["source"]]
    except (KeyError, IndexError, TypeError):
        raise InvalidInputError(f"'{path}': texture {texture} names no image") from None
    if "bufferView" in image:
        view, data = _view_bytes(_load(path), path, image["bufferView"], {})
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
        return Image.open(io.BytesIO(blob))
    except Exception as e:   # PIL raises several kinds for an unreadable image
        raise InvalidInputError(f"'{path}': texture {texture}'s image cannot be read: {e}") from None


def _sheen_map(path: Path, doc: dict, sheen: dict) -> np.ndarray | None:
    """KHR_materials_sheen's textures as one (H, W, 4) map: the colour texture's rgb (sRGB-encoded,
    decoded to linear) and the roughness texture's alpha (linear), at the colour texture's size (the
    roughness resampled bilinearly where the two differ); a missing one is white."""
    from PIL import Image

    colour = sheen.get("sheenColorTexture")
    rough = sheen.get("sheenRoughnessTexture")
    if colour is None and rough is None:
        return None
    for info in (colour, rough):
        if info is not None and info.get("texCoord", 0) != 0:
            raise InvalidInputError(f"'{path}': a sheen texture reads UV set {info['texCoord']}; the renderer "
                                    "has one UV set (TEXCOORD_0)")
    rgb = srgb_to_linear(_image(_gltf_image(path, doc, colour["index"]), 3)) if colour is not None else None
    alpha = None
    if rough is not None:
        img = _gltf_image(path, doc, rough["index"]).convert("RGBA")
        if rgb is not None and img.size != (rgb.shape[1], rgb.shape[0]):
            img = img.resize((rgb.shape[1], rgb.shape[0]), Image.BILINEAR)
        alpha = np.asarray(img, np.float64)[..., 3] / 255.0
    shape = (rgb if rgb is not None else alpha).shape[:2]
    out = np.ones(shape + (4,), np.float32)
    if rgb is not None:
        out[..., :3] = rgb
    if alpha is not None:
        out[..., 3] = alpha
    return out


def material_from_gltf(path: str | Path) -> Material | None:
    """The file's material as a physically based Material, or None when its meshes name none. A file
    whose pieces use several materials gives one Material whose factors are per vertex (each
    vertex its piece's, in `load_mesh`'s vertex order); their textures, if any, must be the same."""
    path = Path(path)
    doc = gltf_json(path)
    used = sorted({p["material"] for m in doc.get("meshes", []) for p in m.get("primitives", []) if "material" in p})
    if not used:
        return None
    specs = [doc["materials"][i] for i in used]
    textures = {_texture_set(spec) for spec in specs}
    if len(textures) > 1:
        names = ", ".join(f"{spec.get('name', f'#{i}')} {_texture_set(spec)[:5]}" for i, spec in zip(used, specs))
        raise InvalidInputError(f"'{path}' uses {len(used)} materials with different textures (base colour, "
                                f"metallic-roughness, normal, sheen colour, sheen roughness: {names}); the renderer takes one texture set per mesh: "
                                "give the pieces one texture atlas, or export them as separate files")
    spec = specs[0]
    pbr = spec.get("pbrMetallicRoughness", {})
    left_out = sorted({name for s in specs for name in ("occlusionTexture",) if name in s})

    albedo_map = mr_map = normal_map = None
    normal_scale = _texture_set(spec)[-1]
    sheen_map = _sheen_map(path, doc, spec.get("extensions", {}).get(SHEEN, {}))
    scene = None
    if "baseColorTexture" in pbr or "metallicRoughnessTexture" in pbr or "normalTexture" in spec:
        scene = _trimesh_scene(path)
        core = _trimesh_material(scene)
        if "normalTexture" in spec and getattr(core, "normalTexture", None) is not None:
            normal_map = _image(core.normalTexture, 3).astype(np.float32)
        if "baseColorTexture" in pbr and getattr(core, "baseColorTexture", None) is not None:
            albedo_map = srgb_to_linear(_image(core.baseColorTexture, 3)).astype(np.float32)
        if "metallicRoughnessTexture" in pbr and getattr(core, "metallicRoughnessTexture", None) is not None:
            rgb = _image(core.metallicRoughnessTexture, 3)
            mr_map = np.ascontiguousarray(np.stack([rgb[..., 2], rgb[..., 1]], axis=-1), np.float32)
    if left_out:
        warnings.warn(f"'{path}': not read: {', '.join(left_out)} (docs/materials.md)", stacklevel=2)
    if len(used) == 1:
        factors = _factors(spec)
    else:
        factors = _per_vertex_factors(path, doc, scene or _trimesh_scene(path))
    for name in ("albedo", "sheen_colour"):   # one colour for the whole mesh: a plain tuple
        if np.ndim(factors[name]) == 1:
            factors[name] = tuple(float(c) for c in factors[name])
    return Material(model="pbr", albedo_map=albedo_map, metallic_roughness_map=mr_map, normal_map=normal_map,
                    normal_scale=normal_scale, sheen_map=sheen_map, **factors)


def _per_vertex_factors(path: Path, doc: dict, scene) -> dict:
    """Each vertex's material factors, for the vertices as `load_mesh` stacks the file's pieces: each
    piece (a trimesh geometry) is matched to the primitive whose POSITION values it holds."""
    from ..gltf_morph import _accessor, _load
    from ..mesh import triangle_parts

    gltf, cache, positions = _load(path), {}, {}
    primitives = [(p["attributes"]["POSITION"], p.get("material")) for m in doc.get("meshes", [])
                  for p in m.get("primitives", []) if "POSITION" in p.get("attributes", {})]

    def material_of(vertices: np.ndarray) -> int | None:
        found = set()
        for acc, material in primitives:
            if gltf.accessors[acc].count != len(vertices):
                continue
            if acc not in positions:
                positions[acc] = _accessor(gltf, path, acc, cache)
            if np.array_equal(positions[acc], vertices):
                found.add(material)
        if len(found) != 1:
            raise InvalidInputError(f"'{path}': cannot tell which material a piece of {len(vertices)} vertices uses "
                                    f"({'no primitive holds its positions' if not found else 'primitives of several materials hold them'})")
        return found.pop()

    default = {"albedo": np.ones(3), "metallic": 1.0, "roughness": 1.0, "sheen_colour": np.zeros(3),
               "sheen_roughness": 0.0}   # glTF's default material, for a primitive that names none
    pieces = []
    for geom, _ in triangle_parts(scene):
        material = material_of(np.asarray(geom.vertices, np.float64))
        f = default if material is None else _factors(doc["materials"][material])
        pieces.append({k: np.broadcast_to(np.asarray(v, np.float64), (len(geom.vertices),) + np.shape(v))
                       for k, v in f.items()})
    return {k: np.ascontiguousarray(np.concatenate([p[k] for p in pieces]), np.float32) for k in pieces[0]}


def _trimesh_scene(path: Path):
    import trimesh

    return trimesh.load_scene(path, process=False, maintain_order=True)


def _trimesh_material(scene):
    for geom in scene.geometry.values():
        material = getattr(getattr(geom, "visual", None), "material", None)
        if material is not None:
            return material
    return None
