"""load_u3m: a `.u3m` (with its folder) or a `.u3ma` into a U3MMaterial.

The read, in the order that keeps it bounded:
1. the source: a zip or a JSON document, told by its bytes; an archive's directory judged (sizes,
   ratios, names) before any member is read (sources.py);
2. the document: parsed within its byte bound, validated against its version's schema (document.py);
3. every image the document names: its path checked against the spec's rules, then its header read
   and its size judged, all of them, before any image is decoded;
4. the images decoded (each file once a use as colour, scalar or normal data) into the typed result.

What 1.0 and 1.1 differ in (changes.txt), and how each reads here:
- 1.1 adds `side` (1.0 reads as side = null), `physics`, `metadata`, `preview`: physics' thickness and
  weight are kept; metadata is not read (nothing in it renders).
- 1.0's fields may be null: a null field reads as 1.1's default constant (FIELDS).
- 1.0's `normal` and `clearcoat_normal` are numbers with a number texture: a constant number has no
  direction and reads as (0, 0, 1); a texture reads as a normal map of scale 1 (1.0 says nothing of
  what factor and offset would do to a normal).
- 1.0's `anisotropy_rotation` was "probably degree", 1.1's is in turns: 1.0's constant, factor and
  offset are divided by 360.
- 1.0's dpi is one number, 1.1's is {x, y}.
- `custom` is another company's section: the spec forbids reading it, and it is not read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import MaterialError
from ..shading.tonemap import srgb_eotf
from .document import parse_document, validate_document
from .images import ImageKind, decode_image, open_image
from .limits import DEFAULT_LIMITS, U3MLimits
from .material import (
    FIELDS,
    BlendMode,
    ColorConstant,
    ColorTexture,
    Face,
    NormalConstant,
    NormalTexture,
    Preview,
    RepeatMode,
    ScalarConstant,
    ScalarTexture,
    U3MMaterial,
    Visualisation,
)
from .sources import Source, open_source, path_problem

MM_PER_INCH = 25.4


def load_u3m(source: str | os.PathLike | bytes, *, name: str | None = None,
             limits: U3MLimits = DEFAULT_LIMITS) -> U3MMaterial:
    """Read a U3M material: a `.u3m` document (its images are read from its folder), a `.u3ma` archive,
    or the bytes of either (`name` names them in messages; a document as bytes can name no image).
    Any problem raises MaterialError naming the file, the field and what was wrong."""
    with open_source(source, limits, name) as src:
        document = parse_document(src.read_document(), src.document_file)
        version = validate_document(document, src.document_file)
        return _Reader(src, version, limits).material(document["material"])


@dataclass(frozen=True)
class _Use:
    """One texture of the document: where it is named, how its image is read, its `image` object."""

    field: str          # JSON path of the image object
    kind: ImageKind
    image: dict


class _Reader:
    def __init__(self, source: Source, version: str, limits: U3MLimits):
        self._source, self._version, self._limits = source, version, limits
        self._file = source.document_file
        self._decoded: dict[tuple[str, ImageKind], np.ndarray] = {}

    def material(self, m: dict) -> U3MMaterial:
        faces = {face: m.get(face.value) for face in Face}   # 1.0 has no side
        if all(v is None for v in faces.values()) and m.get("physics") is None:
            raise MaterialError("front and back are null; a U3M holds at least one visualisation or physics",
                                file=self._file, field="material.front")
        self._decode_all(faces)
        physics = m.get("physics") or {}
        return U3MMaterial(
            name=m["name"], id=m["id"], version=self._version, file=self._file,
            front=self._visualisation(faces[Face.FRONT], "material.front"),
            back=self._visualisation(faces[Face.BACK], "material.back"),
            side=self._visualisation(faces[Face.SIDE], "material.side"),
            thickness_mm=_optional_float(physics.get("thickness")),
            weight_g_m2=_optional_float(physics.get("weight")))

    # -- images: every path and every header judged before the first pixel is decoded

    def _uses(self, faces: dict[Face, dict | None]) -> list[_Use]:
        uses = []
        for face, v in faces.items():
            for name, (kind, _) in FIELDS.items():
                texture = (v or {}).get(name) and v[name].get("texture")
                if texture:
                    uses.append(_Use(f"material.{face.value}.{name}.texture.image", kind, texture["image"]))
        return uses

    def _decode_all(self, faces: dict[Face, dict | None]) -> None:
        uses = self._uses(faces)
        for face, v in faces.items():   # previews are not read, but their paths follow the rule too
            if v and v.get("preview"):
                self._check_path(v["preview"]["path"], f"material.{face.value}.preview.path")
        for use in uses:
            self._check_path(use.image["path"], f"{use.field}.path")
        unique = {(use.image["path"], use.kind): use for use in uses}
        sizes: dict[str, tuple[int, int]] = {}
        total = 0
        for (path, _), use in unique.items():
            if path not in sizes:
                data, shown = self._source.read(path, f"{use.field}.path")
                im = open_image(data, file=shown, field=f"{use.field}.path",
                                max_pixels=self._limits.max_image_pixels)
                sizes[path] = im.size
                del im, data
            w, h = sizes[path]
            total += w * h
            if total > self._limits.max_total_pixels:
                raise MaterialError(f"the material's images declare {total} px in all by this one ({path}, {w} x {h} "
                                    f"px); the limit is {self._limits.max_total_pixels} px "
                                    "(U3MLimits.max_total_pixels)", file=self._file, field=f"{use.field}.path")
        for (path, kind), use in unique.items():
            data, shown = self._source.read(path, f"{use.field}.path")
            self._decoded[path, kind] = decode_image(data, kind, file=shown, field=f"{use.field}.path",
                                                     max_pixels=self._limits.max_image_pixels)

    def _check_path(self, path: str, field: str) -> None:
        if (problem := path_problem(path)) is not None:
            raise MaterialError(f"{path!r} {problem}", file=self._file, field=field)

    # -- the typed result

    def _visualisation(self, v: dict | None, field: str) -> Visualisation | None:
        if v is None:
            return None
        values = {name: self._field(v.get(name), kind, default, f"{field}.{name}")
                  for name, (kind, default) in FIELDS.items()}
        preview = v.get("preview")
        return Visualisation(**values, shader=v.get("shader", "principled"),
                             preview=None if not preview else Preview(preview["path"], float(preview["width"]),
                                                                      float(preview["height"])))

    def _field(self, spec: dict | None, kind: ImageKind, default, field: str):
        if kind is ImageKind.SCALAR:
            # 1.0's anisotropy_rotation is in degrees, 1.1's in turns.
            unit = 1.0 / 360.0 if self._version == "1.0" and field.endswith(".anisotropy_rotation") else 1.0
            constant = ScalarConstant(float(spec["constant"]) * unit if spec else default)
            texture = spec and spec.get("texture")
            if not texture:
                return constant
            return ScalarTexture(**self._placement(texture["image"], kind, f"{field}.texture.image"),
                                 factor=float(texture["factor"]) * unit, offset=float(texture["offset"]) * unit,
                                 constant=constant)
        if kind is ImageKind.COLOR:
            constant = ColorConstant(_linear(spec["constant"]) if spec else default)
            texture = spec and spec.get("texture")
            if not texture:
                return constant
            return ColorTexture(**self._placement(texture["image"], kind, f"{field}.texture.image"),
                                mode=BlendMode(texture.get("mode", "multiply")), factor=_linear(texture["factor"]),
                                constant=constant)
        given = spec["constant"] if spec else None
        # 1.1: {x, y, z}; 1.0 declares normals as numbers, which carry no direction.
        constant = NormalConstant(tuple(float(given[a]) for a in "xyz") if isinstance(given, dict) else default)
        texture = spec and spec.get("texture")
        if not texture:
            return constant
        return NormalTexture(**self._placement(texture["image"], kind, f"{field}.texture.image"),
                             scale=float(texture.get("scale", 1.0)), constant=constant)

    def _placement(self, image: dict, kind: ImageKind, field: str) -> dict:
        pixels = self._decoded[image["path"], kind]
        dpi = image["dpi"]
        dpi_xy = (float(dpi["x"]), float(dpi["y"])) if isinstance(dpi, dict) else (float(dpi), float(dpi))
        size_mm = []
        # A zero size (the schema allows it) is taken from the pixels and the dpi, the duplicate the spec
        # says should agree; with no dpi either, the texture has no size on the fabric.
        for key, px, d in (("width", pixels.shape[1], dpi_xy[0]), ("height", pixels.shape[0], dpi_xy[1])):
            mm = float(image[key])
            if mm <= 0 and d > 0:
                mm = px / d * MM_PER_INCH
            if mm <= 0:
                raise MaterialError(f"is {image[key]} mm and the dpi is {d}: the texture has no size on the fabric",
                                    file=self._file, field=f"{field}.{key}")
            size_mm.append(mm)
        repeat = image["repeat"]
        return {"path": image["path"], "image": pixels, "width_mm": size_mm[0], "height_mm": size_mm[1],
                "dpi": dpi_xy, "rotation_deg": float(repeat["rotation"]), "repeat": RepeatMode(repeat["mode"])}


def _linear(rgb: dict) -> tuple[float, float, float]:
    """A document's colour (sRGB-encoded, the spec's "u3m standard colorspace") as linear Rec. 709."""
    r, g, b = srgb_eotf(np.array([rgb["r"], rgb["g"], rgb["b"]], np.float64)).tolist()
    return r, g, b


def _optional_float(value) -> float | None:
    return None if value is None else float(value)
