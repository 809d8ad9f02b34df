"""U3M fabrics (Vizoo's Unified 3D Material, versions 1.0 and 1.1): `load_u3m` reads a `.u3m` document
with its image folder, or a `.u3ma` archive, checks it against the spec's schema and rules, decodes its
images within bounds (U3MLimits) and returns a typed U3MMaterial. See docs/u3m.md.

    material = load_u3m("denim.u3ma")
    back = material.visualisation(Face.BACK)      # the front's when the back is null, as the spec says
    if isinstance(back.basecolor, ColorTexture):
        rgb = back.basecolor.values()             # (H, W, 3) linear float32, factor and blend mode applied
"""

from .images import IMAGE_FORMATS, ImageKind
from .limits import DEFAULT_LIMITS, U3MLimits
from .material import (
    FIELDS,
    BlendMode,
    ColorConstant,
    ColorTexture,
    Constant,
    Face,
    NormalConstant,
    NormalTexture,
    Preview,
    RepeatMode,
    ScalarConstant,
    ScalarTexture,
    Texture,
    U3MMaterial,
    Visualisation,
)
from .place import material_from_u3m, uv_metres
from .reader import load_u3m
from .sources import path_problem

__all__ = ["DEFAULT_LIMITS", "FIELDS", "IMAGE_FORMATS", "BlendMode", "ColorConstant", "ColorTexture", "Constant",
           "Face", "ImageKind", "NormalConstant", "NormalTexture", "Preview", "RepeatMode", "ScalarConstant",
           "ScalarTexture", "Texture", "U3MLimits", "U3MMaterial", "Visualisation", "load_u3m", "material_from_u3m",
           "path_problem", "uv_metres"]
