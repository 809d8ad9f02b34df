"""The quality settings, declared once (no GL): name, type, range or choices, one-line doc, group, and
what a change of it invalidates. The frame's checks (FrameSettings), the presets' files, the command
line's flags, the service's request model and the generated reference (docs/settings.md) all read
this table; adding a setting touches it and the code that uses the setting.

The presets (renderer/presets/*.toml) give every setting here a value; they are data, read where a
request is resolved (renderer/presets), never a module's defaults. FrameSettings' and PEMSettings'
quality fields are made from this table (`fields`): their names, types and defaults are these.
`default` is the paper's choice (the PEM lookups for both terms, the plain median cut, one map size,
full caster detail, no contact shadows; the bias, which the paper does not state, is the presets'):
what FrameSettings() and PEMSettings() hold, and what tests of one mechanism hold still.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import numpy as np

from .errors import InvalidInputError

# Limits the settings' ranges name (the renderer's own bounds; renderer.py imports them from here).
MAX_SHADOW_SIDE = 8192      # the largest shadow map side, small lights' included (shadow_size x small_light_scale)
MAX_SHARP_SHARE_DEG = 30.0  # a group's mean direction stays within this of every member
MAX_BIAS_TEXELS = 16.0      # shadow bias beyond this many texels moves shadows visibly off their casters
MAX_CONTACT_TEXELS = 64.0   # the contact search's reach, in main-map texels
MAX_SUB_LIGHTS = 16
MAX_LIGHTS = 384

GROUPS = ("lights", "shadows", "contact", "shading")
# What a change of a setting makes anew: the PEM set (seconds), the shadow maps (every frame anyway),
# a lighting-pass program variant (compiled once per variant), or nothing beyond the frame itself.
INVALIDATES = ("pem set", "shadow maps", "shader variant", "frame")


@dataclass(frozen=True)
class Setting:
    name: str
    type: type                       # int, float, bool or str
    default: object                  # the paper's choice (the bias: the presets')
    doc: str
    group: str
    invalidates: str
    minimum: float | None = None
    maximum: float | None = None
    above_minimum: bool = False      # minimum itself excluded
    below_maximum: bool = False      # maximum itself excluded
    choices: tuple[str, ...] | None = None
    power_of_two: bool = False

    def __post_init__(self):
        assert self.group in GROUPS and self.invalidates in INVALIDATES, self.name

    def limits(self) -> str:
        """The allowed values, as the error message and the docs say them."""
        if self.choices is not None:
            return "one of " + ", ".join(self.choices)
        if self.type is bool:
            return "true or false"
        lo = "(" if self.above_minimum else "["
        hi = ")" if self.below_maximum else "]"
        span = f"{lo}{self.minimum:g}, {self.maximum:g}{hi}"
        if self.type is int:
            return ("a power of two in " if self.power_of_two else "a whole number in ") + span
        return "a number in " + span

    def check(self, value) -> object:
        """The value, or InvalidInputError naming the setting, its limits and the value."""
        bad = InvalidInputError(f"{self.name} must be {self.limits()}, got {value!r}")
        if self.choices is not None:
            if not isinstance(value, str) or value not in self.choices:
                raise bad
            return value
        if isinstance(value, (bool, np.bool_)) != (self.type is bool):
            raise bad
        if self.type is bool:
            return bool(value)
        if not isinstance(value, numbers.Integral if self.type is int else numbers.Real) or not math.isfinite(value):
            raise bad
        if (value < self.minimum or value > self.maximum or (self.above_minimum and value == self.minimum)
                or (self.below_maximum and value == self.maximum)):
            raise bad
        if self.power_of_two and int(value) & (int(value) - 1):
            raise bad
        return int(value) if self.type is int else float(value)


def regions_per_face(n_lights: int) -> int:
    """Validate N = 6 * 2^k and return 2^k: the uniform median cut's rule (renderer/lighting/median_cut.py,
    median_cut; median_cut_to takes any count from 6, the extra regions where the energy is)."""
    per_face = n_lights // 6
    if n_lights < 6 or n_lights % 6 or per_face & (per_face - 1):
        raise InvalidInputError(
            f"the uniform median cut takes 6 * 2^k regions (6, 12, 24, 48, 96, 192, 384, ...), got {n_lights}: "
            "it halves every region of each cube face at each step; median_cut_to takes any count from 6"
        )
    return per_face


SETTINGS: tuple[Setting, ...] = (
    # Lights and PEMs.
    Setting("lights", int, 48, "median-cut regions, one light and one shadow map each", "lights", "pem set",
            6, MAX_LIGHTS),
    Setting("face_size", int, 128, "PEM cube face size", "lights", "pem set", 4, 2048, power_of_two=True),
    Setting("whole_sources", bool, False, "median cut: no cut through a compact bright source (a sun), which keeps "
            "it in one region (false: the paper's plain cut)", "lights", "pem set"),
    Setting("lights_from", str, "median-cut", "how the map becomes lights: median-cut (the paper), area (Arbree, "
            "Walter and Bala's area lights, each a disc with its own map, plus the remainder's median cut, at most "
            "`lights` in all) or auto (area where the map has area lights and none is wider than 15 degrees, else "
            "the median cut)", "lights", "pem set",
            choices=("median-cut", "area", "auto")),
    # Shadow maps.
    Setting("shadow_size", int, 256, "shadow-map side per light, texels", "shadows", "shadow maps", 16,
            MAX_SHADOW_SIDE),
    Setting("blur_scale", float, 0.1, "scale of the paper's per-light shadow blur (0: hard shadows)", "shadows",
            "shadow maps", 0.0, 100.0),
    # blocker: each area light's penumbra (a main map's) as wide as its angular radius and the blocker's
    # distance make it (shading/vsm.glsl, PENUMBRA_BLOCKER); fixed: the paper's blur alone, as for every
    # median-cut region.
    Setting("penumbra", str, "fixed", "area lights' penumbrae: fixed (the paper's blur, blur_scale) or blocker (as "
            "wide as the light's angular size and the blocker's distance make them, percentage-closer soft shadows "
            "on the maps' MIP chains: sharp at contact, soft far from it)", "shadows", "shader variant",
            choices=("fixed", "blocker")),   # area lights only, whom the knob sweep's median cut has none of:
                                             # `garment-render bench --area` measures it
    # The proxy: shadows/proxy.py. The shadow pass costs per triangle on a CPU rasterizer.
    Setting("caster_detail", float, 1.0, "share of the casters' triangles the main maps draw (a proxy over the same "
            "vertices; 1: the meshes themselves)", "shadows", "shadow maps", 0.0, 1.0, above_minimum=True),
    # The shadow maps' bias, in each map's own texels (main and sharp maps alike): the lookup pushed off
    # the surface, and Chebyshev's variance floor. Chosen on the benchmark scenes (docs/sweep.md, the
    # bias rows). Only against the receiver's own shadow group (renderer/scene.py): the other group's
    # casters are compared without it.
    Setting("normal_offset_texels", float, 1.5, "shadow lookups pushed off the surface along the normal, in each "
            "map's texels", "shadows", "frame", 0.0, MAX_BIAS_TEXELS),
    Setting("min_sigma_texels", float, 3.0, "least deviation of the depths under a texel, in that map's texels "
            "(keeps sloped surfaces from shadowing themselves)", "shadows", "frame", 0.0, MAX_BIAS_TEXELS),
    # The sharp maps: small lights' (angular radius <= ~6 degrees) in an array of their own, drawn at full
    # caster detail; 1: the same maps as every other light. Only the small lights carrying at least
    # small_light_min_energy x the mean light's energy get them (the others' edges, dim, cost more than
    # they show: docs/sweep.md; relative to the mean, so that a sun split into more regions keeps its
    # maps), and with sharp_large_lights the large lights that bright too (the sky beside a sun: their
    # energy is more concentrated than their region). Sharp lights within sharp_share_deg of a brighter
    # one whose disc theirs overlaps share its map, drawn along the group's energy-weighted direction;
    # each keeps its own direction and energy for shading.
    Setting("small_light_scale", int, 1, "small lights (a sun, under ~6 degrees) get maps this many times "
            "shadow_size per side, drawn from the casters themselves", "shadows", "shadow maps", 1, 8),
    Setting("small_light_min_energy", float, 0.0, "only small lights with at least this many times the mean light's "
            "energy get those maps (0: every small light)", "shadows", "shadow maps", 0.0, 1e6),
    Setting("sharp_large_lights", bool, False, "large lights that bright get those maps too", "shadows",
            "shadow maps"),
    Setting("sharp_share_deg", float, 0.0, "sharp lights within this many degrees of a brighter one whose disc "
            "theirs overlaps share its map (a sun split into a few regions; 0: one map each)", "shadows",
            "shadow maps", 0.0, MAX_SHARP_SHARE_DEG),
    # Contact shadows.
    # Full mode (shading/contact.glsl): along screen lines through the geometry pass's positions, those
    # occluders the maps' bias skips (the collar over the neck) and the near ones a map drawn from a
    # proxy blurs (a fold's lips). Chosen on the benchmark scenes (docs/sweep.md).
    Setting("contact_shadow_texels", float, 0.0, "occluders within this many main-map texels of a surface, which the "
            "maps' bias skips, found in the camera's view (0: off, the paper)", "contact", "shader variant", 0.0,
            MAX_CONTACT_TEXELS),
    # Shading.
    # diffuse pem: PEM_i along the normal at the s = 1 level (the paper); lights: each region's energy
    # times the clamped cosine over its disc, no diffuse lookups. glossy wide: small lights (angular
    # radius <= ~6 degrees) from their disc through the Phong lobe in closed form, and the large lights
    # too wherever the lobe is wider than their disc (1 / s >= a^2 / 4: there the PEM's coarse levels
    # are the larger error; a narrow lobe reads the PEM's fine levels, which hold the region's detail).
    # Every closed-form glossy term loses the part of its disc below the triangle's own plane.
    Setting("diffuse", str, "pem", "diffuse term from the PEMs along the normal (pem, the paper) or from each "
            "light's disc in closed form (lights)", "shading", "shader variant", choices=("pem", "lights")),
    Setting("glossy", str, "pem", "glossy term from the PEMs along the reflection vector (pem, the paper), or wide: "
            "small lights' from their disc through the Phong lobe, large lights' too where the lobe is wider than "
            "their disc", "shading", "shader variant", choices=("pem", "wide")),
    # Each region's closed-form glossy term (glossy wide) over this many discs: its texels cut further by
    # the same median cut (lighting/median_cut.py, SubLights), its visibility, diffuse term and PEMs
    # still the region's. Chosen on the benchmark scenes (docs/sweep.md, the sub_lights rows).
    Setting("sub_lights", int, 1, "discs per region in the closed-form glossy term (1: the paper's one light)",
            "shading", "shader variant", 1, MAX_SUB_LIGHTS, power_of_two=True),
    # Anti-aliasing (shaders/edges/): the geometry pass multisampled, the lighting pass once a pixel, and
    # each pixel's samples given the colour of the neighbour that shaded their surface (renderer.py,
    # _edges_pass). The driver bounds it (GL_MAX_SAMPLES: 4 on llvmpipe).
    Setting("aa_samples", int, 1, "geometry samples a pixel: edges anti-aliased from them, fractional coverage in "
            "alpha, shading still once a pixel (1: none, the paper)", "shading", "frame", 1, 8, power_of_two=True),
    # Kautz and McCool's fit (lighting/material_lobes.py): GGX's lobes and, where the scene has sheen,
    # sheen's.
    Setting("lobes", int, 2, "fitted lobes per layer of a physically based material (GGX, sheen): one PEM lookup "
            "per light each (Kautz and McCool's fit; Phong materials have one)", "shading", "shader variant", 1,
            2),   # not in the knob sweep, whose fabrics are Phong: `garment-render bench --materials` measures it
)
BY_NAME = {s.name: s for s in SETTINGS}
NAMES = tuple(BY_NAME)
# The settings of the PEM set, not of the frame (the others are FrameSettings fields). PEMSettings
# holds them but the face size, which is the cube's (the map's resampling chooses it).
PEM_SETTINGS = tuple(s.name for s in SETTINGS if s.invalidates == "pem set")
PEM_FIELDS = tuple(n for n in PEM_SETTINGS if n != "face_size")
FRAME_SETTINGS = tuple(n for n in NAMES if n not in PEM_SETTINGS)


def fields(names: tuple[str, ...]) -> list[tuple[str, type, dataclasses.Field]]:
    """These settings as dataclass fields (dataclasses.make_dataclass): each its name, its declared
    type and its default here. FrameSettings and PEMSettings are made of them, so a setting is
    declared once."""
    return [(n, BY_NAME[n].type, dataclasses.field(default=BY_NAME[n].default)) for n in names]


# Rules between settings, declared once. The sharp maps' side: shadow_size x small_light_scale stays
# within MAX_SHADOW_SIDE; a frame refuses a pair over it (FrameSettings), and a preset's or budget's
# scale yields to a shadow_size the caller names (presets.merge_knobs) where the caller named no scale.
def shadow_side_error(shadow_size: int, small_light_scale: int) -> str | None:
    """Why the pair is refused, or None."""
    if int(shadow_size) * int(small_light_scale) > MAX_SHADOW_SIDE:
        return (f"shadow_size x small_light_scale must be at most {MAX_SHADOW_SIDE}, got {shadow_size} x "
                f"{small_light_scale}")
    return None


def fitted_small_light_scale(shadow_size: int, small_light_scale: int) -> int:
    """The scale, or the largest that keeps the pair within the rule."""
    if shadow_side_error(shadow_size, small_light_scale) is None:
        return int(small_light_scale)
    return max(1, MAX_SHADOW_SIDE // int(shadow_size))


def most_sharp_lights(n_lights: int, small_light_scale: int, small_light_min_energy: float) -> int:
    """How many of n lights may get sharp maps, whatever the map: every one that may be small when
    every small light does (min energy 0), else the lights carrying at least that multiple of the mean
    energy, at most n / min energy of them; none with scale 1 (the sharp maps are the main ones)."""
    if small_light_scale == 1:
        return 0
    if small_light_min_energy <= 0:
        return n_lights
    return int(min(n_lights, n_lights / small_light_min_energy))   # min first: n / 1e-320 is inf


# What a caller sets that no preset chooses: the PEMs' filter, the shading mode, the variance shadow
# maps' light-bleeding reduction and a map's layout. Declared here once, as the settings are: the
# command line's flags, the service's fields and enums, and the renderer's own enums (Filter,
# ShadingMode, Layout: tests/test_config.py checks they hold these values) follow them.
OPTIONS: tuple[Setting, ...] = (
    Setting("filter", str, "sqrt-cosine", "the PEMs' MIP filter (Knuth et al., sec. 3.2; a budget's measured "
            "filter where one is asked for)", "lights", "pem set",
            choices=("none", "box", "gauss", "cosine", "sqrt-cosine")),
    Setting("layout", str, "auto", "the environment map's layout (auto: from its aspect ratio)", "lights",
            "pem set", choices=("auto", "latlong", "angular", "hcross", "vcross")),
    Setting("bleed_reduction", float, 0.2, "variance shadow maps' light-bleeding reduction: the share of "
            "Chebyshev's bound below which a point is in full shadow", "shadows", "frame", 0.0, 1.0,
            below_maximum=True),
    Setting("mode", str, "full", "the full method, or the same without occlusion (the paper's Fig. 6; its "
            "ambient-occlusion and many-light baselines are the lab's comparisons, not the product's)", "shading",
            "shader variant", choices=("full", "none")),
)
OPTION = {o.name: o for o in OPTIONS}


# Settings that went because they did not pay on the broad benchmark's held-out scenes
# (docs/broad-benchmark.md, "Settings removed"): what a request or flag naming one is told.
RETIRED = {
    "needed_levels": "removed: the PEM set always keeps only the levels the scene's materials read (the same image)",
    "horizon": "removed: the shading normal's plane no longer blocks every light (it raised the error held out)",
    "terminator": "removed: always on (a small light below a triangle's own plane lights neither term)",
    "sharp_max_maps": "removed: no effect held out; small_light_min_energy chooses the lights with sharp maps",
    "sharp_normal_offset_texels": "removed: the sharp maps take normal_offset_texels, in their own texels",
    "sharp_full_detail_deg": "removed: every sharp map draws the casters at full detail",
    "shadow_threshold": "removed: every light has a shadow map (dim lights without one lowered the error nowhere "
                        "held out)",
    "sh_unshadowed": "removed with shadow_threshold: every light has a shadow map",
    "glossy_horizon": "removed: always per light (each light's glossy term keeps the share of its disc above the "
                      "triangle's plane)",
    "calibration": "removed: g maps to the level of the closest normalized kernel (l2)",
}


def retired(name: str) -> str | None:
    """What replaced a removed setting (None: not removed)."""
    return RETIRED.get(name)


def check(name: str, value) -> object:
    return BY_NAME[name].check(value)


def _show(value) -> str:
    return str(value).lower() if isinstance(value, bool) else f"{value:g}" if isinstance(value, float) else str(value)
