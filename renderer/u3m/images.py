"""A U3M image decoded into the float32 array a renderer samples.

The spec (u3m_additional_spec.txt, "colors") tells colour images from data images: a colour image
(basecolor, subsurface_color) honours its embedded ICC profile and is assumed sRGB without one; a data
image (normal, roughness, metalness, alpha, displacement, every scalar) ignores any profile. So:

- colour: converted with Pillow's ImageCms (LittleCMS) from its profile to sRGB, relative colorimetric
  intent, then decoded to linear with the sRGB EOTF: linear Rec. 709 / sRGB primaries, D65, float32,
  (H, W, 3). Colours outside sRGB's gamut are clipped by that conversion. ImageCms transforms 8-bit
  pixels only, so a 16-bit colour image with a profile is converted at 8 bits a channel; a 16-bit one
  without a profile keeps its 16 bits (the EOTF is applied to every code value exactly).
- data: the stored code values over their maximum (255 or 65535), float32 in [0, 1]; a normal map
  (H, W, 3) as stored (decode with 2 v - 1, `NormalTexture.values`), a scalar image (H, W), its colour
  channels averaged as the schema says ("converted to grayscale by averaging the 3 channels").

An alpha channel in a colour or normal image is dropped (U3M's alpha is a field of its own). Row 0 is
the image's top row as stored. Formats: the spec's baseline, PNG, JPEG and TIFF (IMAGE_FORMATS); Pillow
is not asked to identify anything else. The declared size is judged from the header before any pixel
is decoded.
"""

from __future__ import annotations

import functools
import io
import re
import struct
import sys
import zlib
from enum import Enum

import numpy as np
from PIL import Image, ImageCms, UnidentifiedImageError

from ..errors import MaterialError
from ..shading.tonemap import srgb_eotf

IMAGE_FORMATS = ("PNG", "JPEG", "TIFF")   # the spec's baseline formats (u3m_additional_spec_u3m.txt)


class ImageKind(Enum):
    """How an image's values are read (module docstring)."""

    COLOR = "color"
    SCALAR = "scalar"
    NORMAL = "normal"


# Exceptions Pillow raises on a corrupt or truncated file (PIL/ImageFile.py, the decoders, ImageCms).
_DECODE_ERRORS = (OSError, SyntaxError, ValueError, struct.error, EOFError, zlib.error, IndexError, KeyError,
                  TypeError, ImageCms.PyCMSError)


def open_image(data: bytes, *, file: str, field: str, max_pixels: int) -> Image.Image:
    """The image in `data`, its header read and its pixels not yet decoded; refused when the header
    declares more than `max_pixels` (U3MLimits.max_image_pixels). `file` and `field` name it in errors."""
    try:
        im = Image.open(io.BytesIO(data), formats=IMAGE_FORMATS)
    except Image.DecompressionBombError as e:   # Pillow's own bound (Image.MAX_IMAGE_PIXELS), over ours
        declared = re.search(r"\((\d+) pixels\)", str(e))
        raise MaterialError(f"the image declares {declared.group(1) + ' px' if declared else 'too many pixels'}, over "
                            f"Pillow's bound; the limit is {max_pixels} px (U3MLimits.max_image_pixels)", file=file,
                            field=field) from None
    except UnidentifiedImageError:
        raise MaterialError("is not an image in a format this reader decodes (PNG, JPEG or TIFF, the spec's "
                            "baseline), or is corrupt", file=file, field=field) from None
    except _DECODE_ERRORS as e:
        raise MaterialError(f"cannot be read as an image: {e}", file=file, field=field) from None
    w, h = im.size
    if w <= 0 or h <= 0:
        raise MaterialError(f"the image is empty ({w} x {h} px)", file=file, field=field)
    if w * h > max_pixels:
        raise MaterialError(f"the image declares {w} x {h} px ({w * h} px); the limit is {max_pixels} px "
                            "(U3MLimits.max_image_pixels)", file=file, field=field)
    return im


def decode_image(data: bytes, kind: ImageKind, *, file: str, field: str, max_pixels: int) -> np.ndarray:
    """The image in `data` as a read-only float32 array (module docstring), refused before its pixels
    are decoded as `open_image` says."""

    def fail(reason: str) -> MaterialError:
        return MaterialError(reason, file=file, field=field)

    im = open_image(data, file=file, field=field, max_pixels=max_pixels)
    try:
        out = _color(im, data, fail) if kind is ImageKind.COLOR else _data(im, data, kind, fail)
    except MaterialError:
        raise
    except MemoryError:
        raise fail(f"no memory to decode {im.size[0]} x {im.size[1]} px") from None
    except _DECODE_ERRORS as e:
        raise fail(f"cannot be decoded (corrupt or truncated?): {e}") from None
    out.flags.writeable = False
    return out


@functools.cache
def _srgb_profile() -> ImageCms.ImageCmsProfile:
    return ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))


@functools.cache
def _eotf_table(top: int) -> np.ndarray:
    """The sRGB EOTF of every code value 0..top: decoding by table lookup is exact and allocates the
    float32 result only."""
    return srgb_eotf(np.arange(top + 1, dtype=np.float64) / top)


def _color(im: Image.Image, data: bytes, fail) -> np.ndarray:
    icc = im.info.get("icc_profile")
    if not icc:
        raw, top = _raw(im, data)
        rgb = raw[..., :3] if raw.shape[2] >= 3 else raw[..., :1].repeat(3, axis=2)
        if top is None:   # float samples: taken as sRGB-encoded [0, 1]
            return srgb_eotf(rgb)
        return _eotf_table(top)[rgb]
    try:
        source = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    except (ImageCms.PyCMSError, OSError, ValueError, TypeError) as e:
        raise fail(f"its embedded ICC profile cannot be read: {e}") from None
    eight = _eight_bit(im)
    try:
        srgb = ImageCms.profileToProfile(eight, source, _srgb_profile(),
                                         renderingIntent=ImageCms.Intent.RELATIVE_COLORIMETRIC, outputMode="RGB")
    except ImageCms.PyCMSError as e:
        space = getattr(source.profile, "xcolor_space", "?").strip()
        raise fail(f"its embedded ICC profile ({space}) cannot convert its {eight.mode} pixels: {e}") from None
    return _eotf_table(255)[np.asarray(srgb)]


def _eight_bit(im: Image.Image) -> Image.Image:
    """The image in a mode ImageCms transforms (8 bits a channel: L, RGB or CMYK)."""
    if im.mode in ("L", "RGB", "CMYK"):
        return im
    if im.mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
        values = np.clip(np.asarray(im).astype(np.int64), 0, 65535)
        return Image.fromarray(((values + 128) // 257).astype(np.uint8), "L")
    if im.mode in ("1", "LA", "La"):
        return im.convert("L")
    return im.convert("RGB")


def _data(im: Image.Image, data: bytes, kind: ImageKind, fail) -> np.ndarray:
    raw, top = _raw(im, data)
    channels = raw.shape[2]
    scale = np.float32(1.0 if top is None else 1.0 / top)
    if kind is ImageKind.NORMAL:
        if channels < 3:
            raise fail(f"a normal map has 3 channels (RGB); this image has {channels} ({im.mode})")
        out = raw[..., :3].astype(np.float32)
        out *= scale
        return out
    if channels >= 3:
        out = raw[..., :3].sum(axis=2, dtype=np.float32)
        out *= scale / np.float32(3.0)
        return out
    out = raw[..., 0].astype(np.float32)
    out *= scale
    return out


def _raw(im: Image.Image, data: bytes) -> tuple[np.ndarray, int | None]:
    """The stored code values, (H, W, C) uint8 or uint16 (C = 1 to 4), and the largest code value
    (None for float samples)."""
    wide = _rgb16(im, data)
    if wide is not None:
        return wide, 65535
    im.load()
    mode = im.mode
    if mode in ("I;16", "I;16L", "I;16B", "I;16N"):
        return np.asarray(im).astype(np.uint16)[..., None], 65535
    if mode == "I":   # 16-bit greyscale as some readers open it (32-bit integers), or a 32-bit TIFF
        return np.clip(np.asarray(im), 0, 65535).astype(np.uint16)[..., None], 65535
    if mode == "F":
        return np.asarray(im, dtype=np.float32)[..., None], None
    if mode == "1":
        im = im.convert("L")
    elif mode == "La":
        im = im.convert("LA")
    elif mode not in ("L", "LA", "RGB", "RGBA"):   # palette, CMYK, YCbCr, LAB, premultiplied RGBa
        im = im.convert("RGBA" if mode in ("PA", "RGBa") or "transparency" in im.info else "RGB")
    raw = np.asarray(im)
    return (raw if raw.ndim == 3 else raw[..., None]), 255


# Pillow's unpackers for 16-bit RGB keep each sample's high byte (its RGB modes hold 8 bits); the same
# rawmode with the other byte order keeps the low byte instead. Big-, little-, native-endian.
_OTHER_ORDER = {";16B": ";16L", ";16L": ";16B", ";16N": ";16B" if sys.byteorder == "little" else ";16L"}


def _rawmode(args) -> str | None:
    if isinstance(args, str):
        return args
    return args[0] if isinstance(args, tuple) and args and isinstance(args[0], str) else None


def _with_rawmode(args, rawmode: str):
    return rawmode if isinstance(args, str) else (rawmode, *args[1:])


def _rgb16(im: Image.Image, data: bytes) -> np.ndarray | None:
    """A 16-bit RGB(A) image's samples with their 16 bits, or None for any other image. Pillow decodes
    such an image to 8 bits (the high byte of each sample); it is decoded a second time with the
    rawmode of the other byte order, which unpacks the low bytes through the same decompression and
    PNG/TIFF unfiltering (the filters work on the whole 6- or 8-byte pixel in both), and the two are
    joined."""
    if im.mode not in ("RGB", "RGBA") or not im.tile:
        return None
    rawmodes = {_rawmode(tile.args) for tile in im.tile}
    if len(rawmodes) != 1:
        return None
    rawmode = rawmodes.pop()
    if rawmode is None or rawmode[-4:] not in _OTHER_ORDER or rawmode.split(";")[0] not in ("RGB", "RGBA", "RGBX"):
        return None
    other = rawmode[:-4] + _OTHER_ORDER[rawmode[-4:]]
    low = Image.open(io.BytesIO(data), formats=IMAGE_FORMATS)
    low.tile = [tile._replace(args=_with_rawmode(tile.args, other)) for tile in low.tile]
    im.load()
    low.load()
    wide = np.asarray(im).astype(np.uint16)
    wide <<= 8
    wide |= np.asarray(low)
    return wide
