"""The environment a user sees behind the garment, from the source map at its own resolution.

The PEM set's cube is as coarse as the lighting allows (64-128 texels a face at the presets: a
texel is 0.7-1.4 degrees, several pixels of a 35-degree view at 256 x 256, so window frames and a
sun's disc show as blocks). The background is read from the source instead, with its full MIP chain
and filtered over the pixel's own footprint:

* a lat-long source directly (its rows wrap; one lookup a pixel over the footprint from the view
  ray's analytic derivative, continuous where the longitude wraps, several across a row towards the
  poles): no resampling on the CPU, and one reconstruction between the file and the screen. Sources
  wider than BACKGROUND_LATLONG_WIDTH_MAX are box-filtered to it first;
* any other layout (an angular probe, a cross) through a cube resampled from the source at twice the
  source's own density (a layout W texels a quarter turn, a face of W / 2): a cube at the source's
  density is a second resampling that blurs it again.

Against the source itself, supersampled over each pixel (`background_truth`), a 1k lat-long's
background at 128 x 128 (the warehouse map; `pytest tests/test_background.py -s` prints them) measured
rel. RMSE 0.041 read directly, 0.126 through a cube of 512^2 and 5.85 from balanced's PEM cube; at the
poles 0.007 directly and 0.015-0.020 through the cube. Read directly, one filtered lookup a pixel
costs no more than the cube's four.
"""

from __future__ import annotations

import numpy as np

from ..envmap.layouts import Layout
from ..errors import InvalidInputError

# The largest background face: 1024 (a 2048-wide source at twice its density), 37.7 MB of half
# floats and 50 MB with the chain; larger cubes are shown at 2k detail.
BACKGROUND_FACE_MAX = 1024
# The widest lat-long kept for the background: 4096 x 2048, 50 MB of half floats and 67 MB with the
# chain; a wider source is box-filtered to it (halved until it fits).
BACKGROUND_LATLONG_WIDTH_MAX = 4096
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


def background_source(image: np.ndarray, layout: Layout | str, *, repair: bool, name: str,
                      cube_cache=None) -> np.ndarray:
    """What a map's `BackgroundMap` is made of: a lat-long source (H, W, 3) itself, repaired as its
    cubes are (`envmap.check_texels`); another layout resampled to a cube at `background_face_size`
    (kept in `cube_cache`, a folder, where given)."""
    from ..envmap import environment_from_array
    from ..envmap.io import check_texels

    layout = Layout(layout)
    if layout is Layout.LATLONG:
        return check_texels(image, repair=repair, name=name)[0]
    return environment_from_array(image, layout, background_face_size(image.shape, layout), name=name,
                                  repair=repair, cube_cache=cube_cache).cube


class BackgroundMap:
    """A texture of the environment with its MIP chain, for the background pass: a lat-long source
    (H, W, 3) itself, or a cube (6, F, F, 3) resampled from another layout. Texels must be finite
    and non-negative (a map loaded with repair=True is); half floats hold them, a sun beyond their
    range shown as HALF_MAX. Owns its texture; `release()` frees it. Make it once per map
    (`Renderer.background_map`)."""

    def __init__(self, gl, source: np.ndarray):
        """gl: the renderer's GLContext."""
        import moderngl

        from ..gpu.rawgl import Texture2DLevels

        source = np.asarray(source, np.float32)
        if source.ndim == 3 and source.shape[2] >= 3 and source.shape[0] >= 1 and source.shape[1] >= 2:
            self.latlong = True
        elif source.ndim == 4 and source.shape[0] == 6 and source.shape[1] == source.shape[2] and source.shape[3] >= 3:
            self.latlong = False
        else:
            raise InvalidInputError(f"background must be a lat-long image of shape (H, W, 3) or a cube of shape "
                                    f"(6, F, F, 3), got {source.shape}")
        rgb = source[..., :3]
        if not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
            raise InvalidInputError("background has NaN, Inf or negative texels; load the map with repair=True")
        if self.latlong:
            while rgb.shape[1] > BACKGROUND_LATLONG_WIDTH_MAX:
                rgb = _halve(rgb)
            # The MIP chain made here, 2 x 2 boxes as GL's, and uploaded (rawgl.Texture2DLevels: GL's
            # would cost a blit program's first compile); the longitude wraps, the latitude stops.
            levels = [rgb]
            while levels[-1].shape[:2] != (1, 1):
                levels.append(_halve(levels[-1]))
            self.texture = Texture2DLevels(gl.gl, [np.minimum(lvl, HALF_MAX) for lvl in levels], repeat_s=True)
        else:
            n = int(source.shape[1])
            self.texture = gl.ctx.texture_cube((n, n), 3, dtype="f2")
            half = np.minimum(rgb, HALF_MAX).astype(np.float16)
            for face in range(6):
                self.texture.write(face, np.ascontiguousarray(half[face]).tobytes())
            self.texture.build_mipmaps()
            self.texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)

    def use(self, location: int) -> None:
        """Bind the texture to sampler unit `location`."""
        self.texture.use(location=location)

    def release(self) -> None:
        self.texture.release()


def _halve(img: np.ndarray) -> np.ndarray:
    """The next MIP level of an (H, W, C) image, GL's size (each side halved, rounded down, at least
    1): 2 x 2 boxes, a side of one texel kept, the last row or column of an odd side left out."""
    h, w = img.shape[:2]
    if h > 1:
        img = 0.5 * (img[0:h - 1:2] + img[1:h:2])
    if w > 1:
        img = 0.5 * (img[:, 0:w - 1:2] + img[:, 1:w:2])
    return img


def background_truth(image: np.ndarray, layout: Layout | str, camera, width: int, height: int,
                     samples: int = 4) -> np.ndarray:
    """What a pixel of the background should show: the mean of samples x samples bilinear lookups of
    the source image (H, W, 3) itself along rays spread evenly over the pixel. float32 (height,
    width, 3), row 0 at the top, the renderer's layout. A measure for the background pass, which
    reads a filtered texture instead."""
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
