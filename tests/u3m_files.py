"""U3M documents, archives and images written by hand from the spec (../shared/specs/u3m), for the tests
of renderer/u3m: every field of a visualisation in both schema versions, PNGs and TIFFs of 8 and 16 bits
(the 16-bit RGB writers are ours: Pillow writes none), JPEGs, and an ICC profile that is not sRGB."""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
from PIL import Image

from renderer.u3m import FIELDS, ImageKind

UUID = "{45d231aa-96a0-4d94-9aae-4a99fae0e32a}"   # a UUID4 of variant 1, as 1.1's pattern wants


# -- documents -------------------------------------------------------------------------------------

def image(path: str, version: str, width_mm=40.0, height_mm=20.0, dpi=300.0, rotation=0.0, mode="normal") -> dict:
    """An `image` object: 1.0 gives dpi as one number, 1.1 as {x, y}."""
    return {"path": path, "width": width_mm, "height": height_mm,
            "dpi": dpi if version == "1.0" else {"x": dpi, "y": dpi},
            "repeat": {"rotation": rotation, "mode": mode}}


def scalar(constant: float, texture: dict | None = None) -> dict:
    return {"constant": constant, "texture": texture}


def scalar_texture(img: dict, factor=1.0, offset=0.0) -> dict:
    return {"factor": factor, "offset": offset, "image": img}


def color(rgb=(1.0, 1.0, 1.0), texture: dict | None = None) -> dict:
    return {"constant": dict(zip("rgb", rgb)), "texture": texture}


def color_texture(img: dict, factor=(1.0, 1.0, 1.0), mode="multiply") -> dict:
    return {"mode": mode, "factor": dict(zip("rgb", factor)), "image": img}


def normal(version: str, texture_image: dict | None = None, scale=1.0, xyz=(0.0, 0.0, 1.0)) -> dict:
    """1.1: {constant: {x, y, z}, texture: {scale, image}}; 1.0 declares normals as numbers."""
    if version == "1.0":
        return {"constant": 0, "texture": None if texture_image is None else scalar_texture(texture_image)}
    return {"constant": dict(zip("xyz", xyz)),
            "texture": None if texture_image is None else {"scale": scale, "image": texture_image}}


def visualisation(version: str, **fields) -> dict:
    """Every field of a visualisation as its default constant, `fields` over them."""
    out: dict = {}
    for name, (kind, default) in FIELDS.items():
        if kind is ImageKind.SCALAR:
            out[name] = scalar(default)
        elif kind is ImageKind.COLOR:
            out[name] = color(default)
        else:
            out[name] = normal(version)
    out["shader"] = "principled"
    if version == "1.1":
        out["preview"] = None
    out.update(fields)
    return out


def document(version: str, front: dict | None, back: dict | None = None, side: dict | None = None,
             physics: dict | None = None, name="Hand-written fabric") -> dict:
    material = {"id": UUID, "name": name, "description": "written from the spec by hand",
                "created": "2024-05-01T10:00:00+02:00", "modified": "2024-05-01T10:00:00+02:00",
                "front": front, "back": back}
    if version == "1.1":
        material.update(side=side, physics=physics, metadata=None)
    return {"schema": version, "material": material, "custom": None}


def physics(thickness_mm=0.6, weight=180.0) -> dict:
    return {"thickness": thickness_mm, "weight": weight, "composition": None, "devices": {"fab": "null"},
            "material_type": None, "construction": None}


def write_u3m(folder: Path, doc: dict | bytes, images: dict[str, bytes], name="fabric.u3m") -> Path:
    """A `.u3m` document and its images in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    for path, data in images.items():
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_bytes(data)
    target = folder / name
    target.write_bytes(doc if isinstance(doc, bytes) else json.dumps(doc, indent=2).encode())
    return target


def u3ma_bytes(doc: dict | bytes, images: dict[str, bytes], document_name="fabric.u3m") -> bytes:
    """A `.u3ma`: the document and its images in one zip (deflated, as the spec allows)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr(document_name, doc if isinstance(doc, bytes) else json.dumps(doc, indent=2))
        for path, data in images.items():
            z.writestr(path, data)
    return buf.getvalue()


def write_u3ma(path: Path, doc: dict | bytes, images: dict[str, bytes], document_name="fabric.u3m") -> Path:
    path.write_bytes(u3ma_bytes(doc, images, document_name))
    return path


# -- images ----------------------------------------------------------------------------------------

def encode(array: np.ndarray, fmt="PNG", **options) -> bytes:
    """An 8-bit (uint8) or 16-bit greyscale (uint16, 2-D) image through Pillow."""
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, fmt, **options)
    return buf.getvalue()


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


_COLOR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}   # channels -> PNG colour type (grey, grey+alpha, RGB, RGBA)


def png16(values: np.ndarray) -> bytes:
    """A 16-bit PNG of `values` (H, W, C) uint16, C = 1 to 4, its rows filtered with each of the five
    PNG filters in turn (PNG 1.2 section 6) so that a reader's unfiltering is exercised on 6- and
    8-byte pixels."""
    h, w, c = values.shape
    rows = values.astype(">u2").reshape(h, w * c).view(np.uint8).astype(np.int32)
    bpp = 2 * c
    prior = np.zeros(rows.shape[1], np.int32)
    out = []
    for y in range(h):
        x = rows[y]
        a = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        b = prior
        cc = np.concatenate([np.zeros(bpp, np.int32), prior[:-bpp]])
        kind = y % 5
        if kind == 0:
            filtered = x
        elif kind == 1:
            filtered = x - a
        elif kind == 2:
            filtered = x - b
        elif kind == 3:
            filtered = x - (a + b) // 2
        else:
            p = a + b - cc
            pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - cc)
            filtered = x - np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, cc))
        out.append(bytes([kind]) + (filtered % 256).astype(np.uint8).tobytes())
        prior = x
    header = struct.pack(">IIBBBBB", w, h, 16, _COLOR_TYPES[c], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(b"".join(out)))
            + _chunk(b"IEND", b""))


def png_header_only(width: int, height: int) -> bytes:
    """A PNG that declares width x height px of 8-bit RGB and holds almost no data: the kind of file
    that would ask a careless reader for width * height * 3 bytes."""
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(b"\x00" * 4096))
            + _chunk(b"IEND", b""))


def tiff16(values: np.ndarray, big_endian: bool = False) -> bytes:
    """An uncompressed baseline TIFF (TIFF 6.0, section 6: one strip, chunky) of `values` (H, W, C)
    uint16, C = 3 (RGB) or 4 (RGBA, unassociated alpha), in either byte order."""
    h, w, c = values.shape
    e = ">" if big_endian else "<"
    pixels = values.astype(e + "u2").tobytes()
    entries = [(256, 3, 1, w), (257, 3, 1, h), (258, 3, c, None), (259, 3, 1, 1), (262, 3, 1, 2),
               (273, 4, 1, None), (277, 3, 1, c), (278, 3, 1, h), (279, 4, 1, len(pixels)), (284, 3, 1, 1)]
    if c == 4:
        entries.append((338, 3, 1, 2))   # ExtraSamples: unassociated alpha
    ifd_at = 8
    bits_at = ifd_at + 2 + 12 * len(entries) + 4
    data_at = bits_at + 2 * c + (2 * c) % 4
    table = b""
    for tag, kind, count, value in entries:
        if tag == 258:
            field = struct.pack(e + "I", bits_at)
        elif tag == 273:
            field = struct.pack(e + "I", data_at)
        elif kind == 3:
            field = struct.pack(e + "HH", value, 0)
        else:
            field = struct.pack(e + "I", value)
        table += struct.pack(e + "HHI", tag, kind, count) + field
    blob = ((b"MM\x00*" if big_endian else b"II*\x00") + struct.pack(e + "I", ifd_at)
            + struct.pack(e + "H", len(entries)) + table + struct.pack(e + "I", 0) + struct.pack(e + f"{c}H", *[16] * c))
    return blob + b"\x00" * (data_at - len(blob)) + pixels

# -- an ICC profile that is not sRGB ---------------------------------------------------------------

# Adobe RGB (1998): its primaries and white (Adobe RGB (1998) Color Image Encoding, 2005, section 4.3)
# and its gamma, 563/256 = 2.19921875 (section 4.3.4.2).
ADOBE_PRIMARIES = ((0.64, 0.33), (0.21, 0.71), (0.15, 0.06))
SRGB_PRIMARIES = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
D65_XY = (0.3127, 0.3290)
ADOBE_GAMMA = 563 / 256
D50_XYZ = np.array([0.9642, 1.0, 0.8249])
# Bradford's cone response (Lam 1985; as in ICC.1:2010 Annex E and LittleCMS).
BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])


def rgb_to_xyz(primaries, white_xy=D65_XY) -> np.ndarray:
    """The 3x3 matrix from linear RGB to XYZ of the given primaries and white (RP 177-1993)."""
    xyz = np.array([[x / y, 1.0, (1 - x - y) / y] for x, y in primaries]).T
    wx, wy = white_xy
    white = np.array([wx / wy, 1.0, (1 - wx - wy) / wy])
    return xyz * np.linalg.solve(xyz, white)


def _bradford_to_d50(white_xy=D65_XY) -> np.ndarray:
    wx, wy = white_xy
    source = BRADFORD @ np.array([wx / wy, 1.0, (1 - wx - wy) / wy])
    return np.linalg.inv(BRADFORD) @ np.diag((BRADFORD @ D50_XYZ) / source) @ BRADFORD


def _s15(v: float) -> bytes:
    return struct.pack(">i", round(v * 65536))


def _xyz_tag(xyz) -> bytes:
    return b"XYZ \0\0\0\0" + b"".join(_s15(v) for v in xyz)


def icc_profile(primaries=ADOBE_PRIMARIES, gamma=ADOBE_GAMMA, description="Adobe RGB (1998) by hand") -> bytes:
    """An ICC v2 display profile of matrix/TRC form (ICC.1:2001-04): the primaries' colorants adapted
    to the D50 connection space with Bradford, one gamma for the three channels."""
    colorants = _bradford_to_d50() @ rgb_to_xyz(primaries)
    text = description.encode("ascii") + b"\0"
    desc = (b"desc\0\0\0\0" + struct.pack(">I", len(text)) + text + struct.pack(">II", 0, 0)
            + struct.pack(">HB", 0, 0) + b"\0" * 67)
    curve = b"curv\0\0\0\0" + struct.pack(">IH", 1, round(gamma * 256)) + b"\0\0"
    tags = [(b"desc", desc), (b"cprt", b"text\0\0\0\0public domain\0"), (b"wtpt", _xyz_tag(D50_XYZ)),
            (b"rXYZ", _xyz_tag(colorants[:, 0])), (b"gXYZ", _xyz_tag(colorants[:, 1])),
            (b"bXYZ", _xyz_tag(colorants[:, 2])), (b"rTRC", curve), (b"gTRC", curve), (b"bTRC", curve)]
    offset = 128 + 4 + 12 * len(tags)
    table, data = b"", b""
    for signature, body in tags:
        body += b"\0" * (-len(body) % 4)
        table += signature + struct.pack(">II", offset + len(data), len(body))
        data += body
    size = offset + len(data)
    header = (struct.pack(">I", size) + b"\0\0\0\0" + struct.pack(">I", 0x02100000) + b"mntrRGB XYZ "
              + struct.pack(">6H", 2024, 5, 1, 0, 0, 0) + b"acsp" + b"\0" * 24 + struct.pack(">I", 0)
              + b"".join(_s15(v) for v in D50_XYZ) + b"\0" * 48)
    assert len(header) == 128
    return header + struct.pack(">I", len(tags)) + table + data
