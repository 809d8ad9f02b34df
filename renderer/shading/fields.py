"""A material's values, declared once: each field's kind, range, default, the models that read it and
what it means. The command line's garment flags (renderer/cli.py), the fields a material file may
hold, the service's MaterialSpec (service/schemas.py) and docs/materials.md's table are made from
here; `Material` checks its values against the same ranges. A material's textures, its texture sets
and its back are structures of their own (shading/material.py), not fields here.

A leaf: numpy-free, importable by the service's schemas without the renderer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MODELS = ("phong", "pbr")
MODEL_DOC = ("phong (albedo, specular, glossiness: the paper's model) or pbr (glTF metallic-roughness with "
             "KHR_materials_sheen and GGX anisotropy; albedo is the base colour)")


@dataclass(frozen=True)
class MaterialField:
    """One value of a Material. kind: "colour" (linear RGB, 3 numbers) or "number"; [lo, hi] its
    range; per_vertex: a mesh may give one per vertex ((V,) or (V, 3)); garment: the command line's
    default for a garment where it is not the Material's (a red garment with a sheen)."""

    name: str
    kind: str
    default: float | tuple[float, float, float]
    lo: float
    hi: float
    models: tuple[str, ...]
    per_vertex: bool
    doc: str
    garment: float | tuple[float, float, float] | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def garment_default(self):
        return self.default if self.garment is None else self.garment

    def limits(self) -> str:
        what = "r,g,b each" if self.kind == "colour" else "a number"
        return f"{what} in [{self.lo:g}, {self.hi:g}]" + (", or one per vertex" if self.per_vertex else "")

    def check(self, value: float) -> float:
        """A scalar value of this field, finite and in range (the per-vertex arrays: Material's own)."""
        from ..errors import InvalidInputError

        try:
            v = float(value) if not isinstance(value, (bool, str)) else math.nan
        except (TypeError, ValueError):
            v = math.nan
        if not math.isfinite(v):
            raise InvalidInputError(f"{self.name} must be a finite number, got {value!r}")
        if not self.lo <= v <= self.hi:
            raise InvalidInputError(f"{self.name} must lie in [{self.lo:g}, {self.hi:g}], got {v:g}")
        return v


FIELDS = (
    MaterialField("albedo", "colour", (0.8, 0.8, 0.8), 0.0, 1.0, MODELS, True,
                  "diffuse reflectance (phong) or base colour (pbr), linear RGB", garment=(0.8, 0.2, 0.2)),
    MaterialField("specular", "number", 0.0, 0.0, 1e3, ("phong",), True, "weight of the glossy lobe", garment=0.5),
    MaterialField("glossiness", "number", 0.5, 0.0, 1.0, ("phong",), True,
                  "the paper's g (Eq. 3): 0 a diffuse lobe, 1 a mirror", garment=0.8),
    MaterialField("metallic", "number", 0.0, 0.0, 1.0, ("pbr",), True, "glTF's metallic"),
    MaterialField("roughness", "number", 0.5, 0.0, 1.0, ("pbr",), True,
                  "glTF's roughness (below the lobe tables' first node, 0.05, it shades as 0.05)"),
    MaterialField("sheen_colour", "colour", (0.0, 0.0, 0.0), 0.0, 1.0, ("pbr",), True,
                  "KHR_materials_sheen's colour, linear RGB (black: no sheen)"),
    MaterialField("sheen_roughness", "number", 0.5, 0.0, 1.0, ("pbr",), True, "KHR_materials_sheen's roughness"),
    MaterialField("anisotropy", "number", 0.0, 0.0, 1.0, ("pbr",), False,
                  "GGX's anisotropy: a satin's or a silk's highlight stretched along one direction of the cloth "
                  "(0: isotropic)"),
    MaterialField("anisotropy_rotation", "number", 0.0, -1.0, 1.0, ("pbr",), False,
                  "that direction, in turns counter-clockwise from the mesh's growing u towards its growing v "
                  "(a mesh without UVs: from the up axis)"),
    MaterialField("alpha", "number", 1.0, 0.0, 1.0, MODELS, False,
                  "the share of the cloth's area that is fibre (U3M's alpha): light and sight pass the rest "
                  "straight, a voile's or a mesh's open weave (1: opaque)"),
    MaterialField("transmission", "number", 0.0, 0.0, 1.0, MODELS, False,
                  "the share of the light reaching the fibres that they pass on diffusely to the other side, "
                  "tinted by the base colour (U3M's transmission): a thin fabric glowing against the light "
                  "(0: none)"),
)
BY_NAME = {f.name: f for f in FIELDS}


def fields_of(model: str) -> tuple[MaterialField, ...]:
    """The fields a model reads."""
    return tuple(f for f in FIELDS if model in f.models)


def reference_table() -> str:
    """docs/materials.md's table of the fields (tests/test_materials.py holds it to this)."""
    rows = ["| field | models | values | default | meaning |", "|---|---|---|---|---|"]
    for f in FIELDS:
        default = ", ".join(f"{c:g}" for c in f.default) if f.kind == "colour" else f"{f.default:g}"
        rows.append(f"| `{f.name}` | {', '.join(f.models)} | {f.limits()} | {default} | {f.doc} |")
    return "\n".join(rows)
