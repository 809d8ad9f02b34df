"""Display encoding of linear renders: exposure, a tone curve, the sRGB OETF, 8-bit PNG.

Input images are scene-referred linear RGB (Rec. 709 / sRGB primaries), as the shading pass writes
them. Row 0 of an image is the top row of the PNG (flip a bottom-up GL readback before encoding).
Order: linear * 2**exposure_ev -> tone curve (display-linear, [0, 1]) -> sRGB OETF -> 8 bits.
Every PNG written here says so: an sRGB chunk, with the gAMA and cHRM that stand for it (`PNG_SRGB_CHUNKS`).
"""

from __future__ import annotations

import io
import math
import os
import struct
from enum import Enum

import numpy as np

from ..errors import InvalidInputError

# Middle grey: the scene-referred value that auto exposure maps the median covered luminance to
# (the photographic "18% grey" key; Reinhard et al. 2002, "Photographic Tone Reproduction for
# Digital Images", use the same default key a = 0.18, though on the log-average rather than the median).
EXPOSURE_KEY = 0.18

# Rec. 709 / sRGB luminance weights (ITU-R BT.709-6, the luminance equation of part 1).
_LUMA = np.array([0.2126, 0.7152, 0.0722])

# Largest scene value fed to a curve: keeps x**2 finite in float32 (ACES fit) and maps +Inf to white.
_MAX_SCENE_VALUE = 1e15

# Auto exposure stays within this range, so 2**ev stays finite in float32 for any image.
_MAX_AUTO_EV = 32.0


class ToneCurve(str, Enum):
    """How exposed scene-linear values map to display-linear [0, 1]."""

    PBR_NEUTRAL = "pbr-neutral"  # Khronos PBR Neutral: base colours kept, highlights compressed toward white
    FILMIC = "filmic"  # Narkowicz's fit of the ACES RRT + Rec. 709 ODT
    REINHARD = "reinhard"  # x / (1 + x) per channel
    LINEAR = "linear"  # clamp to [0, 1]

    @classmethod
    def parse(cls, value: ToneCurve | str) -> ToneCurve:
        try:
            return cls(value.lower() if isinstance(value, str) else value)
        except ValueError:
            raise InvalidInputError(f"tone curve must be one of {[c.value for c in cls]}; got {value!r}") from None


# The default of the CLI and the service, chosen for product images: a colourway's colour is the product, and
# PBR Neutral shows a base colour under white light as that colour with its hue and saturation, where the ACES
# fit, per channel, lifts mid tones and shifts hue and saturation (tests/test_colour.py: 3-5 code values off
# with PBR Neutral, up to 33 with filmic).
DEFAULT_CURVE = ToneCurve.PBR_NEUTRAL


def aces_filmic(x: np.ndarray) -> np.ndarray:
    """Narkowicz's ACES fit, per channel, clamped to [0, 1].

    K. Narkowicz, "ACES Filmic Tone Mapping Curve" (2016), a least-squares fit (max error 0.0138) of
    ODT(RRT(x)) with the input pre-exposed so that 1 maps to about 0.8; multiply the input by 0.6 for
    the original ACES exposure:
        f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)
    Its derivative's numerator is 1.408 x^2 + 0.7028 x + 0.0042 > 0, so f is monotone for x >= 0;
    f crosses 1 at x ~ 7.24 and tends to 2.51 / 2.43, hence the clamp.
    """
    x = np.asarray(x, np.float32)
    shape, x = x.shape, x.reshape(-1)  # 1-D so the in-place steps below also work for scalars
    num = x * np.float32(2.51)
    num += np.float32(0.03)
    num *= x
    den = x * np.float32(2.43)
    den += np.float32(0.59)
    den *= x
    den += np.float32(0.14)
    num /= den
    return np.clip(num, 0.0, 1.0, out=num).reshape(shape)


# Khronos PBR Neutral's constants (see `pbr_neutral`): F90, Ks and Kd of the specification.
_PBR_F90 = 0.04
_PBR_KS = 0.8 - _PBR_F90
_PBR_KD = 0.15


def pbr_neutral(rgb: np.ndarray) -> np.ndarray:
    """Khronos PBR Neutral on linear Rec. 709 RGB (..., 3) >= 0 (finite), to display-linear (..., 3)
    float32 in [0, 1]. The channels are coupled: a colour moves only toward white, so hue is kept.

    The Khronos Group, "Khronos PBR Neutral Tone Mapper" specification (2024;
    github.com/KhronosGroup/ToneMapping, PBR_Neutral/README.md). For c = (R, G, B):
        F90 = 0.04 (a dielectric's reflectance at normal incidence, IoR 1.5), Ks = 0.8 - F90 (where
        compression starts), Kd = 0.15 (how fast compressed colours desaturate);
        x = min(R, G, B);  f = x - x^2 / (4 F90) for x <= 2 F90, else F90
        p = max(c - f);  p_n = 1 - (1 - Ks)^2 / (p + 1 - 2 Ks);  g = 1 / (Kd (p - p_n) + 1)
        out = c - f for p <= Ks, else (c - f) (p_n / p) g + p_n (1 - g)
    So for min(c) >= 2 F90 and max(c) <= Ks + F90 the curve is out = c - F90 exactly: it removes the
    specular F90 that a shiny dielectric facing the camera adds under white light of radiance 1.
    Below 2 F90 the offset f bends to 0 (value F90 and slope 0 where its pieces meet), so black stays
    black; above Ks the peak p goes to p_n < 1 (value Ks and slope 1 at Ks) and the colour is mixed
    toward the grey p_n by 1 - g.
    """
    c = np.asarray(rgb, np.float32)
    if c.ndim < 1 or c.shape[-1] != 3:
        raise InvalidInputError(f"the pbr-neutral curve maps RGB triples: an image of shape (..., 3); got {c.shape}")
    # A copy as channel planes (3, N): an operation per pixel then runs over contiguous rows.
    shape, c = c.shape, np.array(c.reshape(-1, 3).T, order="C")
    r, g, b = c
    # f's two pieces in one: x - x^2 / (4 F90) with x clamped to 2 F90 (where it is F90).
    x = np.minimum(np.minimum(r, g), b)
    np.minimum(x, np.float32(2 * _PBR_F90), out=x)
    c -= x - x * x * np.float32(1 / (4 * _PBR_F90))
    p = np.maximum(np.maximum(r, g), b)
    hot = p > np.float32(_PBR_KS)
    if hot.any():
        # Over every pixel (a boolean gather costs more than the arithmetic), kept where p > Ks.
        pk = np.maximum(p, np.float32(_PBR_KS))  # every denominator below is then >= 1 - Ks
        p_n = np.float32(1.0) - np.float32((1 - _PBR_KS) ** 2) / (pk + np.float32(1 - 2 * _PBR_KS))
        mix = np.float32(1.0) / (np.float32(_PBR_KD) * (pk - p_n) + np.float32(1.0))
        # The spec's mix written as p_n - g p_n (p - (c - f)) / p: the peak channel (all of a grey) is
        # exactly p_n, so a brighter grey never maps darker.
        compressed = pk - c
        compressed *= mix * p_n / pk
        np.subtract(p_n, compressed, out=compressed)
        np.copyto(c, compressed, where=hot)
    return np.clip(c, 0.0, 1.0, out=c).T.reshape(shape)


def srgb_oetf(linear: np.ndarray) -> np.ndarray:
    """sRGB encoding of display-linear values in [0, 1] (the piecewise curve of IEC 61966-2-1:1999):
    12.92 L for L <= 0.0031308, else 1.055 L**(1/2.4) - 0.055. Inputs are clamped to [0, 1]."""
    lin = np.clip(np.asarray(linear, np.float32), 0.0, 1.0)
    shape, lin = lin.shape, lin.reshape(-1)  # 1-D so the in-place steps below also work for scalars
    out = np.power(lin, np.float32(1.0 / 2.4))
    out *= np.float32(1.055)
    out -= np.float32(0.055)
    np.copyto(out, lin * np.float32(12.92), where=lin <= 0.0031308)
    # 1.055 - 0.055 rounds to 0.99999994 in float32; the curve's end is exactly 1.
    np.copyto(out, np.float32(1.0), where=lin >= 1.0)
    return out.reshape(shape)


def srgb_eotf(encoded: np.ndarray) -> np.ndarray:
    """Inverse of `srgb_oetf`: sRGB-encoded [0, 1] to display-linear (the 0.04045 threshold is 12.92 * 0.0031308)."""
    v = np.clip(np.asarray(encoded, np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4)).astype(np.float32)


def _check_exposure(exposure_ev: float) -> float:
    try:
        ev = float(exposure_ev)
    except (TypeError, ValueError):
        raise InvalidInputError(f"exposure_ev must be a number of stops; got {exposure_ev!r}") from None
    if not math.isfinite(ev):
        raise InvalidInputError(f"exposure_ev must be finite; got {exposure_ev!r}")
    return ev


def _scene_values(rgb: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(rgb)
    if a.dtype.kind not in "fiu":
        raise InvalidInputError(f"{what} must be a real numeric array; got dtype {a.dtype}")
    # NaN -> 0 and negatives -> 0 (no negative radiance; lossy EXR compression rings below zero);
    # +Inf -> white. Done here so every curve sees finite, non-negative input. fmax/fmin drop NaN.
    with np.errstate(over="ignore"):  # float64 beyond float32 range becomes Inf, then white
        x = np.fmax(a, np.float32(0.0), dtype=np.float32)
    return np.fmin(x, np.float32(_MAX_SCENE_VALUE), out=x)


def tonemap(
    rgb_linear: np.ndarray, exposure_ev: float = 0.0, curve: ToneCurve | str = DEFAULT_CURVE
) -> np.ndarray:
    """Scene-linear RGB (..., C), any real dtype, to sRGB-encoded float32 in [0, 1], same shape.

    Channels are mapped independently, except by pbr-neutral, which maps RGB triples (C = 3).
    NaN and negative values give 0, +Inf gives 1.
    exposure_ev: stops; the image is multiplied by 2**exposure_ev before the curve.
    """
    ev = _check_exposure(exposure_ev)
    curve = ToneCurve.parse(curve)
    x = _scene_values(rgb_linear, "rgb_linear")
    # Past +-126 stops every pixel is black or white anyway; the clamp keeps the scale a finite,
    # normal float32 (0 * Inf would be NaN).
    with np.errstate(over="ignore"):  # huge values times the scale may reach Inf: clipped to white next
        x *= np.float32(2.0 ** min(max(ev, -126.0), 126.0))
    np.fmin(x, np.float32(_MAX_SCENE_VALUE), out=x)
    if curve is ToneCurve.FILMIC:
        display = aces_filmic(x)
    elif curve is ToneCurve.PBR_NEUTRAL:
        display = pbr_neutral(x)
    elif curve is ToneCurve.REINHARD:
        # Reinhard et al. 2002's global operator x / (1 + x), per channel, as 1 - 1 / (1 + x) in float64:
        # every step rounds monotonically, so brighter never maps darker (x / (1 + x) in float32 did,
        # near 1e6, where 1 + x rounds).
        display = (1.0 - 1.0 / (1.0 + x.astype(np.float64))).astype(np.float32)
    else:
        display = np.clip(x, 0.0, 1.0)
    return srgb_oetf(display)


# The colour space of every PNG written: an sRGB chunk (rendering intent 0, perceptual), and for
# decoders that ignore it the gAMA and cHRM values that the PNG specification (ISO/IEC 15948:2003,
# 11.3.3.5) says an encoder writing sRGB should write beside it: gamma 45455 (1/2.2 x 100000), the
# D65 white and Rec. 709 primaries x 100000 (white x y, red x y, green x y, blue x y). (chunk type,
# data) pairs, in the order they go before the image data.
PNG_SRGB_CHUNKS = (
    (b"sRGB", bytes([0])),
    (b"gAMA", struct.pack(">I", 45455)),
    (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)),
)


def srgb_pnginfo():
    """Pillow's `pnginfo` that writes `PNG_SRGB_CHUNKS`: pass it to every `Image.save(..., format="PNG")`."""
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for kind, data in PNG_SRGB_CHUNKS:
        info.add(kind, data)
    return info


def _quantize(v: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(v, 0.0, 1.0) * 255.0).astype(np.uint8)


def encode_rgba8(
    rgba_linear: np.ndarray, exposure_ev: float = 0.0, curve: ToneCurve | str = DEFAULT_CURVE
) -> np.ndarray:
    """(H, W, 4) linear RGBA (or (H, W, 3), opaque) to uint8 (H, W, 4): tone-mapped sRGB colour,
    alpha copied as coverage (clamped to [0, 1], NaN -> 0, never tone-mapped). A frame's colour is
    premultiplied by its coverage (OpenEXR's convention; an anti-aliased edge pixel holds the
    surfaces' share of the pixel), a PNG's is not: where 0 < alpha < 1 the colour is divided by alpha
    before the tone curve, so that a compositor's `over` gives the frame back."""
    a = np.asarray(rgba_linear)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InvalidInputError(f"image must have shape (H, W, 4) or (H, W, 3) with H, W > 0; got {a.shape}")
    out = np.empty(a.shape[:2] + (4,), np.uint8)
    rgb = a[..., :3]
    if a.shape[2] == 4:
        alpha = _scene_values(a[..., 3], "alpha")  # NaN -> 0
        out[..., 3] = _quantize(alpha)
        part = (alpha > 0.0) & (alpha < 1.0)
        if part.any():
            rgb = rgb.astype(np.float32, copy=True)
            rgb[part] /= alpha[part, None]
    else:
        out[..., 3] = 255
    out[..., :3] = _quantize(tonemap(rgb, exposure_ev, curve))
    return out


def to_png_bytes(
    rgba_linear: np.ndarray,
    exposure_ev: float = 0.0,
    curve: ToneCurve | str = DEFAULT_CURVE,
    *,
    compress_level: int = 1,
) -> bytes:
    """An 8-bit RGBA PNG of a linear (H, W, 4) or (H, W, 3) image; see `encode_rgba8`.

    compress_level: zlib level 0-9. The default 1 encoded a smooth 512 x 512 render about 3x faster
    than Pillow's 6 for a file ~12% larger: the right trade for frames served live.
    """
    from PIL import Image  # only encoding needs Pillow

    if not (isinstance(compress_level, int) and 0 <= compress_level <= 9):
        raise InvalidInputError(f"compress_level must be an integer 0..9; got {compress_level!r}")
    buf = io.BytesIO()
    image = Image.fromarray(encode_rgba8(rgba_linear, exposure_ev, curve))
    image.save(buf, format="PNG", compress_level=compress_level, pnginfo=srgb_pnginfo())
    return buf.getvalue()


def write_png(
    path: str | os.PathLike,
    rgba_linear: np.ndarray,
    exposure_ev: float = 0.0,
    curve: ToneCurve | str = DEFAULT_CURVE,
    *,
    compress_level: int = 6,
) -> None:
    """Write `to_png_bytes(rgba_linear, exposure_ev, curve)` to `path` (files keep Pillow's default level 6)."""
    data = to_png_bytes(rgba_linear, exposure_ev, curve, compress_level=compress_level)
    with open(path, "wb") as f:
        f.write(data)


def auto_exposure_ev(rgb: np.ndarray, alpha: np.ndarray | None = None) -> float:
    """Stops that map the median luminance of covered pixels to EXPOSURE_KEY (0.18, middle grey).

    rgb: (H, W, 3) linear (a 4th channel is used as alpha when `alpha` is None). alpha: (H, W)
    coverage; pixels with alpha > 0.5 count (all pixels when there is no alpha), but those of no light at
    all (a shadow catcher's floor, black with its shadow in alpha). Non-finite pixels
    are ignored and negative luminance counts as 0. Returns 0.0 when nothing is covered or the
    median is black, and at most +-32 stops otherwise, so the result is always finite.
    """
    a = np.asarray(rgb)
    if a.ndim < 1 or a.shape[-1] not in (3, 4):
        raise InvalidInputError(f"rgb must have shape (..., 3) or (..., 4); got {a.shape}")
    if alpha is None and a.shape[-1] == 4:
        alpha = a[..., 3]
    with np.errstate(over="ignore", invalid="ignore"):
        lum = a[..., :3].astype(np.float64) @ _LUMA  # float64: sums of huge values stay finite
    mask = np.isfinite(lum)
    if alpha is not None:
        cov = np.asarray(alpha, np.float32)
        if cov.shape == lum.shape + (1,):
            cov = cov[..., 0]
        if cov.shape != lum.shape:
            raise InvalidInputError(f"alpha must have shape {lum.shape}; got {cov.shape}")
        mask &= cov > 0.5  # NaN coverage compares False: not covered
        # A covered pixel of no light at all is a shadow catcher's floor (its shadow is its alpha alone):
        # the figure sets the exposure.
        mask &= np.any(a[..., :3] != 0, axis=-1)
    if not mask.any():
        return 0.0
    with np.errstate(over="ignore"):
        median = float(np.median(np.maximum(lum[mask], 0.0)))
    if not median > 0.0:
        return 0.0
    if not math.isfinite(median):  # float64 overflow averaging the two middle values
        return -_MAX_AUTO_EV
    return float(np.clip(math.log2(EXPOSURE_KEY) - math.log2(median), -_MAX_AUTO_EV, _MAX_AUTO_EV))
