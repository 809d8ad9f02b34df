"""U3M 1.1 documents and `.u3ma` archives written from fields (the inverse of `load_u3m` for what it
reads): the fabrics the benchmarks make, and a way for a user to hand the renderer a fabric built in
code. Every field not given is the spec's default constant (material.FIELDS); colours are written
sRGB-encoded as the spec stores them, from linear values.

    front = visualisation(basecolor=colour_texture("print.png", 120.0, 120.0), roughness=0.8)
    data = u3ma_bytes(document("Print", front), {"print.png": png_bytes})
"""

from __future__ import annotations

import hashlib
import io
import json
import uuid
import zipfile

import numpy as np

from .images import ImageKind
from .material import FIELDS


def _srgb(linear):
    """The sRGB encoding of linear values in [0, 1] (numbers or arrays)."""
    c = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def image(path: str, width_mm: float, height_mm: float, rotation_deg: float = 0.0, mode: str = "normal",
          dpi: float = 300.0) -> dict:
    """An `image` object: `path` in the archive covering `width_mm` x `height_mm` of fabric."""
    return {"path": path, "width": float(width_mm), "height": float(height_mm), "dpi": {"x": dpi, "y": dpi},
            "repeat": {"rotation": float(rotation_deg), "mode": mode}}


def scalar_texture(path: str, width_mm: float, height_mm: float, factor: float = 1.0, offset: float = 0.0,
                   **placement) -> dict:
    return {"factor": factor, "offset": offset, "image": image(path, width_mm, height_mm, **placement)}


def colour_texture(path: str, width_mm: float, height_mm: float, **placement) -> dict:
    return {"mode": "multiply", "factor": {"r": 1.0, "g": 1.0, "b": 1.0},
            "image": image(path, width_mm, height_mm, **placement)}


def normal_texture(path: str, width_mm: float, height_mm: float, scale: float = 1.0, **placement) -> dict:
    return {"scale": scale, "image": image(path, width_mm, height_mm, **placement)}


def visualisation(**fields) -> dict:
    """A 1.1 visualisation: each field a number (scalar), an (r, g, b) linear colour, or a texture
    object (`scalar_texture`, `colour_texture`, `normal_texture`) over the default constant."""
    out: dict = {}
    for name, (kind, default) in FIELDS.items():
        value = fields.pop(name, None)
        texture = value if isinstance(value, dict) else None
        constant = default if value is None or texture is not None else value
        if kind is ImageKind.SCALAR:
            out[name] = {"constant": float(constant), "texture": texture}
        elif kind is ImageKind.COLOR:
            out[name] = {"constant": dict(zip("rgb", (float(_srgb(c)) for c in constant))), "texture": texture}
        else:
            out[name] = {"constant": dict(zip("xyz", map(float, constant))), "texture": texture}
    if fields:
        raise ValueError(f"no U3M field {', '.join(sorted(fields))}; the fields are {', '.join(FIELDS)}")
    out.update(shader="principled", preview=None)
    return out


def document(name: str, front: dict, back: dict | None = None) -> dict:
    """A 1.1 document of one fabric (a UUID of its name: the same name, the same id)."""
    return {"schema": "1.1", "custom": None, "material": {
        # A version-4 UUID (1.1's pattern) made from the name's digest.
        "id": "{" + str(uuid.UUID(bytes=hashlib.sha256(name.encode()).digest()[:16], version=4)) + "}", "name": name,
        "description": "", "created": "2026-01-01T00:00:00+00:00", "modified": "2026-01-01T00:00:00+00:00",
        "front": front, "back": back, "side": None,
        "physics": None, "metadata": None}}


def u3ma_bytes(doc: dict, images: dict[str, bytes], document_name: str = "fabric.u3m") -> bytes:
    """A `.u3ma`: the document and its images in one zip."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr(document_name, json.dumps(doc, indent=1))
        for path, data in images.items():
            z.writestr(path, data)
    return buf.getvalue()


def png(values: np.ndarray) -> bytes:
    """An 8-bit PNG of values in [0, 1], (H, W) or (H, W, 3); colours sRGB-encoded from linear."""
    from PIL import Image

    a = np.clip(np.asarray(values, np.float64), 0.0, 1.0)
    buf = io.BytesIO()
    Image.fromarray(np.rint(a * 255).astype(np.uint8)).save(buf, "PNG")
    return buf.getvalue()


def srgb_png(linear: np.ndarray) -> bytes:
    """An 8-bit sRGB PNG of a linear colour image (H, W, 3)."""
    return png(_srgb(linear))
