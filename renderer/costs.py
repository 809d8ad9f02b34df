"""What a frame allocates on the GL device, known before any of it is made: the shadow-map arrays
(main and sharp, shadows/vsm.py ShadowMaps), the render targets (renderer.py _Targets, and the still
meshes' _StillTarget) and the PEM set (lighting/pem.py PEMSet). A service judges a scene against its
limits with it, and a test holds it to what the renderer's objects hold.

The shadow maps are most of it, and their layout is the light plan's: which lights get sharp maps, and
how many of those share one, is known only after the median cut (`plan_maps` on the PEM set's
regions). From the settings alone `frame_cost` gives a bound instead, and the least any map can give
(`FrameCost.least_shadow_bytes`), so that a request no map can fit is refused before a PEM set is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .config import most_sharp_lights
from .lighting.median_cut import RegionSet
from .lighting.pem_plan import PEMSettings, pem_cost
from .shadows.lights import GROUP_MOMENT_BYTES, LayerPlan, plan_layers, shadow_groups, share_sharp_maps, small_lights

if TYPE_CHECKING:   # renderer.py may plan with this module one day: no import of it at run time
    from .settings import FrameSettings

# Bytes a texel of the render targets (renderer.py _geometry_targets, _Targets, _StillTarget): the
# lighting pass's output, the G-buffer and the anti-aliased image are RGBA32F; a depth texture or
# renderbuffer (GL_DEPTH_COMPONENT24) takes a 32-bit word a sample on the drivers we run.
RGBA32F_BYTES = 16
DEPTH_BYTES = 4
G_BUFFER_TARGETS = 4          # position + specular, normal + glossiness, geometric normal, albedo
PBR_G_BUFFER_TARGETS = 5      # ... and the physically based materials' parameters
# ShadowMaps.casters (penumbra "blocker"): each texel's caster share per group, two float16.
CASTER_SHARE_BYTES = 4


def _mip_chain_texels(size: int) -> int:
    """Texels of a square map's MIP levels below level 0 (ShadowMaps.nbytes' chain)."""
    return sum((size >> k) ** 2 for k in range(1, size.bit_length()))


def _array_bytes(size: int, layers: int, groups: int, blur: bool, mipmapped: bool) -> int:
    """ShadowMaps.nbytes of an array of `layers` layers a group: the moments, the blur's scratch,
    and with `mipmapped` their MIP chain and the caster shares with theirs."""
    if layers == 0:
        return 0
    chain = _mip_chain_texels(size) if mipmapped else 0
    moments = (size * size * groups * layers * (2 if blur else 1) + chain * groups * layers) * GROUP_MOMENT_BYTES
    shares = (size * size + chain) * layers * CASTER_SHARE_BYTES if mipmapped else 0
    return moments + shares


def plan_maps(regions: RegionSet, settings: FrameSettings) -> LayerPlan:
    """Which of the PEM set's lights get a main map and which a sharp one, and which sharp lights share
    a map: the light plan's rule (`light_maps`) without the maps' directions. tests/test_costs.py
    holds it to the frames' own counts."""
    return light_maps(regions, settings)[0]


def light_maps(regions: RegionSet, settings: FrameSettings) -> tuple[LayerPlan, np.ndarray]:
    """The light plan's rule, written once (renderer/plan.py plans with it, the costs count with
    it): every light has a map (none in the no-occlusion mode); the small lights (angular radius under
    ~6 degrees) carrying at least small_light_min_energy x the mean light's energy, and with
    sharp_large_lights the large ones that bright too, get sharp maps; sharp lights within
    sharp_share_deg of a brighter one whose disc theirs overlaps share its map. Returns the plan and
    each light's shadow direction (a shared map's, its group's energy-weighted direction)."""
    n = regions.n_regions
    shadowed = settings.mode != "none"   # ShadingMode.NO_OCCLUSION: no light has a map
    layers = np.arange(n, dtype=np.int32) if shadowed else np.full(n, -1, np.int32)
    disc_radius = regions.disc_radius_rad()
    small = small_lights(disc_radius)
    relative = regions.energy_luminance / max(float(regions.energy_luminance.mean()), 1e-300)
    bright = relative >= settings.small_light_min_energy
    sharp = (small | settings.sharp_large_lights) & bright if settings.small_light_min_energy > 0 else small
    plan = plan_layers(layers, sharp, settings.small_light_scale)
    return share_sharp_maps(plan, regions.directions, regions.energy_luminance,
                            np.radians(settings.sharp_share_deg), disc_radius)


@dataclass(frozen=True)
class FrameCost:
    """Bytes one frame holds on the GL device (`frame_cost`), each part as the renderer's objects
    count it: main_maps_bytes and sharp_maps_bytes, ShadowMaps.nbytes of the main and sharp arrays;
    targets_bytes, the render targets' and the still meshes' own; pem_bytes, PEMSet.nbytes.
    main_layers / sharp_layers: layers a shadow group of each array (the main array keeps one when no
    light has a main map). exact: the layout is the light plan's on the PEM set's regions; else the
    settings' bound (the most sharp maps the settings allow), and least_shadow_bytes what the fewest
    any map could give would take."""

    main_maps_bytes: int
    sharp_maps_bytes: int
    targets_bytes: int
    pem_bytes: int
    main_layers: int
    sharp_layers: int
    shadow_size: int
    sharp_size: int
    shadow_groups: int
    n_lights: int
    blur: bool
    exact: bool
    least_shadow_bytes: int

    @property
    def shadow_bytes(self) -> int:
        return self.main_maps_bytes + self.sharp_maps_bytes

    @property
    def total_bytes(self) -> int:
        return self.shadow_bytes + self.targets_bytes + self.pem_bytes

    def describe(self) -> str:
        """The shadow maps' layout in words (a bound's: what may vary), for a message."""
        if self.exact:
            sharp = f" and {self.sharp_layers} sharp maps of {self.sharp_size}^2" if self.sharp_layers else ""
            layout = f"{self.main_layers} main maps of {self.shadow_size}^2{sharp} for {self.n_lights} lights"
        else:
            layout = (f"{self.n_lights} lights with maps of {self.shadow_size}^2, up to {self.sharp_layers} of them "
                      f"sharp maps of {self.sharp_size}^2 as the environment map has them")
        return (f"{layout}, {self.shadow_groups} shadow group{'s' if self.shadow_groups > 1 else ''} x "
                f"{GROUP_MOMENT_BYTES} bytes a texel{', twice for the blur' if self.blur else ''}")

    def as_dict(self) -> dict:
        return {"shadow_map_bytes": self.shadow_bytes, "main_map_bytes": self.main_maps_bytes,
                "sharp_map_bytes": self.sharp_maps_bytes, "target_bytes": self.targets_bytes,
                "pem_set_bytes": self.pem_bytes, "total_bytes": self.total_bytes, "main_maps": self.main_layers,
                "sharp_maps": self.sharp_layers, "shadow_groups": self.shadow_groups, "exact": self.exact}


def targets_bytes(width: int, height: int, aa_samples: int, pbr: bool, still_meshes: bool) -> int:
    """The render targets of a width x height frame: the lighting pass's output, the G-buffer and its
    depth; with several samples a pixel the multisampled depth, the anti-aliased image and the edge
    marks; with `still_meshes` (meshes outside shadow group 0 beside ones in it) their own G-buffer
    and depth, and their multisampled depth."""
    gbuf = (PBR_G_BUFFER_TARGETS if pbr else G_BUFFER_TARGETS) * RGBA32F_BYTES
    per_pixel = RGBA32F_BYTES + gbuf + DEPTH_BYTES
    if aa_samples > 1:
        per_pixel += DEPTH_BYTES * aa_samples + RGBA32F_BYTES + DEPTH_BYTES
    if still_meshes:
        per_pixel += gbuf + DEPTH_BYTES + (DEPTH_BYTES * aa_samples if aa_samples > 1 else 0)
    return width * height * per_pixel


def frame_cost(settings: FrameSettings, pem: PEMSettings, face_size: int, casters: Sequence[bool] = (True,), *,
               pbr: bool = False, regions: RegionSet | None = None) -> FrameCost:
    """What one frame of FrameSettings `settings` takes with the PEM set of `pem` at `face_size`, for a
    scene whose meshes cast as `casters` says (one bool a mesh, Scene's order) and with `pbr` a
    physically based material. `regions`: the PEM set's (PEMSet.regions), which give the light plan's
    own layout; None: the settings' bound (see FrameCost)."""
    groups_of = shadow_groups(list(casters))
    groups = max(len({g for g, c in zip(groups_of, casters) if c}), 1)   # Renderer._shadow_pass keeps one
    still = 0 in groups_of and any(g != 0 for g in groups_of)
    size, k = int(settings.shadow_size), int(settings.small_light_scale)
    shadowed = settings.mode != "none"
    # Every frame that draws a map blurs it when the scale is above 0 (blur_sigma_texels then gives
    # every light at least MIN_SIGMA_TEXELS), and then keeps the scratch array.
    blur = settings.blur_scale > 0
    if regions is not None:
        plan = plan_maps(regions, settings)
        n = regions.n_regions
        main, sharp = len(plan.main_lights), len(plan.sharp_lights)
        # Contact-hardening penumbrae: the main array carries MIP chains when an area light is in it.
        mipmapped = bool(((settings.penumbra == "blocker") & regions.area_mask & (plan.layer >= 0)
                          & ~plan.sharp).any())
    else:
        n = int(pem.lights)   # the regions a PEM set has at most (exactly this many from the median cut)
        sharp = most_sharp_lights(n, k, settings.small_light_min_energy) if shadowed else 0
        main = n - sharp if shadowed else 0
        # Only a PEM set with area lights has any (PEMSettings.lights_from).
        mipmapped = settings.penumbra == "blocker" and pem.lights_from != "median-cut"
    main_bytes = _array_bytes(size, max(main, 1), groups, blur and main > 0, mipmapped)
    sharp_bytes = _array_bytes(size * k, sharp, groups, blur, False)
    least = main_bytes + sharp_bytes
    if regions is None:
        # The fewest bytes any map gives: no sharp map (each is k^2 main ones), or, where sharp lights
        # share maps, every light that may be sharp in one. Area lights may be fewer than `lights`.
        shared = shadowed and sharp > 0 and settings.sharp_share_deg > 0
        fewest = n if shadowed and pem.lights_from == "median-cut" else 1
        least = min([_array_bytes(size, fewest, groups, blur and shadowed, False)]
                    + ([_array_bytes(size, max(n - sharp, 1), groups, blur and n > sharp, False)
                        + _array_bytes(size * k, 1, groups, blur, False)] if shared else []))
    exact = regions is not None or (sharp == 0 and not mipmapped and pem.lights_from == "median-cut")
    return FrameCost(
        main_maps_bytes=main_bytes, sharp_maps_bytes=sharp_bytes,
        targets_bytes=targets_bytes(settings.width, settings.height, settings.aa_samples, pbr, still),
        pem_bytes=pem_cost(face_size, pem).stored_bytes, main_layers=max(main, 1), sharp_layers=sharp,
        shadow_size=size, sharp_size=size * k, shadow_groups=groups, n_lights=n, blur=blur,
        exact=exact, least_shadow_bytes=least)
