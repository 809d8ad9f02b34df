"""A U3M material as the renderer takes it: typed, validated, every image decoded.

A U3M (Vizoo's Unified 3D Material, 1.0 and 1.1) describes a fabric by up to three visualisations,
`front`, `back` and `side` (1.0 has no side), each a fixed set of principled-shader fields (FIELDS).
Each field is a constant or a texture, never both in use: "software chooses one, not both"; a reader
that can sample a texture uses it, and the document's constant stays on the texture as the fallback
the spec asks writers to keep (about the texture's mean).

Conventions, stated once here:
- Colour (ColorConstant.rgb, ColorTexture.factor and image) is linear Rec. 709 / sRGB primaries, D65:
  the spec's colour values ("u3m standard colorspace": sRGB) decoded with the sRGB EOTF, colour images
  converted from their ICC profile (images.py).
- Data images are their stored code values over their maximum, in [0, 1], never colour-managed.
- A texture covers `width_mm` x `height_mm` of fabric (the document's physical size, which wins over
  the image's own dpi when they disagree, as the spec says) and repeats over the garment as `repeat`
  says (wrap, or mirror every other repeat, per axis). `image[0]` is the image's top row as stored.
- `rotation_deg`: the document's `image.repeat.rotation`. The spec gives no unit, direction or pivot;
  it is kept as written and taken to be degrees (the spec's only other angle, 1.0's anisotropy_rotation,
  was "probably degree").
- Scalars keep the spec's units: anisotropy_rotation in turns (1 = 360 deg; 1.0's degrees are converted),
  specular_value on [0, 1] for a reflectance of [0 %, 8 %], ior as a refractive index, roughness and
  metalness in [0, 1].

What the later stages will want from it: textures at their physical size on the garment (width_mm,
height_mm, rotation_deg, repeat), tangent frames for `normal` (OpenGL convention: +y up in the image,
as the spec says), the side the camera sees per pixel (`U3MMaterial.visualisation(Face.BACK)`, with
the spec's fallback), and the physically based fields (basecolor, normal, roughness, metalness,
specular_value, sheen_value, anisotropy_*, alpha, transmission).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, fields
from enum import Enum

import numpy as np

from ..errors import MaterialError
from .images import ImageKind


class Face(Enum):
    """A visualisation of the fabric: the side a garment shows outward, its back, its cut edge."""

    FRONT = "front"
    BACK = "back"
    SIDE = "side"


class RepeatMode(Enum):
    """How a texture repeats beyond one image (`image.repeat.mode`): wrap, or mirror every other
    repeat, in x (the image's width) and y (its height)."""

    NORMAL = "normal"
    MIRROR_X = "mirror_x"
    MIRROR_Y = "mirror_y"
    MIRROR_XY = "mirror_xy"

    @property
    def mirror_x(self) -> bool:
        return self in (RepeatMode.MIRROR_X, RepeatMode.MIRROR_XY)

    @property
    def mirror_y(self) -> bool:
        return self in (RepeatMode.MIRROR_Y, RepeatMode.MIRROR_XY)


class BlendMode(Enum):
    """How a colour texture (a) meets its factor (b) (`texture.mode`; the spec's formulas, per channel,
    on linear values)."""

    ADD = "add"
    SUBTRACT = "subtract"
    MULTIPLY = "multiply"
    DIVIDE = "divide"
    MAX = "max"
    MIN = "min"
    OVERLAY = "overlay"

    def apply(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """a (..., 3) blended with b (3,): float32, not clamped (add and divide can leave [0, 1])."""
        a = np.asarray(a, np.float32)
        b = np.asarray(b, np.float32)
        if self is BlendMode.ADD:
            return a + b
        if self is BlendMode.SUBTRACT:
            return a - b
        if self is BlendMode.MULTIPLY:
            return a * b
        if self is BlendMode.DIVIDE:   # "if b == 0, the result should be 1.0"
            safe = np.where(b == 0, np.float32(1), b)
            return np.where(b == 0, np.float32(1), a / safe).astype(np.float32)
        if self is BlendMode.MAX:
            return np.maximum(a, b)
        if self is BlendMode.MIN:
            return np.minimum(a, b)
        # overlay: 2 a b if a < 0.5, else 1 - 2 (1 - a)(1 - b)
        return np.where(a < 0.5, 2 * a * b, 1 - 2 * (1 - a) * (1 - b)).astype(np.float32)


class Constant:
    """A field given as one value over the whole fabric."""


@dataclass(frozen=True)
class ScalarConstant(Constant):
    value: float


@dataclass(frozen=True)
class ColorConstant(Constant):
    rgb: tuple[float, float, float]   # linear Rec. 709


@dataclass(frozen=True)
class NormalConstant(Constant):
    xyz: tuple[float, float, float]   # tangent space, +z out of the fabric; not renormalised


@dataclass(frozen=True, eq=False)
class Texture:
    """An image laid on the fabric. `image` is read-only float32: (H, W, 3) for colour (linear) and
    normal (raw, [0, 1]) fields, (H, W) for scalars (raw, [0, 1], channels averaged)."""

    path: str                    # as the document names it, relative to the document
    image: np.ndarray
    width_mm: float              # the fabric one image covers
    height_mm: float
    dpi: tuple[float, float]     # as the document gives it (x, y); 1.0 gives one number for both
    rotation_deg: float
    repeat: RepeatMode

    @property
    def size_px(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.image.shape[1], self.image.shape[0]


@dataclass(frozen=True, eq=False)
class ScalarTexture(Texture):
    """A scalar field's texture: its value is offset + image * factor (the spec's finalNumericPixel)."""

    factor: float
    offset: float
    constant: ScalarConstant

    def values(self) -> np.ndarray:
        """(H, W) float32: the field's value at each pixel."""
        return np.float32(self.offset) + self.image * np.float32(self.factor)


@dataclass(frozen=True, eq=False)
class ColorTexture(Texture):
    """A colour field's texture: its value is mode(image, factor) (BlendMode)."""

    mode: BlendMode
    factor: tuple[float, float, float]   # linear Rec. 709
    constant: ColorConstant

    def values(self) -> np.ndarray:
        """(H, W, 3) float32, linear: the field's colour at each pixel."""
        return self.mode.apply(self.image, np.asarray(self.factor, np.float32))


@dataclass(frozen=True, eq=False)
class NormalTexture(Texture):
    """A normal map (OpenGL convention: x right, y up in the image, z out of the fabric)."""

    scale: float                 # multiplies x and y before renormalising
    constant: NormalConstant

    def values(self) -> np.ndarray:
        """(H, W, 3) float32 unit normals: 2 v - 1, x and y times `scale`, renormalised; a zero vector
        becomes (0, 0, 1), as the spec suggests."""
        n = self.image * np.float32(2) - np.float32(1)
        n[..., :2] *= np.float32(self.scale)
        length = np.sqrt(np.einsum("...i,...i->...", n, n))
        flat = length == 0
        n[flat] = (0.0, 0.0, 1.0)
        length[flat] = 1.0
        n /= length[..., None]
        return n


ScalarField = ScalarConstant | ScalarTexture
ColorField = ColorConstant | ColorTexture
NormalField = NormalConstant | NormalTexture

# Every field of a visualisation: its kind and its default (U3M 1.1's schema, which a 1.0 field given
# as null takes). A test holds this table to the schema.
FIELDS: dict[str, tuple[ImageKind, float | tuple[float, float, float]]] = {
    "alpha": (ImageKind.SCALAR, 1.0),
    "anisotropy_value": (ImageKind.SCALAR, 0.0),
    "anisotropy_rotation": (ImageKind.SCALAR, 0.0),
    "clearcoat_value": (ImageKind.SCALAR, 0.0),
    "clearcoat_normal": (ImageKind.NORMAL, (0.0, 0.0, 1.0)),
    "clearcoat_roughness": (ImageKind.SCALAR, 0.0),
    "ior": (ImageKind.SCALAR, 1.4),
    "metalness": (ImageKind.SCALAR, 0.0),
    "normal": (ImageKind.NORMAL, (0.0, 0.0, 1.0)),
    "displacement": (ImageKind.SCALAR, 0.0),
    "roughness": (ImageKind.SCALAR, 0.7),
    "sheen_value": (ImageKind.SCALAR, 0.0),
    "sheen_tint": (ImageKind.SCALAR, 0.0),
    "specular_value": (ImageKind.SCALAR, 0.5),
    "specular_tint": (ImageKind.SCALAR, 0.0),
    "subsurface_radius": (ImageKind.SCALAR, 0.0),
    "subsurface_value": (ImageKind.SCALAR, 0.0),
    "transmission": (ImageKind.SCALAR, 0.0),
    "basecolor": (ImageKind.COLOR, (1.0, 1.0, 1.0)),
    "subsurface_color": (ImageKind.COLOR, (1.0, 1.0, 1.0)),
}


@dataclass(frozen=True)
class Preview:
    """The visualisation's preview image (1.1), for people (a thumbnail): its path is checked, its
    pixels are not read."""

    path: str
    width_mm: float
    height_mm: float


@dataclass(frozen=True, eq=False)
class Visualisation:
    """One face of the fabric: its principled-shader fields (FIELDS; the spec's names)."""

    alpha: ScalarField
    anisotropy_value: ScalarField
    anisotropy_rotation: ScalarField     # turns: 1 = 360 deg
    clearcoat_value: ScalarField
    clearcoat_normal: NormalField
    clearcoat_roughness: ScalarField
    ior: ScalarField
    metalness: ScalarField
    normal: NormalField
    displacement: ScalarField            # relative distance, higher = towards the viewer
    roughness: ScalarField
    sheen_value: ScalarField
    sheen_tint: ScalarField
    specular_value: ScalarField          # [0, 1] for a reflectance of [0 %, 8 %]
    specular_tint: ScalarField
    subsurface_radius: ScalarField
    subsurface_value: ScalarField
    transmission: ScalarField
    basecolor: ColorField
    subsurface_color: ColorField
    shader: str = "principled"
    preview: Preview | None = None

    def textures(self) -> Iterator[tuple[str, Texture]]:
        """(field name, texture) of each field given as a texture."""
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Texture):
                yield f.name, value


# The spec's fallbacks (1.1 schema, material.front/back/side descriptions): a null back or side takes
# the front's values; a null front takes the back's, else the side's.
_FALLBACK = {Face.FRONT: (Face.FRONT, Face.BACK, Face.SIDE),
             Face.BACK: (Face.BACK, Face.FRONT, Face.SIDE),
             Face.SIDE: (Face.SIDE, Face.FRONT, Face.BACK)}


@dataclass(frozen=True, eq=False)
class U3MMaterial:
    """A U3M document read and checked, with every image it names decoded. The faces are as the
    document gives them (None where null); `visualisation` resolves the spec's fallbacks."""

    name: str
    id: str
    version: str                         # "1.0" or "1.1"
    file: str                            # the document, for messages
    front: Visualisation | None
    back: Visualisation | None
    side: Visualisation | None
    thickness_mm: float | None = None    # physics (1.1), when given
    weight_g_m2: float | None = None

    def visualisation(self, face: Face | str) -> Visualisation:
        """The visualisation to render `face` with: its own, else the front's, else the other one
        (the spec's order); a material with physics alone has none, and is refused here."""
        face = Face(face)
        for candidate in _FALLBACK[face]:
            found = getattr(self, candidate.value)
            if found is not None:
                return found
        raise MaterialError("the material has no visualisation (front, back and side are null; it describes "
                            "physics only), so it cannot be rendered", file=self.file, field="material.front")

    def textures(self) -> Iterator[tuple[str, Texture]]:
        """(JSON path of the field, texture) of every texture of every face the document gives."""
        for face in Face:
            visualisation = getattr(self, face.value)
            if visualisation is not None:
                for name, texture in visualisation.textures():
                    yield f"material.{face.value}.{name}", texture

    @property
    def nbytes(self) -> int:
        """Bytes held by the decoded images (an image shared by several fields counts once)."""
        return sum({id(t.image): t.image.nbytes for _, t in self.textures()}.values())
