"""Bytes in, bytes out: frame bodies to validated arrays, rendered images to PNG/EXR, uploaded HDR files
to pixels. All of it runs off the GL thread (in worker threads of the request handlers).

Frame body layout (header `X-Frame-Layout`, or query `layout`; default `positions`): a comma-separated
list of blocks, concatenated in that order, each V x 3 little-endian float32 for the mesh it names:

    positions         the garment's vertex positions (required unless body_positions is given)
    normals           the garment's vertex normals (optional; computed here when absent)
    body_positions    the body's positions (scenes with a body; the body keeps its last pose otherwise)
    body_normals      the body's normals

Positions and normals are in the scene's up axis (rotated to the renderer's Y-up here).
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from renderer.envmap import exr_header, read_hdr_image
from renderer.errors import EnvironmentMapError, MeshError
from renderer.mesh import Mesh, vertex_normals, z_up_to_y_up
from renderer.shading.tonemap import PNG_SRGB_CHUNKS, auto_exposure_ev, encode_rgba8, tonemap

from .errors import InvalidRequestError, PayloadTooLargeError
from .registry import SceneRecord

BLOCKS = ("positions", "normals", "body_positions", "body_normals")
_BLOCK_MESH = {"positions": "garment", "normals": "garment", "body_positions": "body", "body_normals": "body"}


# -- frame bodies ----------------------------------------------------------------------------------


@dataclass
class FrameArrays:
    """One decoded frame: per scene mesh (garment, body) positions and normals, float32 (V, 3) Y-up, or None."""

    positions: list[np.ndarray | None]
    normals: list[np.ndarray | None]
    decode_ms: float = 0.0
    normals_ms: float = 0.0


def parse_layout(text: str | None, scene: SceneRecord) -> list[str]:
    """The blocks of a frame body, validated against the scene."""
    if text is None or not text.strip():
        return ["positions"]
    blocks = [b.strip().lower() for b in text.split(",") if b.strip()]
    for b in blocks:
        if b not in BLOCKS:
            raise InvalidRequestError(f"unknown block {b!r} in frame layout {text!r}; blocks are {', '.join(BLOCKS)}")
        if scene.mesh(_BLOCK_MESH[b]) is None:
            raise InvalidRequestError(f"frame layout {text!r} names {b!r} but scene {scene.id} has no body mesh")
    if len(set(blocks)) != len(blocks):
        raise InvalidRequestError(f"frame layout {text!r} names a block twice")
    if "positions" not in blocks and "body_positions" not in blocks:
        raise InvalidRequestError(f"frame layout {text!r} has no positions block; normals come with positions")
    for n, p in (("normals", "positions"), ("body_normals", "body_positions")):
        if n in blocks and p not in blocks:
            raise InvalidRequestError(f"frame layout {text!r} has {n} without {p}")
    return blocks


def frame_nbytes(blocks: list[str], scene: SceneRecord) -> int:
    return sum(12 * scene.mesh(_BLOCK_MESH[b]).n_vertices for b in blocks)


def _size_hint(got: int, expected: int) -> str:
    if got == 2 * expected:
        return " (twice the size: float64 data? send float32)"
    if got == 0:
        return " (the body is empty)"
    if got % 12 == 0:
        return f" (that is {got // 12} xyz float32 triples: a frame of another mesh, or another layout?)"
    return f" ({got} is not a multiple of 12 bytes per vertex)"


def check_frame_size(got: int, blocks: list[str], scene: SceneRecord) -> int:
    expected = frame_nbytes(blocks, scene)
    if got != expected:
        parts = " + ".join(f"{b} {scene.mesh(_BLOCK_MESH[b]).n_vertices} x 3 x 4" for b in blocks)
        raise InvalidRequestError(
            f"frame body has {got} bytes, scene {scene.id} expects {expected} bytes for layout "
            f"'{','.join(blocks)}' ({parts}, little-endian float32){_size_hint(got, expected)}")
    return expected


def decode_frame(data: bytes | memoryview, blocks: list[str], scene: SceneRecord,
                 compute_normals: bool = True) -> FrameArrays:
    """Validate and decode one frame (size, NaN/Inf, zero normals), rotate to Y-up, and compute the
    missing normals (`compute_normals` False: left to the renderer's GPU pass)."""
    import time

    t0 = time.perf_counter()
    check_frame_size(memoryview(data).nbytes, blocks, scene)
    roles = [m.role for m in scene.meshes]
    positions: list[np.ndarray | None] = [None] * len(roles)
    normals: list[np.ndarray | None] = [None] * len(roles)
    view = memoryview(data)
    offset = 0
    for b in blocks:
        mesh = scene.mesh(_BLOCK_MESH[b])
        n = mesh.n_vertices
        chunk = view[offset:offset + 12 * n]
        offset += 12 * n
        i = roles.index(mesh.role)
        if b.endswith("positions"):
            try:
                p = Mesh.positions_from_bytes(chunk, n)
            except MeshError as e:
                raise MeshError(f"{b} block: {e}") from None
            positions[i] = z_up_to_y_up(p) if scene.up == "z" else p
        else:
            normals[i] = _normals(chunk, n, b, scene.up)
    t1 = time.perf_counter()
    for i, mesh in enumerate(scene.meshes):
        if compute_normals and positions[i] is not None and normals[i] is None:
            normals[i] = vertex_normals(positions[i], mesh.faces)
    t2 = time.perf_counter()
    return FrameArrays(positions, normals, (t1 - t0) * 1e3, (t2 - t1) * 1e3)


def _normals(chunk: memoryview, n: int, block: str, up: str) -> np.ndarray:
    a = np.frombuffer(chunk, dtype="<f4").reshape(n, 3).astype(np.float32)
    finite = np.isfinite(a).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise MeshError(f"{block} block: NaN/Inf normals at {bad.size} of {n} vertices (first at vertex {bad[0]})")
    length = np.linalg.norm(a, axis=1)
    if np.any(length == 0):
        bad = np.flatnonzero(length == 0)
        raise MeshError(f"{block} block: zero-length normals at {bad.size} of {n} vertices (first at vertex {bad[0]}); "
                        "leave normals out of the layout to have them computed")
    a /= length[:, None]
    return z_up_to_y_up(a) if up == "z" else a


# -- images ----------------------------------------------------------------------------------------


def encode_png(image: np.ndarray, exposure_ev: float | None, tone: str, opaque: bool,
               compress_level: int = 1) -> tuple[bytes, float]:
    """8-bit sRGB PNG of a linear (H, W, 4) render; RGB when `opaque` (the map fills the background),
    else RGBA with coverage alpha. exposure_ev None: automatic (`frame_exposure_ev`).
    Returns (png, exposure used). The tone curve and sRGB encoding are the renderer's (tonemap.py)."""
    ev = frame_exposure_ev(image) if exposure_ev is None else float(exposure_ev)
    return png_bytes(encode_pixels(image, ev, tone, opaque), compress_level), ev


def encode_pixels(image: np.ndarray, exposure_ev: float, tone: str, opaque: bool) -> np.ndarray:
    """The 8-bit sRGB pixels of `encode_png`: uint8 (H, W, 3) when `opaque`, else (H, W, 4)."""
    if opaque:
        rgb = tonemap(image[..., :3], exposure_ev, tone)
        return np.rint(np.clip(rgb, 0.0, 1.0, out=rgb) * np.float32(255.0)).astype(np.uint8)
    return encode_rgba8(image, exposure_ev, tone)


def frame_exposure_ev(image: np.ndarray) -> float:
    """Automatic exposure (renderer's `auto_exposure_ev`: median covered luminance -> middle grey) on
    every other pixel of every other row: the median of a quarter of the pixels differs by a
    few thousandths of a stop on rendered frames and costs a fifth of the time (~1 ms at 512^2)."""
    sub = image[::2, ::2]
    return auto_exposure_ev(sub[..., :3], sub[..., 3])


def png_bytes(pixels: np.ndarray, compress_level: int = 1) -> bytes:
    """An sRGB PNG of uint8 (H, W, 3|4), written directly: every row with filter type 2 ("Up", the byte
    difference to the row above; PNG spec section 9.2) computed by numpy, then one zlib stream; the
    colour space chunks are the renderer's (`PNG_SRGB_CHUNKS`), as Pillow writes them there.
    At level 1 this is ~3x faster than Pillow's adaptive filtering for the same size on rendered
    frames (5 ms vs 15 ms at 512^2), which is what keeps encoding a small share of a frame."""
    h, w, c = pixels.shape
    flat = np.ascontiguousarray(pixels).reshape(h, w * c)
    raw = np.empty((h, 1 + w * c), np.uint8)
    raw[:, 0] = 2
    raw[0, 1:] = flat[0]
    np.subtract(flat[1:], flat[:-1], out=raw[1:, 1:])  # uint8 arithmetic wraps modulo 256, as PNG wants

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    colour_type = {3: 2, 4: 6}[c]  # truecolour, truecolour with alpha
    header = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + b"".join(chunk(k, d) for k, d in PNG_SRGB_CHUNKS)
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), compress_level)) + chunk(b"IEND", b""))


def encode_exr(image: np.ndarray, channels: dict[str, np.ndarray] | None = None) -> bytes:
    """Linear scene radiance as an RGBA float32 OpenEXR (alpha = coverage), ZIP-compressed scanlines,
    with the renderer's header (`exr_header`: its Rec. 709 chromaticities); `channels`: the passes
    beside it (renderer.aovs.exr_channels)."""
    import OpenEXR

    buf = io.BytesIO()
    OpenEXR.File(exr_header(), {"RGBA": np.ascontiguousarray(image, np.float32), **(channels or {})}).write(buf)
    return buf.getvalue()


# -- uploaded environment maps ---------------------------------------------------------------------

_EXR_MAGIC = b"\x76\x2f\x31\x01"


def sniff_hdr_kind(data: bytes) -> str:
    """"exr" or "hdr" from the first bytes; InvalidRequestError naming what the bytes look like otherwise."""
    if data[:4] == _EXR_MAGIC:
        return "exr"
    if data[:2] == b"#?":
        return "hdr"
    looks = {b"\x89PNG": "a PNG image", b"\xff\xd8\xff": "a JPEG image", b"GIF8": "a GIF image",
             b"PK\x03\x04": "a zip archive", b"{": "JSON"}
    what = next((v for k, v in looks.items() if data.startswith(k)), f"first bytes {data[:8]!r}")
    raise InvalidRequestError(
        f"the upload is not an OpenEXR or Radiance HDR file ({what}); send the .exr/.hdr file's bytes as they are")


def hdr_dimensions(data: bytes, kind: str) -> tuple[int, int] | None:
    """(width, height) from the header, to refuse huge maps before decoding; None when the header is
    unreadable (the decoder then reports exactly what is wrong)."""
    try:
        if kind == "exr":
            import OpenEXR

            header = OpenEXR.File(io.BytesIO(data), header_only=True).header()
            (x0, y0), (x1, y1) = header.get("displayWindow", header["dataWindow"])
            (dx0, dy0), (dx1, dy1) = header["dataWindow"]
            return max(int(x1 - x0), int(dx1 - dx0)) + 1, max(int(y1 - y0), int(dy1 - dy0)) + 1
        end = data.find(b"\n\n", 0, 1 << 16)
        line_end = data.find(b"\n", end + 2, end + 2 + 256)
        if end < 0 or line_end < 0:
            return None
        _, h, _, w = data[end + 2:line_end].split()
        return int(w), int(h)
    except Exception:
        return None


@contextlib.contextmanager
def uploaded_file(data: bytes, extension: str, prefix: str):
    """The bytes of an upload as a temporary file with the given extension (the readers pick their
    format from it), removed afterwards: yields its Path."""
    fd, tmp = tempfile.mkstemp(suffix="." + extension, prefix=prefix)
    path = Path(tmp)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        yield path
    finally:
        path.unlink(missing_ok=True)


def decode_hdr(data: bytes, kind: str, name: str, max_pixels: int, room=None) -> np.ndarray:
    """Decode an uploaded .exr/.hdr file into float32 (H, W, 3) with the renderer's readers, after
    its header's size passed `max_pixels` and `room(bytes, what)` (the environments' memory budget)."""
    dims = hdr_dimensions(data, kind)
    if dims is not None and dims[0] * dims[1] > max_pixels:
        raise PayloadTooLargeError(
            f"environment map {name!r} is {dims[0]}x{dims[1]} = {dims[0] * dims[1]} pixels, more than the limit "
            f"{max_pixels} (GARMENT_RENDER_MAX_ENV_PIXELS); downscale it (a 2k lat-long map is plenty for lighting)")
    if dims is not None and room is not None:
        room(dims[0] * dims[1] * 12, f"environment map {name!r} ({dims[0]}x{dims[1]}, decoded)")
    with uploaded_file(data, kind, "upload-") as path:
        try:
            return read_hdr_image(path)
        except EnvironmentMapError as e:
            raise EnvironmentMapError(str(e).replace(str(path), f"uploaded file {name!r}")) from None
        except (ValueError, RuntimeError, OSError) as e:  # a reader failure that slipped past the typed ones
            raise EnvironmentMapError(f"uploaded file {name!r}: cannot decode ({type(e).__name__}: {e})") from None
