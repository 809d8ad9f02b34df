"""Reading and writing HDR images (OpenEXR, Radiance RGBE) and checking their texels (numpy only).

Every reader returns linear radiance as float32 (H, W, 3), row 0 at the top of the image. Every failure
to read raises `EnvironmentMapError` with the file name and what is wrong with it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from pathlib import Path

import numpy as np

from renderer.errors import EnvironmentMapError, InvalidInputError

HALF_MAX = 65504.0  # largest finite IEEE 754 half float
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_RGBE_SUFFIXES = (".hdr", ".pic", ".rgbe")
_MAX_HEADER_BYTES = 1 << 16
_MAX_SIDE = 1 << 16


# ----------------------------------------------------------------------------------------------------------------
# Public entry points


def read_hdr_image(path: str | Path) -> np.ndarray:
    """Read an .exr or Radiance .hdr/.pic file as linear radiance: float32 (H, W, 3), row 0 at the top.

    EXR: RGB, RGBA (alpha dropped) or a single Y channel (copied to RGB), half or float, scanline or
    tiled; for mip/rip-mapped files the full-resolution level. The data window is placed in the
    display window (zeros outside). Radiance: see `_read_rgbe`.
    """
    path = Path(path)
    if not path.is_file():
        raise EnvironmentMapError(f"{path}: no such file")
    suffix = path.suffix.lower()
    with path.open("rb") as fh:
        magic = fh.read(4)
    # The bytes decide, not the name; a name that says otherwise is reported (a Radiance file saved as
    # .exr reads as what it is).
    kind = "exr" if magic == _EXR_MAGIC else "rgbe" if magic[:2] == b"#?" else None
    named = "exr" if suffix == ".exr" else "rgbe" if suffix in _RGBE_SUFFIXES else None
    if kind is not None and named is not None and kind != named:
        what = {"exr": "an OpenEXR file", "rgbe": "a Radiance RGBE file"}
        warnings.warn(f"{path}: named {suffix} but {what[kind]}; read as {what[kind]}", stacklevel=2)
    if kind == "exr" or (kind is None and named == "exr"):
        return _read_exr(path)
    if kind == "rgbe" or (kind is None and named == "rgbe"):
        return _read_rgbe(path)
    raise EnvironmentMapError(
        f"{path}: unsupported file type {suffix or '(no extension)'}; expected OpenEXR (.exr) or Radiance RGBE "
        f"(.hdr, .pic)")


# The primaries and white of the renderer's linear RGB, stated in every EXR written: Rec. 709 / sRGB,
# CIE 1931 xy (ITU-R BT.709-6, part 1, items 1.3 and 1.4: D65 white), in the order of OpenEXR's
# `chromaticities` attribute (red, green, blue, white). A reader that assumes another space (ACES
# AP0, say) converts from these rather than guessing.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)


def exr_header() -> dict:
    """The header of every EXR the project writes: ZIP-compressed scanlines, Rec. 709 chromaticities."""
    import OpenEXR

    return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
            "chromaticities": REC709_CHROMATICITIES}


def write_exr(path: str | Path, rgb_or_rgba: np.ndarray, half: bool = False,
              channels: dict[str, np.ndarray] | None = None) -> None:
    """Write float (H, W, 3) or (H, W, 4) as a ZIP-compressed scanline OpenEXR, float32 or half channels,
    with Rec. 709 chromaticities (`exr_header`); `channels`: more float32 channels beside them, name ->
    (H, W) (renderer/aovs.py's passes: Z, N.X, ..., id).

    With half=True, values beyond the half range (|x| > 65504) are refused rather than written as Inf.
    """
    import OpenEXR

    path = Path(path)
    arr = np.asarray(rgb_or_rgba)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InvalidInputError(f"write_exr({path}): expected an array of shape (H, W, 3) or (H, W, 4), "
                                f"got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise InvalidInputError(f"write_exr({path}): expected real numbers, got dtype {arr.dtype}")
    if half:
        finite = arr[np.isfinite(arr)]
        if finite.size and float(np.max(np.abs(finite))) > HALF_MAX:
            raise InvalidInputError(
                f"write_exr({path}): values up to {float(np.max(np.abs(finite))):.6g} exceed the half-float "
                f"range ({HALF_MAX:g}); write with half=False")
    data = np.ascontiguousarray(arr, np.float16 if half else np.float32)
    name = "RGB" if data.shape[2] == 3 else "RGBA"
    more = {}
    for channel, values in (channels or {}).items():
        values = np.ascontiguousarray(values, np.float32)
        if values.shape != data.shape[:2] or channel in name:
            raise InvalidInputError(f"write_exr({path}): channel {channel!r} must be {data.shape[:2]} and not one "
                                    f"of {name}, got {values.shape}")
        more[channel] = values
    try:
        OpenEXR.File(exr_header(), {name: data, **more}).write(str(path))
    except Exception as exc:  # the binding raises RuntimeError/ValueError/OSError variously
        raise EnvironmentMapError(f"{path}: cannot write OpenEXR file ({exc})") from exc


@dataclasses.dataclass(frozen=True)
class TexelReport:
    """What `check_texels` found: counts of channel values (not texels). n_inf counts +Inf and -Inf;
    n_negative counts finite values below zero. repaired is True when the returned image differs."""

    n_nan: int
    n_inf: int
    n_negative: int
    repaired: bool

    @property
    def clean(self) -> bool:
        return self.n_nan == 0 and self.n_inf == 0 and self.n_negative == 0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def check_texels(img: np.ndarray, *, repair: bool, name: str) -> tuple[np.ndarray, TexelReport]:
    """Find NaN, +/-Inf and negative values in img (H, W, C).

    Without repair, any such value raises `EnvironmentMapError` with the counts, the fraction of texels
    hit and the first few (row, col) positions. With repair, returns a float32 copy where NaN, -Inf and
    negative values become 0 and +Inf becomes the largest finite value of the image (the brightest
    texel the map can justify). A clean image is returned as is.
    """
    a = np.asarray(img)
    if a.ndim != 3:
        raise InvalidInputError(f"{name}: expected an image of shape (H, W, C), got {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        return a, TexelReport(0, 0, 0, False)  # integer images cannot hold NaN, Inf or be HDR-negative
    # Fast path without full-size temporaries: min/max propagate NaN.
    lo, hi = (float(np.min(a)), float(np.max(a))) if a.size else (0.0, 0.0)
    if math.isfinite(lo) and math.isfinite(hi) and lo >= 0.0:
        return a, TexelReport(0, 0, 0, False)

    nan = np.isnan(a)
    pos_inf = np.isposinf(a)
    neg_inf = np.isneginf(a)
    negative = (a < 0) & ~neg_inf
    n_nan, n_pos, n_neg_inf, n_negative = (int(np.count_nonzero(m)) for m in (nan, pos_inf, neg_inf, negative))
    report = TexelReport(n_nan, n_pos + n_neg_inf, n_negative, repaired=repair)
    if not repair:
        bad_texel = np.any(nan | pos_inf | neg_inf | negative, axis=2)
        rows, cols = np.nonzero(bad_texel)
        n_texels = a.shape[0] * a.shape[1]
        where = ", ".join(f"({r}, {c})" for r, c in zip(rows[:5].tolist(), cols[:5].tolist()))
        raise EnvironmentMapError(
            f"{name}: {n_nan} NaN, {n_pos} +Inf, {n_neg_inf} -Inf and {n_negative} negative texel values in "
            f"{rows.size} of {n_texels} texels ({100.0 * rows.size / n_texels:.3g}%); first at (row, col) "
            f"{where}{', ...' if rows.size > 5 else ''}. Load with repair=True to set NaN, -Inf and negative "
            f"values to 0 and +Inf to the largest finite value.")
    out = np.array(a, dtype=np.float32, copy=True)
    if n_pos:
        finite = a[np.isfinite(a)]
        out[pos_inf] = float(finite.max()) if finite.size else 0.0
    out[nan | neg_inf | negative] = 0.0
    return out, report


# ----------------------------------------------------------------------------------------------------------------
# OpenEXR


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    with path.open("rb") as fh:
        magic = fh.read(4)
    if magic != _EXR_MAGIC:
        raise EnvironmentMapError(f"{path}: not an OpenEXR file (bad magic number {magic!r})")
    try:
        # separate_channels keeps layer names and per-channel types; the binding reads the
        # full-resolution level (0, 0) of tiled mip- and rip-mapped files.
        exr = OpenEXR.File(str(path), separate_channels=True)
        parts = exr.parts
    except Exception as exc:  # RuntimeError for bad headers, ValueError when the pixel data is cut short
        raise EnvironmentMapError(f"{path}: truncated or corrupt OpenEXR file ({exc})") from exc
    if not parts:
        raise EnvironmentMapError(f"{path}: truncated or corrupt OpenEXR file (no readable part)")

    for part in parts:
        picked = _pick_exr_channels(part.channels)
        if picked is not None:
            break
    else:
        names = sorted(parts[0].channels)
        raise EnvironmentMapError(
            f"{path}: no colour channels; found {names}, expected R, G, B (optionally A, in any one layer) or Y")

    chans = [part.channels[n] for n in picked]
    for ch in chans:
        if ch.xSampling != 1 or ch.ySampling != 1:
            raise EnvironmentMapError(f"{path}: channel {ch.name} is subsampled ({ch.xSampling}x{ch.ySampling}); "
                                      "luminance/chroma EXR images are not supported, save as RGB")
        if ch.pixels is None or ch.pixels.dtype.kind != "f":
            dtype = None if ch.pixels is None else ch.pixels.dtype
            raise EnvironmentMapError(f"{path}: channel {ch.name} has type {dtype}; expected half or float")
    planes = [np.asarray(ch.pixels, np.float32) for ch in chans]
    rgb = np.stack(planes * 3 if len(planes) == 1 else planes, axis=-1)
    return _place_in_display_window(rgb, part.header, path)


def _pick_exr_channels(channels: dict) -> list[str] | None:
    """Names of the R, G, B channels (or the Y channel) of the first layer that has them, default layer first."""
    layers: dict[str, dict[str, str]] = {}
    for full in channels:
        layer, _, base = full.rpartition(".")
        layers.setdefault(layer, {})[base] = full
    for layer in sorted(layers, key=lambda s: (s != "", s)):
        names = layers[layer]
        if all(c in names for c in "RGB"):
            return [names["R"], names["G"], names["B"]]
        if "Y" in names and "RY" not in names and "BY" not in names:
            return [names["Y"]]
    return None


def _place_in_display_window(rgb: np.ndarray, header: dict, path: Path) -> np.ndarray:
    try:
        (dx0, dy0), (dx1, dy1) = (tuple(int(v) for v in c) for c in header["dataWindow"])
        (sx0, sy0), (sx1, sy1) = (tuple(int(v) for v in c) for c in header.get("displayWindow", header["dataWindow"]))
    except (KeyError, TypeError, ValueError):
        return np.ascontiguousarray(rgb)
    if rgb.shape[:2] != (dy1 - dy0 + 1, dx1 - dx0 + 1):
        raise EnvironmentMapError(f"{path}: pixel data {rgb.shape[:2]} does not match the data window")
    if (dx0, dy0, dx1, dy1) == (sx0, sy0, sx1, sy1):
        return np.ascontiguousarray(rgb)
    # An environment map covers the whole display window; texels outside the data window are black.
    out = np.zeros((sy1 - sy0 + 1, sx1 - sx0 + 1, 3), np.float32)
    x0, y0, x1, y1 = max(dx0, sx0), max(dy0, sy0), min(dx1, sx1), min(dy1, sy1)
    if x0 <= x1 and y0 <= y1:
        out[y0 - sy0:y1 - sy0 + 1, x0 - sx0:x1 - sx0 + 1] = rgb[y0 - dy0:y1 - dy0 + 1, x0 - dx0:x1 - dx0 + 1]
    return out


# ----------------------------------------------------------------------------------------------------------------
# Radiance RGBE
#
# Format (Ward, "Real Pixels", Graphics Gems II, 1991; Radiance src/common/color.c, header.c, resolu.c):
#   "#?RADIANCE" (or "#?RGBE") line, header lines VAR=value, an empty line, the resolution string, then
#   H scanlines of W pixels of 4 bytes (R, G, B mantissas and a shared exponent E). A scanline is either
#   flat (4*W bytes) or new-style run-length encoded: bytes 2, 2, W>>8, W&255, then the R, G, B and E
#   planes one after the other, each a sequence of runs: a count byte c > 128 followed by one byte
#   repeated c-128 times, or c in 1..128 followed by c literal bytes. Old-style RLE (pixels 1,1,1,n
#   repeating the previous pixel, pre-1991 files) is not supported: such files fail as truncated.


def _read_rgbe(path: Path) -> np.ndarray:
    data = path.read_bytes()
    height, width, flip_y, flip_x, pos = _parse_rgbe_header(data, path)
    rgbe = _decode_rgbe_pixels(data, pos, height, width, path)
    if flip_y:
        rgbe = rgbe[::-1]
    if flip_x:
        rgbe = rgbe[:, ::-1]
    return _rgbe_to_float(rgbe)


def _parse_rgbe_header(data: bytes, path: Path) -> tuple[int, int, bool, bool, int]:
    """Parse the header and resolution string; returns (H, W, flip_y, flip_x, offset of the pixel data).

    FORMAT must be 32-bit_rle_rgbe. EXPOSURE (and COLORCORR, PRIMARIES, GAMMA) are ignored: EXPOSURE
    records a multiplier already applied to the stored values (dividing by it would give the values
    before that), and like stb_image, OpenCV and the pipelines that publish HDRIs we take the stored
    values as the radiance.
    """
    if not data.startswith(b"#?"):
        raise EnvironmentMapError(f"{path}: not a Radiance RGBE file (missing the '#?RADIANCE' first line)")
    end = data.find(b"\n\n", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise EnvironmentMapError(f"{path}: Radiance header does not end (no empty line in the first "
                                  f"{min(len(data), _MAX_HEADER_BYTES)} bytes); file truncated or not RGBE")
    for raw in data[:end].split(b"\n")[1:]:
        line = raw.strip()
        if line.startswith(b"FORMAT="):
            fmt = line[len(b"FORMAT="):].strip().decode("latin-1")
            if fmt != "32-bit_rle_rgbe":
                raise EnvironmentMapError(f"{path}: pixel format {fmt!r} is not supported; expected 32-bit_rle_rgbe")
    res_end = data.find(b"\n", end + 2, end + 2 + 256)
    if res_end < 0:
        raise EnvironmentMapError(f"{path}: missing resolution line after the header; file truncated")
    res = data[end + 2:res_end].decode("latin-1", "replace").split()
    try:
        (ay, sh, ax, sw) = res
        height, width = int(sh), int(sw)
    except ValueError:
        raise EnvironmentMapError(
            f"{path}: bad resolution line {' '.join(res)!r}; expected '-Y <height> +X <width>'") from None
    if ay not in ("-Y", "+Y") or ax not in ("+X", "-X"):
        raise EnvironmentMapError(
            f"{path}: orientation '{ay} {sh} {ax} {sw}' is not supported; only row-major orientations "
            "('-Y H +X W', the standard, and its flips '+Y', '-X') can be read. Re-save the image in the "
            "standard orientation")
    if not (0 < height <= _MAX_SIDE and 0 < width <= _MAX_SIDE):
        raise EnvironmentMapError(f"{path}: implausible image size {width}x{height}")
    return height, width, ay == "+Y", ax == "-X", res_end + 1


def _decode_rgbe_pixels(data: bytes, pos: int, height: int, width: int, path: Path) -> np.ndarray:
    """Decode H scanlines starting at byte pos into uint8 (H, W, 4); one Python iteration per scanline."""
    buf = np.frombuffer(data, np.uint8)
    n = len(data)
    out = np.empty((height, width, 4), np.uint8)
    rle_width_ok = 8 <= width <= 0x7FFF  # writers use flat scanlines outside this range
    for y in range(height):
        if pos + 4 <= n and rle_width_ok and data[pos] == 2 and data[pos + 1] == 2 and data[pos + 2] < 128:
            declared = (data[pos + 2] << 8) | data[pos + 3]
            if declared != width:
                raise EnvironmentMapError(f"{path}: scanline {y} declares width {declared}, the image is {width} "
                                          "wide; file corrupt")
            pos = _decode_rle_scanline(buf, pos + 4, width, out[y], y, path)
        else:
            if pos + 4 * width > n:
                raise EnvironmentMapError(
                    f"{path}: truncated: pixel data ends in scanline {y} of {height} (or the file uses old-style "
                    "run-length encoding, which is not supported)")
            out[y] = buf[pos:pos + 4 * width].reshape(width, 4)
            pos += 4 * width
    return out


@functools.lru_cache(maxsize=8)
def _arange(n: int) -> np.ndarray:
    # 0..n-1, cached: the scanline decoder asks for the same few lengths once per scanline.
    a = np.arange(n, dtype=np.int32)
    a.setflags(write=False)
    return a


class _CorruptRun(Exception):
    pass


def _decode_rle_scanline(buf: np.ndarray, start: int, width: int, row_out: np.ndarray, y: int, path: Path) -> int:
    """Decode one new-style RLE scanline at buf[start:] into row_out (W, 4); returns the offset after it.

    The runs form a chain (each count byte says where the next one is), which is sequential. Instead
    of walking it run by run in Python we find all chain nodes at once by pointer doubling (list
    ranking, Wyllie 1979): with jump tables J_k = next^(2^k), the set {0} closed under J_K-1..J_0 is
    every node within 2^K steps. Nodes past the scanline's end are cut off by the running value count.
    """
    n_values = 4 * width
    avail = len(buf) - start
    # Typical scanlines need ~4W(1 + 1/128) bytes; the worst case (literal runs of one) needs 8W.
    span = min(avail, n_values + n_values // 32 + 64)
    while True:
        try:
            result = _rle_chain(buf[start:start + span], n_values)
        except _CorruptRun as exc:
            raise EnvironmentMapError(f"{path}: corrupt run-length data in scanline {y} ({exc})") from None
        if result is not None:
            nodes, counts, end = result
            break
        if span >= min(avail, 2 * n_values):
            raise EnvironmentMapError(f"{path}: truncated: run-length data ends in scanline {y}")
        span = min(avail, 2 * n_values)
    win = buf[start:start + end]
    c = win[nodes]
    starts = np.cumsum(counts) - counts
    # A run must not spill from one channel plane into the next (Radiance reports this as overrun).
    boundaries = np.arange(1, 4) * width
    at = np.minimum(np.searchsorted(starts, boundaries), starts.size - 1)
    if not np.array_equal(starts[at], boundaries):
        raise EnvironmentMapError(f"{path}: corrupt run-length data in scanline {y} (a run crosses a channel)")
    owner = np.repeat(np.arange(nodes.size), counts)
    offset = np.arange(n_values) - starts[owner]
    src = nodes[owner] + 1 + np.where(c[owner] > 128, 0, offset)
    row_out[:] = win[src].reshape(4, width).T
    return start + end


def _rle_chain(win: np.ndarray, n_values: int):
    """Chain nodes (count-byte offsets), their value counts and the end offset of one scanline within win,
    or None when the scanline does not end inside win; raises _CorruptRun on impossible data."""
    n = win.size
    if n == 0:
        return None
    c = win.astype(np.int32)
    is_run = c > 128
    counts_all = np.where(is_run, c - 128, c)
    nxt = np.empty(n + 1, np.int32)  # node n is the sentinel "past the window"
    np.add(_arange(n), np.where(is_run, 2, c + 1), out=nxt[:n])
    np.minimum(nxt, n, out=nxt)
    nxt[n] = n
    # Double until a jump from node 0 leaves the window: then 2^K exceeds the chain's length in it.
    jumps = [nxt]
    while jumps[-1][0] < n:
        jumps.append(jumps[-1][jumps[-1]])
    on_chain = np.zeros(n + 1, bool)
    on_chain[0] = True
    for jump in reversed(jumps):
        on_chain[jump[on_chain]] = True
    nodes = np.flatnonzero(on_chain[:n])
    counts = counts_all[nodes]
    total = np.cumsum(counts)
    last = int(np.searchsorted(total, n_values))  # first node that reaches n_values
    if last == nodes.size:
        return None
    if total[last] != n_values:
        raise _CorruptRun("the last run overshoots the scanline")
    if np.any(counts[:last + 1] == 0):
        raise _CorruptRun("a run of length zero")  # never written; stb_image rejects it too
    end = int(nodes[last]) + (2 if is_run[nodes[last]] else int(c[nodes[last]]) + 1)
    if end > n:
        return None
    return nodes[:last + 1], counts[:last + 1], end


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    # value = mantissa * 2^(E - 136), 0 when E == 0: Walter's rgbe.c (used by OpenCV and stb_image).
    # Radiance's colr_color adds 0.5 to the mantissa; we follow the more common convention so values
    # match other tools bit for bit (e.g. rooitou_park's sun is 135 * 2^9 = 69120).
    exponent = rgbe[..., 3].astype(np.int32)
    scale = np.where(exponent == 0, np.float32(0), np.ldexp(np.float32(1), exponent - 136).astype(np.float32))
    rgb = rgbe[..., :3].astype(np.float32)
    rgb *= scale[..., None]  # in place: a 16k map is 1.5 GiB as float32
    return rgb
