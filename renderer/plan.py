"""A frame's light and shadow plan, made on the CPU before anything is drawn (numpy, no GL): which
lights get which maps, each map's projection fitted to the casters and to what the cameras see, the
packed light records the shaders read, the lighting pass's order of the lights by kind and the contact
search's reach. The Renderer binds and dispatches what a plan says (renderer/renderer.py); the costs
count with the same rule (renderer/costs.py, light_maps).

Projections are fitted to boxes snapped to a grid (snap_box), so a plan is a function of the PEM set,
the settings and the snapped boxes alone: LightPlanner keeps the last one while they stay (a garment
moving within its cells), as the shadow pass keeps the still casters' maps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .costs import light_maps
from .gpu.contract import N_LIGHT_KINDS, WIDE_LOBE_DISC_VARIANCE, LightKind
from .lighting.pem_plan import REGIONS_PER_TEXTURE
from .settings import FrameSettings, ShadingMode
from .shadows.lights import blur_sigma_texels, fit_light_view_projs, pack_lights, texel_sizes

if TYPE_CHECKING:
    from .lighting.pem import PEMSet
    from .scene import Scene

# The modes whose lighting pass has closed-form terms (the others read every PEM).
CLOSED_FORM_MODES = (ShadingMode.FULL, ShadingMode.NO_OCCLUSION)
# light_kinds: a large light counts as wide at every pixel only by this margin in 1 - g (a pixel's g is
# interpolated in float32 between vertices or texels).
WIDE_LOBE_MARGIN = 1e-3
# snap_box: a box's sides snap outwards to a grid of at least this many cells along its longest side.
SNAP_CELLS = 16


def glossy_closed_form(mode: ShadingMode, glossy: str) -> bool:
    """Whether some light's glossy term is in closed form (with "wide": small lights', and large ones'
    where the lobe is wide): what FrameSettings.sub_lights applies to."""
    return mode in CLOSED_FORM_MODES and glossy == "wide"


def no_diffuse_pems(mode: ShadingMode, diffuse: str) -> bool:
    """Every light's diffuse term without PEM lookups: the DIFFUSE_LIGHTS program variant, whose
    loops are compiled only for the kinds light_kinds then gives (one rule for both)."""
    return diffuse == "lights" and mode in CLOSED_FORM_MODES


def discs_per_region(settings: FrameSettings) -> int:
    """The glossy discs each region is cut into (FrameSettings.sub_lights where some glossy term is in
    closed form, else 1): the PEM set's disc table the lighting pass reads and its program's loops."""
    return settings.sub_lights if glossy_closed_form(settings.mode, settings.glossy) else 1


def light_kinds(lights: np.ndarray, sharp: np.ndarray, settings: FrameSettings,
                max_glossiness: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The lighting pass's order of the lights and the end of each kind in it (int32 arrays: the
    light_order buffer and u_kind_end of lighting.frag). A light's kind, the bits of LightKind
    (renderer/gpu/contract.py): it reads its diffuse PEM, its glossy PEM, its map is in the sharp
    array, its region is in the second PEM texture. Whether a term comes from the PEM follows the
    shader's modes: in the full and no-occlusion modes every light's diffuse term is in closed form
    with diffuse "lights", and small lights' (angular radius <= ~6 degrees) glossy term with glossy
    "wide"; there a large light whose disc is narrower than the lobe at every pixel (at the scene's
    `max_glossiness`, the widest lobe being the least glossy) has its glossy term in closed form
    everywhere: its glossy PEM is not read (the shader's wide_lobe would discard the lookup at every
    pixel; a CPU rasterizer runs it anyway)."""
    n = len(lights)
    exact_modes = settings.mode in CLOSED_FORM_MODES
    small = lights["shadow"][:, 3] > 0.5   # pack_lights' flag, which the lighting pass reads too
    pem_diffuse = np.full(n, not no_diffuse_pems(settings.mode, settings.diffuse))
    pem_glossy = ~(small & glossy_closed_form(settings.mode, settings.glossy))
    if exact_modes and settings.glossy == "wide":
        # wide_lobe in lighting.frag at the glossiest pixel, with a margin for the interpolated g.
        sin_a = lights["params"][:, 3].astype(np.float64)
        pem_glossy &= ~(max(1.0 - max_glossiness, 0.0) - WIDE_LOBE_MARGIN >= WIDE_LOBE_DISC_VARIANCE * sin_a * sin_a)
    second = np.arange(n) >= REGIONS_PER_TEXTURE
    kind = (pem_diffuse.astype(np.int32) * LightKind.PEM_DIFFUSE | pem_glossy.astype(np.int32) * LightKind.PEM_GLOSSY
            | np.asarray(sharp, np.int32) * LightKind.SHARP | second.astype(np.int32) * LightKind.SECOND_PEM)
    order = np.argsort(kind, kind="stable").astype(np.int32)
    kind_end = np.searchsorted(kind[order], np.arange(1, N_LIGHT_KINDS + 1)).astype(np.int32)
    return order, kind_end


def snap_box(lo: np.ndarray, hi: np.ndarray, unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi) grown outwards to a grid of cells `unit` x a power of two, between
    1/(2 SNAP_CELLS) and 1/SNAP_CELLS of its longest side (`unit`: a length fixed for the scene,
    Scene.footprint_unit, so that a scene's scale does not change its picture). A function of the box
    alone (the same positions give the same maps), and the same box while what moves stays inside its
    cells: the shadow maps are fitted to snapped boxes, so a garment moving a little keeps its maps'
    projections and the casters that hold still need not be drawn again (shadows/vsm.py)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = float((hi - lo).max())
    scale = max(extent, float(np.abs(np.concatenate([lo, hi])).max()) * 1e-6, 1e-300)
    cell = unit * float(np.exp2(np.floor(np.log2(scale / unit / SNAP_CELLS))))
    return np.floor(lo / cell) * cell, np.ceil(hi / cell) * cell


@dataclass
class LightPlan:
    """A frame's lights as the passes need them: the PEM set's regions, each light's layer, disc, map
    plan and shadow direction, map size, blur width, projection's texel size, the packed records the
    shaders read and the contact search's distance."""

    regions: object
    layers: np.ndarray
    disc_radius: np.ndarray
    plan: object
    shadow_dirs: np.ndarray
    sizes: np.ndarray
    sigma: np.ndarray
    blur: bool
    texels: np.ndarray
    lights: np.ndarray
    blocker: bool    # some light's penumbra follows the blocker's distance (the main maps carry MIP chains)
    # The contact search's distance in world units (settings.contact_shadow_texels of the main maps'
    # median texel over all the casters; 0: no search).
    contact_radius: float
    # The lights in the lighting pass's order, by kind, and where each kind ends (light_kinds): what
    # the pass's loops read.
    order: np.ndarray | None = None
    kind_end: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.regions.n_regions

    @property
    def n_shadowed(self) -> int:
        return int((self.layers >= 0).sum())


def plan_lights(pems: PEMSet, settings: FrameSettings, fit_lo: np.ndarray, fit_hi: np.ndarray,
                fit_receivers: tuple[np.ndarray, np.ndarray] | None, unit: float) -> LightPlan:
    """The lights and their maps from the snapped boxes (the contact search's distance 0, no order yet:
    LightPlanner.plan adds them)."""
    regions = pems.regions
    # Which lights get which maps (renderer/costs.py, light_maps: the rule the costs count with).
    plan, shadow_dirs = light_maps(regions, settings)
    n = regions.n_regions
    # Every light has a map (none in the no-occlusion mode).
    shadowed = settings.mode is not ShadingMode.NO_OCCLUSION
    layers = np.arange(n, dtype=np.int32) if shadowed else np.full(n, -1, np.int32)
    disc_radius = regions.disc_radius_rad()
    k = settings.small_light_scale
    # Each light's map size; blur widths are in the light's own texels.
    sizes = np.where(plan.sharp, settings.shadow_size * k, settings.shadow_size)
    sigma = blur_sigma_texels(regions.light_radius_rad(), sizes, settings.blur_scale)
    blur = bool((sigma > 0).any())   # blur scale 0 (every preset): the maps stay as drawn
    # Square texels: the blur's sigma is in texels, the same on both axes, so rectangular texels
    # would make penumbrae anisotropic (a side run fitting x and y separately gained 0-2.5 %).
    vp = fit_light_view_projs(shadow_dirs, fit_lo, fit_hi, sigma, sizes, unit, fit_receivers)
    # Lights sharing a map look it up through the projection it was drawn with (its first light's:
    # with a blur the fit's margin follows each light's own width).
    sharp_layer = plan.layer[plan.sharp]
    vp[plan.sharp] = vp[plan.sharp_lights[sharp_layer]]
    texels = texel_sizes(vp, sizes)
    # Contact-hardening penumbrae for the area lights in the main maps (their discs are bounded
    # sources; a median-cut region's spread is not a disc's, docs/area-bench.md).
    blocker = (settings.penumbra == "blocker") & regions.area_mask & (plan.layer >= 0) & ~plan.sharp
    lights = pack_lights(regions.directions, pems.scale, regions.solid_angle_sr, regions.energy_rgb, vp,
                         sigma, plan.layer, disc_radius, plan.sharp, texels, blocker)
    return LightPlan(regions, layers, disc_radius, plan, shadow_dirs, sizes, sigma, blur, texels, lights,
                     bool(blocker.any()), 0.0)


def contact_radius(lp: LightPlan, settings: FrameSettings, lo: np.ndarray, hi: np.ndarray, unit: float) -> float:
    """The contact search's distance in world units (0: no search): settings.contact_shadow_texels
    in main-map texels (the maps whose bias hides the contact), else the sharp maps', of maps over
    all the casters (lo, hi), not the view: the search's distance in the scene does not follow the
    camera (a closer view, finer maps, the same search)."""
    if not (settings.contact_shadow_texels > 0 and settings.mode is ShadingMode.FULL):
        return 0.0
    main = ~lp.plan.sharp
    pick = main if main.any() else np.ones(lp.n, bool)
    scene_texels = texel_sizes(fit_light_view_projs(lp.shadow_dirs[pick], lo, hi, lp.sigma[pick], lp.sizes[pick],
                                                    unit), lp.sizes[pick])
    return settings.contact_shadow_texels * float(np.median(scene_texels[:, 0]))


class LightPlanner:
    """Plans frame after frame for one renderer, keeping the last plan while its PEM set, settings and
    snapped boxes stay."""

    def __init__(self):
        self._kept: tuple | None = None   # (its PEM set, its key, the plan)
        self.hits = 0                     # plans kept, not made (tests)

    def forget(self) -> None:
        """The next plan is made anew."""
        self._kept = None

    def plan(self, scene: Scene, pems: PEMSet, settings: FrameSettings,
             receivers: tuple[np.ndarray, np.ndarray] | None) -> LightPlan:
        """Which lights get which maps, and each map's projection: once per frame. `receivers`: the box
        of what the cameras see (Scene.visible_bounds; None: all the casters)."""
        # Lights: directions and energies from the PEM set, projections fitted to the casters now,
        # over the receivers in view, each box snapped to the scene's grid.
        lo, hi = scene.bounds(casters_only=True)
        fit_lo, fit_hi = snap_box(lo, hi, scene.footprint_unit)
        fit_receivers = None if receivers is None else snap_box(*receivers, scene.footprint_unit)
        key = (settings, scene.footprint_unit, fit_lo.tobytes(), fit_hi.tobytes(),
               None if fit_receivers is None else b"".join(b.tobytes() for b in fit_receivers))
        kept = self._kept
        if kept is not None and kept[0] is pems and kept[1] == key:
            lp = kept[2]
            self.hits += 1
        else:
            self._kept = None   # a plan that fails half-way leaves nothing to be kept
            lp = plan_lights(pems, settings, fit_lo, fit_hi, fit_receivers, scene.footprint_unit)
            self._kept = (pems, key, lp)
        # The contact search's reach follows the casters' own box (made every frame); the lights' order
        # follows the scene's materials.
        order, kind_end = light_kinds(lp.lights, lp.plan.sharp, settings, scene.max_glossiness)
        return replace(lp, contact_radius=contact_radius(lp, settings, lo, hi, scene.footprint_unit),
                       order=order, kind_end=kind_end)
