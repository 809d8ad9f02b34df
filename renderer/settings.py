"""A frame's settings, without a GL context: the shading mode, the background and FrameSettings (the
registry's frame settings, checked against their limits). renderer/renderer.py renders with them; the
service validates requests against them without importing GL."""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, asdict, field, make_dataclass
from enum import Enum

import numpy as np

from . import config
from .aovs import parse_aovs
from .errors import InvalidInputError


class ShadingMode(str, Enum):
    """The paper's Figure 6 comparison (full method, no occlusion, grey AO, AO with colour) and the
    plain many-light baseline. The product offers the first two (the `mode` option of the command line
    and the service); the three baselines are the lab's comparisons (garment_lab/run.py), reached
    through FrameSettings alone."""

    FULL = "full"
    NO_OCCLUSION = "none"
    AO_GREY = "ao"
    AO_COLOUR = "ao-color"
    MANY_LIGHTS = "many-lights"  # baseline: the N lights shade too (no PEMs), paper's introduction


class Background(str, Enum):
    """What is behind the scene: the map; nothing (alpha 0); or nothing, the scene's shadow catcher
    (Scene.catcher: a floor) drawn as the shadows on it alone, black with alpha the share of the
    light the other meshes take from it, for product images composited over any backdrop."""

    ENVIRONMENT = "env"
    BLACK = "black"
    SHADOW_CATCHER = "shadow-catcher"


class _FrameChecks:
    """FrameSettings' checks and record (its fields are made below)."""

    def __post_init__(self):
        if not (1 <= self.width <= 8192 and 1 <= self.height <= 8192):
            raise InvalidInputError(f"image size must be within 1..8192 per side, got {self.width}x{self.height}")
        object.__setattr__(self, "bleed_reduction", config.OPTION["bleed_reduction"].check(self.bleed_reduction))
        for name in config.FRAME_SETTINGS:   # each setting against its declared limits (renderer/config.py)
            object.__setattr__(self, name, config.check(name, getattr(self, name)))
        if (why := config.shadow_side_error(self.shadow_size, self.small_light_scale)) is not None:
            raise InvalidInputError(why)
        turn = self.environment_rotation_deg
        if isinstance(turn, bool) or not isinstance(turn, (int, float, np.integer, np.floating)) \
                or not math.isfinite(float(turn)):
            raise InvalidInputError(f"environment rotation must be a finite number of degrees, got {turn!r}")
        # One angle, one plan: 360 is 0 and -90 is 270 (renderer/lighting/pem.py, PEMSet.turned).
        object.__setattr__(self, "environment_rotation_deg", float(turn) % 360.0)
        object.__setattr__(self, "aovs", parse_aovs(self.aovs))

    def as_dict(self) -> dict:
        d = asdict(self)
        d["mode"], d["background"], d["aovs"] = self.mode.value, self.background.value, list(self.aovs)
        return d


FrameSettings = make_dataclass(
    "FrameSettings",
    [("width", int, field(default=512)), ("height", int, field(default=512)), ("_", KW_ONLY),   # the size by position
     *config.fields(config.FRAME_SETTINGS),
     ("bleed_reduction", float, field(default=config.OPTION["bleed_reduction"].default)),
     ("mode", ShadingMode, field(default=ShadingMode.FULL)),
     ("background", Background, field(default=Background.ENVIRONMENT)),
     ("environment_rotation_deg", float, field(default=0.0)),
     ("aovs", tuple, field(default=()))],
    bases=(_FrameChecks,), frozen=True, namespace={"__module__": __name__, "__doc__": (
        "Per-frame quality and output settings (the PEM set's are PEMSettings): the image's size, every frame "
        "setting of the registry (renderer/config.py: each one's type, limits, default and what it does), "
        "bleed_reduction, the shading mode, the background and the environment's rotation about the up axis "
        "(degrees, counter-clockwise seen from above: a light at direction d is lit from R d; the PEM set is not "
        "made again), and the passes beside the image (renderer/aovs.py: depth, normal, albedo, id; Frame.aovs). "
        "FrameSettings() is the paper's method; a preset's "
        "settings come from presets.resolve(...).frame(width, height).")})
PAPER_FRAME = FrameSettings()   # render()'s default settings: the paper's method at 512 x 512
