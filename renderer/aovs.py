"""Passes beside the beauty image (AOVs) for compositing and learning: what the geometry pass already
holds for each pixel, read back when a frame asks for them (FrameSettings.aovs).

- `depth`: Z, the distance from the camera's eye to the surface, metres (BACKGROUND_DEPTH where no
  surface is).
- `normal`: N.X, N.Y, N.Z, the world-space shading normal (after the normal map), turned to the
  side the camera sees; 0 where no surface is.
- `albedo`: albedo.R, .G, .B, the material's diffuse reflectance (Phong) or base colour (pbr) after
  its textures, linear; 0 where no surface is.
- `id`: 0 for the background, 1 for the garment (the scene's first mesh), 2, 3, ... for the other
  meshes in order.

They are the pixel centre's surface: with anti-aliasing (aa_samples) the beauty image's edges are
blended, these are not (a compositor's id matte is the pixel's one surface). Rows run from the top, as
the image's do. The EXR channel names are the ones compositors read (`EXR_CHANNELS`).
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError
from .gpu.contract import MESH_ID_STRIDE

AOVS = ("depth", "normal", "albedo", "id")
EXR_CHANNELS = {"depth": ("Z",), "normal": ("N.X", "N.Y", "N.Z"), "albedo": ("albedo.R", "albedo.G", "albedo.B"),
                "id": ("id",)}
# Z where no surface is: far beyond any scene, finite (Blender's convention), so that a compositor's
# depth arithmetic stays finite.
BACKGROUND_DEPTH = 1e10


def parse_aovs(names) -> tuple[str, ...]:
    """The passes asked for, in AOVS' order, each once; a name that is not a pass is refused by name."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = list(names or ())
    unknown = [n for n in names if n not in AOVS]
    if unknown:
        raise InvalidInputError(f"unknown pass(es) {', '.join(map(repr, unknown))}: the passes are {', '.join(AOVS)}")
    return tuple(a for a in AOVS if a in names)


def from_gbuffer(names: tuple[str, ...], read, eye) -> dict[str, np.ndarray]:
    """The passes `names` from the geometry pass's targets: read(k) gives target k as float32 (H, W, 4),
    rows from the top (0 position + specular, 1 normal + glossiness, 2 geometric normal + group and id,
    3 albedo); `eye`, the camera's position."""
    out: dict[str, np.ndarray] = {}
    position = read(0)
    covered = position[..., 3] >= 0.0
    if "depth" in names:
        dist = np.linalg.norm(position[..., :3] - np.asarray(eye, np.float32), axis=-1)
        out["depth"] = np.where(covered, dist, np.float32(BACKGROUND_DEPTH)).astype(np.float32)
    if "normal" in names:
        out["normal"] = np.where(covered[..., None], read(1)[..., :3], 0.0).astype(np.float32)
    if "albedo" in names:
        out["albedo"] = np.where(covered[..., None], read(3)[..., :3], 0.0).astype(np.float32)
    if "id" in names:
        ids = np.floor((read(2)[..., 3] + 0.5) / MESH_ID_STRIDE)
        out["id"] = np.where(covered, ids, 0.0).astype(np.float32)
    return out


def exr_channels(aovs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The passes as EXR channels (name -> (H, W) float32), in AOVS' order."""
    out = {}
    for name in AOVS:
        if name in aovs:
            a = aovs[name]
            for k, channel in enumerate(EXR_CHANNELS[name]):
                out[channel] = np.ascontiguousarray(a if a.ndim == 2 else a[..., k], np.float32)
    return out
