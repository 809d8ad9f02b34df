"""Environment maps: reading HDR files, layouts and their resampling to the cube map, cube conventions.

`load_environment` and `environment_from_array` are the boundary: they validate their inputs once and
return an `EnvironmentMap`, whose cube (6, F, F, 3) float32 follows `cube.py` and is read-only.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from renderer.envmap.cube import (
    FACE_NAMES,
    cube_solid_angles,
    dir_to_face_uv,
    dir_to_texel,
    face_uv_to_dir,
    neighbour_texel,
    sample_bilinear,
    texel_centers_uv,
    texel_directions,
    texel_solid_angles,
)
from renderer.envmap.io import REC709_CHROMATICITIES, TexelReport, check_texels, exr_header, read_hdr_image, write_exr
from renderer.envmap.layouts import (
    Layout,
    as_layout,
    check_layout_size,
    cube_to_latlong,
    detect_layout,
    dir_to_image,
    image_to_dir,
    latlong_row_solid_angles,
    to_cube,
)
from renderer.envmap.procedural import sky_environment, studio_environment
from renderer.errors import InvalidInputError

__all__ = [
    "FACE_NAMES", "cube_solid_angles", "dir_to_face_uv", "dir_to_texel", "face_uv_to_dir", "neighbour_texel",
    "sample_bilinear", "texel_centers_uv", "texel_directions", "texel_solid_angles",
    "REC709_CHROMATICITIES", "TexelReport", "check_texels", "exr_header", "read_hdr_image", "write_exr",
    "Layout", "as_layout", "check_layout_size", "cube_to_latlong", "detect_layout", "dir_to_image", "image_to_dir",
    "latlong_row_solid_angles", "to_cube",
    "sky_environment", "studio_environment",
    "EnvironmentMap", "FACE_SIZE_MIN", "FACE_SIZE_MAX", "environment_from_array", "load_environment",
]

FACE_SIZE_MIN = 4
FACE_SIZE_MAX = 2048
_HASH_VERSION = b"envmap-source-v1"


@dataclasses.dataclass(frozen=True, eq=False)
class EnvironmentMap:
    """An environment map resampled to a cube.

    cube: float32 (6, F, F, 3), linear radiance, read-only, in the cube.py convention.
    source: the file path, or "<array>"; source_shape: (H, W, C) of the source image.
    texel_report: what check_texels found (counts are zero for a clean map).
    content_hash: sha256 hex of the source pixels (as float32, before any repair), their shape and the
    layout; it does not depend on face_size, which a cache key must add.
    """

    name: str
    cube: np.ndarray
    layout: Layout
    source: str
    source_shape: tuple
    texel_report: TexelReport | None
    content_hash: str

    @property
    def face_size(self) -> int:
        return int(self.cube.shape[1])


# Bytes of resampled cubes kept in a cache folder (`cube_cache`): a 512^2 cube (a background of a layout
# other than lat-long) is 19 MB.
CUBE_CACHE_BYTES = 1 << 30


def load_environment(path: str | Path, layout: Layout | str = "auto", face_size: int = 128,
                     repair: bool = False) -> EnvironmentMap:
    """Read an .exr/.hdr environment map and resample it to a cube of face_size (a power of two, 4..2048).

    layout "auto" detects it from the aspect ratio. Without repair, NaN, Inf or negative texels raise
    EnvironmentMapError; with repair they are fixed as `check_texels` describes.
    """
    face_size = _check_face_size(face_size)
    path = Path(path)
    img = read_hdr_image(path)
    return _build(img, layout, face_size, name=path.stem, source=str(path), repair=repair)


def environment_from_array(img: np.ndarray, layout: Layout | str, face_size: int, name: str,
                           repair: bool = False, cube_cache: Path | None = None) -> EnvironmentMap:
    """Like `load_environment` for an image already in memory: float (H, W, 3) linear radiance.
    `cube_cache`: a folder where the resampled cube is kept for the next process (keyed by the
    source's content, the face size, the repair and the resampling code; CUBE_CACHE_BYTES of them at
    most)."""
    face_size = _check_face_size(face_size)
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InvalidInputError(f"environment {name!r}: expected an image of shape (H, W, 3), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InvalidInputError(f"environment {name!r}: expected real numbers, got dtype {arr.dtype}")
    if not isinstance(name, str) or not name:
        raise InvalidInputError(f"environment name must be a non-empty string, got {name!r}")
    return _build(arr, layout, face_size, name=name, source="<array>", repair=repair, cube_cache=cube_cache)


def _check_face_size(face_size) -> int:
    ok = isinstance(face_size, (int, np.integer)) and not isinstance(face_size, bool)
    if not ok or not FACE_SIZE_MIN <= face_size <= FACE_SIZE_MAX or face_size & (face_size - 1):
        raise InvalidInputError(
            f"face_size must be a power of two from {FACE_SIZE_MIN} to {FACE_SIZE_MAX}, got {face_size!r}")
    return int(face_size)


def _build(img: np.ndarray, layout, face_size: int, *, name: str, source: str, repair: bool,
           cube_cache: Path | None = None) -> EnvironmentMap:
    h, w = img.shape[:2]
    layout = detect_layout(h, w) if isinstance(layout, str) and layout == "auto" else check_layout_size(layout, h, w)
    pixels = np.ascontiguousarray(img, np.float32)
    content_hash = _content_hash(pixels, layout)
    pixels, report = check_texels(pixels, repair=repair, name=name)
    if cube_cache is None:
        cube = to_cube(pixels, layout, face_size)
    else:
        from .. import user_cache

        code = tuple(f.__module__ for f in (to_cube, check_texels, face_uv_to_dir))
        cube = user_cache.cached_arrays(cube_cache, f"{content_hash[:32]}-{face_size}-{int(repair)}", code,
                                        lambda: {"cube": to_cube(pixels, layout, face_size)}, CUBE_CACHE_BYTES)["cube"]
    cube.setflags(write=False)
    return EnvironmentMap(name=name, cube=cube, layout=layout, source=source, source_shape=tuple(img.shape),
                          texel_report=report, content_hash=content_hash)


def _content_hash(pixels: np.ndarray, layout: Layout) -> str:
    digest = hashlib.sha256(_HASH_VERSION)
    digest.update(f"{layout.value}:{pixels.shape}".encode())
    digest.update(memoryview(pixels).cast("B"))
    return digest.hexdigest()
