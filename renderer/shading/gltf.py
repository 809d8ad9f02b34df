"""A garment's material from its glTF / GLB file: glTF 2.0's metallic-roughness (base colour,
metallic, roughness, their textures) and the KHR_materials_sheen extension (sheen colour and
roughness), as a `Material(model="pbr")`.

The factors and the extension come from the file's JSON (trimesh keeps the core material only, and
quantizes its colours to 8 bits); the textures from trimesh's reading of the same file. The base
colour texture is sRGB-encoded (the specification), decoded to linear here; the metallic-roughness
texture is linear, roughness in its green and metallic in its blue channel, each multiplying its
factor; the normal texture is tangent-space, its scale kept (Material.normal_map: the tangent frame
is the triangle's, not MikkTSpace's).

Not read, and said so by a warning: the occlusion texture (the renderer's shadows stand for it) and
the sheen extension's textures (its factors are read). A file whose meshes
use more than one material is refused with the count: the renderer takes one material per mesh.
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


def material_from_gltf(path: str | Path) -> Material | None:
    """The file's material as a physically based Material, or None when its meshes name none."""
    path = Path(path)
    doc = gltf_json(path)
    used = sorted({p["material"] for m in doc.get("meshes", []) for p in m.get("primitives", []) if "material" in p})
    if not used:
        return None
    if len(used) > 1:
        raise InvalidInputError(f"'{path}' uses {len(used)} materials; the renderer takes one material per mesh: "
                                "export the garment's pieces as separate files, or pass --material")
    spec = doc["materials"][used[0]]
    pbr = spec.get("pbrMetallicRoughness", {})
    base = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), np.float64)[:3]
    metallic = float(pbr.get("metallicFactor", 1.0))
    roughness = float(pbr.get("roughnessFactor", 1.0))
    sheen = spec.get("extensions", {}).get(SHEEN, {})
    sheen_colour = tuple(float(c) for c in sheen.get("sheenColorFactor", [0.0, 0.0, 0.0]))
    sheen_roughness = float(sheen.get("sheenRoughnessFactor", 0.0))
    left_out = [name for name in ("occlusionTexture",) if name in spec]
    left_out += [f"{SHEEN}.{name}" for name in ("sheenColorTexture", "sheenRoughnessTexture") if name in sheen]

    albedo_map = mr_map = normal_map = None
    normal_scale = float(spec.get("normalTexture", {}).get("scale", 1.0))
    if "baseColorTexture" in pbr or "metallicRoughnessTexture" in pbr or "normalTexture" in spec:
        core = _trimesh_material(path)
        if "normalTexture" in spec and getattr(core, "normalTexture", None) is not None:
            normal_map = _image(core.normalTexture, 3).astype(np.float32)
        if "baseColorTexture" in pbr and getattr(core, "baseColorTexture", None) is not None:
            albedo_map = srgb_to_linear(_image(core.baseColorTexture, 3)).astype(np.float32)
        if "metallicRoughnessTexture" in pbr and getattr(core, "metallicRoughnessTexture", None) is not None:
            rgb = _image(core.metallicRoughnessTexture, 3)
            mr_map = np.ascontiguousarray(np.stack([rgb[..., 2], rgb[..., 1]], axis=-1), np.float32)
    if left_out:
        warnings.warn(f"'{path}': not read: {', '.join(left_out)} (docs/materials.md)", stacklevel=2)
    return Material(tuple(np.clip(base, 0.0, 1.0)), model="pbr", metallic=metallic, roughness=roughness,
                    sheen_colour=sheen_colour, sheen_roughness=sheen_roughness, albedo_map=albedo_map,
                    metallic_roughness_map=mr_map, normal_map=normal_map, normal_scale=normal_scale)


def _trimesh_material(path: Path):
    import trimesh

    scene = trimesh.load_scene(path, process=False, maintain_order=True)
    for geom in scene.geometry.values():
        material = getattr(getattr(geom, "visual", None), "material", None)
        if material is not None:
            return material
    return None
