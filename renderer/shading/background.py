"""The environment a user sees behind the garment, from the source map at its own resolution.

The PEM set's cube is as coarse as the lighting allows (64-128 texels a face at the presets: a
texel is 0.7-1.4 degrees, several pixels of a 35-degree view at 256 x 256, so window frames and a
sun's disc show as blocks). The background instead comes from a cube resampled from the source at
twice the source's own density (a lat-long W pixels wide has W / 4 texels a quarter turn; a cube
face of W / 2), with its full MIP chain, read with trilinear filtering over the pixel's own
footprint (the fragment shader's derivatives). Twice, because a cube at the source's density is a
second resampling that blurs it again: against the source itself, supersampled over each pixel
(`background_truth`), a 1k lat-long's background at 256 x 256 measured rel. RMSE 0.76 from 256^2
faces, 0.17 from 512^2 and 0.12 from 1024^2 (5.96 from balanced's 128^2 PEM cube; the warehouse map,
tests/test_background.py prints them).
"""

from __future__ import annotations

import numpy as np

from ..envmap.layouts import Layout
from ..errors import InvalidInputError

# The largest background face: 1024 (a 2048-wide lat-long at twice its density), 37.7 MB of half
# floats and 50 MB with the chain; larger maps are shown at 2k detail.
BACKGROUND_FACE_MAX = 1024
BACKGROUND_FACE_MIN = 16
# Half floats hold up to 65504; a sun's texels beyond it are shown as this (white after any tone map).
HALF_MAX = 65504.0


def background_face_size(source_shape: tuple, layout: Layout | str) -> int:
    """The cube face size (a power of two) at twice the texel density of a source image of
    `source_shape` (H, W, ...) in `layout`, within [BACKGROUND_FACE_MIN, BACKGROUND_FACE_MAX]."""
    layout = Layout(layout)
    h, w = int(source_shape[0]), int(source_shape[1])
    if h < 1 or w < 1:
        raise InvalidInputError(f"source image must have a positive size, got {source_shape}")
    # Source texels a quarter turn: a lat-long's width, an angular probe's diameter (360 degrees across
    # it) and a cross's long side each span four of them.
    per_quarter = {Layout.LATLONG: w, Layout.ANGULAR: min(h, w), Layout.HCROSS: w, Layout.VCROSS: h}[layout] / 4.0
    size = 1 << max(0, int(np.ceil(np.log2(max(2.0 * per_quarter, 1.0)))))
    return int(np.clip(size, BACKGROUND_FACE_MIN, BACKGROUND_FACE_MAX))


class BackgroundMap:
    """A cube texture of the environment with its MIP chain, for the background pass. Owns its
    texture; `release()` frees it. Make it once per map (`Renderer.background_map`)."""

    def __init__(self, ctx, cube: np.ndarray):
        cube = np.asarray(cube, np.float32)
        if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[1] != cube.shape[2] or cube.shape[3] < 3:
            raise InvalidInputError(f"background cube must have shape (6, F, F, 3), got {cube.shape}")
        if not np.all(np.isfinite(cube[..., :3])) or np.any(cube[..., :3] < 0):
            raise InvalidInputError("background cube has NaN, Inf or negative texels; load the map with repair=True")
        n = int(cube.shape[1])
        self.face_size = n
        self.texture = ctx.texture_cube((n, n), 3, dtype="f2")
        half = np.minimum(cube[..., :3], HALF_MAX).astype(np.float16)
        for face in range(6):
            self.texture.write(face, np.ascontiguousarray(half[face]).tobytes())
        self.texture.build_mipmaps()
        import moderngl

        self.texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)

    def release(self) -> None:
        self.texture.release()


def background_truth(image: np.ndarray, layout: Layout | str, camera, width: int, height: int,
                     samples: int = 4) -> np.ndarray:
    """What a pixel of the background should show: the mean of samples x samples bilinear lookups of
    the source image (H, W, 3) itself along rays spread evenly over the pixel. float32 (height,
    width, 3), row 0 at the top, the renderer's layout. A measure for the background pass, which
    reads a resampled cube instead."""
    from ..envmap.layouts import dir_to_image

    layout = Layout(layout)
    src = np.asarray(image, np.float64)[..., :3]
    h, w = src.shape[:2]
    # Directions do not depend on the near and far planes: any sphere gives the same rays.
    inv = np.linalg.inv(camera.view_proj(width / height, np.asarray(camera.target, np.float64), 1.0))
    offsets = (np.arange(samples) + 0.5) / samples
    rows = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    cols = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    y, x = np.meshgrid(1.0 - rows / height * 2.0, cols / width * 2.0 - 1.0, indexing="ij")
    ends = []
    for z in (-1.0, 1.0):
        p = np.stack([x.ravel(), y.ravel(), np.full(x.size, z), np.ones(x.size)], axis=1) @ inv.T
        ends.append(p[:, :3] / p[:, 3:])
    xs, ys, _ = dir_to_image(ends[1] - ends[0], layout, h, w)
    fx, fy = xs - 0.5, ys - 0.5
    x0, y0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    tx, ty = (fx - x0)[:, None], (fy - y0)[:, None]

    def px(xi, yi):
        xi = np.mod(xi, w) if layout is Layout.LATLONG else np.clip(xi, 0, w - 1)
        return src[np.clip(yi, 0, h - 1), xi]

    value = ((1 - ty) * ((1 - tx) * px(x0, y0) + tx * px(x0 + 1, y0))
             + ty * ((1 - tx) * px(x0, y0 + 1) + tx * px(x0 + 1, y0 + 1)))
    value = value.reshape(height, samples, width, samples, 3).mean(axis=(1, 3))
    return value.astype(np.float32)
