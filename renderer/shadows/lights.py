"""Per-light GPU data and light-space projections fitted to the casters' bounds.

Each median-cut region becomes a directional light at its energy centroid. Its shadow map is an
orthographic view along -direction whose square footprint and depth range are fitted to the
bounding box of the shadow casters, widened by the blur's reach so that filtering never reads past
the map's edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import box_corners

# Shadow groups (Scene): each caster's moments go to its group's pair of the shadow maps; a receiver
# compares against its own group's pair with the bias that keeps a surface from shadowing itself and
# against the other's without it. A mesh that casts nothing is in neither (RECEIVER_ONLY: no bias on both).
SHADOW_GROUPS = 2
RECEIVER_ONLY = SHADOW_GROUPS


def shadow_groups(casters: list[bool]) -> list[int]:
    """Each mesh's shadow group: the first caster (the garment of a garment-and-body scene) alone in
    group 0, every other caster in group 1, a mesh that casts nothing RECEIVER_ONLY. A group's own
    surfaces shadow each other through the bias; between the groups no bias hides a near occluder."""
    groups, first = [], True
    for c in casters:
        groups.append(RECEIVER_ONLY if not c else 0 if first else 1)
        first = first and not c
    return groups

# Bytes per texel, layer and shadow group: (z, z^2) as float32 (RG32F; shadows/vsm.py).
GROUP_MOMENT_BYTES = 8

# Mirror of `struct Light` in shaders/common/lights.glsl (std430; mat4 is column-major).
LIGHT_DTYPE = np.dtype([
    ("view_proj", np.float32, (16,)),
    ("dir_scale", np.float32, (4,)),
    ("params", np.float32, (4,)),
    ("energy", np.float32, (4,)),
    ("shadow", np.float32, (4,)),
])

# Lights of angular radius up to asin(0.1) ~ 5.7 degrees count as small (a sun): their shadows are
# sharp. The shaders get it as the define SMALL_LIGHT_MAX_SIN (renderer.py).
SMALL_LIGHT_MAX_SIN = 0.1

# Assumed occluder-to-receiver distance as a fraction of the shadow map's footprint; it turns a
# region's angular radius into a blur width (penumbra ~ distance * tan(angular radius)).
PENUMBRA_DEPTH_FRACTION = 0.1
MIN_SIGMA_TEXELS = 0.5
MAX_BLUR_RADIUS = 96  # texels; the box-cascade blur costs the same for any radius


def shadow_layers(energy_luminance: np.ndarray, threshold: float) -> np.ndarray:
    """Shadow-map layer of each light, -1 for lights whose share of the total energy is below
    `threshold` (their PEMs are added unshadowed: an error too small to see, a pass saved)."""
    total = float(energy_luminance.sum())
    share = energy_luminance / total if total > 0 else np.zeros_like(energy_luminance)
    shadowed = share >= threshold
    layers = np.full(len(energy_luminance), -1, np.int32)
    layers[shadowed] = np.arange(int(shadowed.sum()), dtype=np.int32)
    return layers


@dataclass
class LayerPlan:
    """Where each light's shadow map lives: the main layer array (shadow_size^2) or, for small lights
    when small_light_scale k > 1, the sharp array (k shadow_size per side, drawn at full caster
    detail).

    layer: (N,) int32, the light's layer in its array, -1 without a shadow map; sharp: (N,) bool, the
    light's map is in the sharp array; main_lights / sharp_lights: the light of each layer of the two
    arrays."""

    layer: np.ndarray
    sharp: np.ndarray
    main_lights: np.ndarray
    sharp_lights: np.ndarray

    @property
    def n_layers(self) -> int:
        return int(len(self.main_lights) + len(self.sharp_lights))


def plan_layers(layers: np.ndarray, small: np.ndarray, small_light_scale: int) -> LayerPlan:
    """Layer plan from `shadow_layers` (-1: no shadow map) and which lights are small: with a scale
    k > 1 the small lights' maps go to the sharp array, the others stay in the main one."""
    shadowed = layers >= 0
    sharp = shadowed & small & (small_light_scale > 1)
    main = shadowed & ~sharp
    layer = np.full(len(layers), -1, np.int32)
    layer[main] = np.arange(int(main.sum()), dtype=np.int32)
    layer[sharp] = np.arange(int(sharp.sum()), dtype=np.int32)
    return LayerPlan(layer, sharp, np.nonzero(main)[0].astype(np.int32), np.nonzero(sharp)[0].astype(np.int32))


def share_sharp_maps(plan: LayerPlan, directions: np.ndarray, energy: np.ndarray, max_angle_rad: float,
                     radii: np.ndarray | None = None) -> tuple[LayerPlan, np.ndarray]:
    """Sharp lights within `max_angle_rad` of a brighter sharp light share its map (a sun split by the
    median cut into a few regions a degree apart): brightest first, each light joins the first group
    whose leader is that close, else leads a group of its own. With `radii` (each light's angular
    radius) only lights whose discs overlap the leader's join it (angle <= the sum of the radii): each
    one's own spread then covers the offset, while point-like parts a degree apart (a sun split into
    many regions) keep their maps, whose offsets draw the sun's penumbra. Returns the new plan and each
    light's shadow direction (its group's energy-weighted mean direction; its own outside groups).
    The lights keep their own directions and energies for shading; only their visibility is shared."""
    shadow_dirs = np.array(directions, np.float64, copy=True)
    if max_angle_rad <= 0.0 or len(plan.sharp_lights) == 0:
        return plan, shadow_dirs

    def close(i: int, lead: int) -> bool:
        limit = max_angle_rad if radii is None else min(max_angle_rad, float(radii[i] + radii[lead]))
        return float(directions[i] @ directions[lead]) >= np.cos(limit)

    order = plan.sharp_lights[np.argsort(-energy[plan.sharp_lights], kind="stable")]
    groups: list[list[int]] = []
    for i in order:
        for members in groups:
            if close(i, members[0]):
                members.append(int(i))
                break
        else:
            groups.append([int(i)])
    sharp = np.zeros_like(plan.sharp)
    layer = np.full(len(plan.layer), -1, np.int32)
    for g, members in enumerate(groups):
        m = np.array(members)
        sharp[m] = True
        layer[m] = g
        if len(m) > 1:
            d = (energy[m, None] * directions[m]).sum(axis=0)
            norm, total = float(np.linalg.norm(d)), float(energy[m].sum())
            # Members far apart could cancel (or carry no energy): the brightest light's direction then.
            shadow_dirs[m] = d / norm if norm > 0.5 * total else directions[m[0]]
    main = (plan.layer >= 0) & ~sharp
    layer[main] = np.arange(int(main.sum()), dtype=np.int32)
    return (LayerPlan(layer, sharp, np.nonzero(main)[0].astype(np.int32),
                      np.array([members[0] for members in groups], np.int32)), shadow_dirs)


def light_basis(direction: np.ndarray) -> np.ndarray:
    """Rows: right, up, forward (= -direction) of a light looking at the scene. (3, 3) float64, or
    (N, 3, 3) for directions (N, 3)."""
    f = -np.asarray(direction, np.float64)
    f = f / np.linalg.norm(f, axis=-1, keepdims=True)
    hint = np.where((np.abs(f[..., 1]) < 0.99)[..., None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    right = np.cross(f, hint)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    up = np.cross(right, f)
    return np.stack([right, up, f], axis=-2)


def blur_sigma_texels(angular_radius_rad: np.ndarray, shadow_size: int, blur_scale: float) -> np.ndarray:
    theta = np.minimum(angular_radius_rad, np.radians(60.0))
    sigma = blur_scale * np.tan(theta) * shadow_size * PENUMBRA_DEPTH_FRACTION
    return np.clip(sigma, MIN_SIGMA_TEXELS if blur_scale > 0 else 0.0, MAX_BLUR_RADIUS / 3.0)


# Footprint sizes a light's map can take per octave (fit_light_view_projs): 8 steps cost at most 9 %
# (on average 4 %) of the map's resolution.
FOOTPRINT_STEPS_PER_OCTAVE = 8
# The least depth range of a light's projection, in its texels (fit_light_view_projs).
MIN_DEPTH_TEXELS = 16.0


def _box_in_light_space(basis: np.ndarray, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Per light (basis (N, 3, 3)), the least and greatest light-space coordinates of a box's corners."""
    ls = np.einsum("cj,nij->nci", box_corners(lo, hi), basis)             # (N, 8, 3)
    return ls.min(axis=1), ls.max(axis=1)


def fit_light_view_projs(directions: np.ndarray, lo: np.ndarray, hi: np.ndarray, sigma_texels: np.ndarray,
                         shadow_size, unit: float = 1.0, receivers: tuple | None = None) -> np.ndarray:
    """World -> light clip matrices (N, 4, 4) float64 of N directions (N, 3): x, y in [-1, 1] over the
    casters' box (lo, hi), depth z in [0, 1] from its nearest to its farthest corner (GL clip space
    with w = 1). The footprint is square (the larger of its two sides), so that a blur in texels stays
    isotropic; shadow_size is one size or each light's; its sizes are steps relative to `unit` (a
    length fixed for the scene, e.g. Scene.footprint_unit).

    `receivers`: the box (lo, hi) of what the camera can see (Scene.visible_bounds). A directional
    light's shadow falls along its own depth axis, so only casters over a seen receiver's x, y can
    shadow it: the footprint is the casters' x, y range where it overlaps the receivers', and the
    depth range stays the casters' (a caster out of view still shadows what is in view). A body's
    head, legs and outstretched arms out of the frame no longer spread the texels over them."""
    basis = light_basis(directions)                                        # (N, 3, 3)
    cmin, cmax = _box_in_light_space(basis, lo, hi)
    if receivers is not None:
        rmin, rmax = _box_in_light_space(basis, *receivers)
        xy_lo, xy_hi = np.maximum(cmin[:, :2], rmin[:, :2]), np.minimum(cmax[:, :2], rmax[:, :2])
        overlap = (xy_hi > xy_lo).all(axis=1)   # else nothing seen lies under a caster: the casters' own
        cmin[overlap, :2], cmax[overlap, :2] = xy_lo[overlap], xy_hi[overlap]
    centre = 0.5 * (cmin + cmax)
    tiny = np.maximum(1e-12 * np.maximum(1.0, np.abs(centre).max(axis=1)), 1e-30)
    half_xy = 0.5 * (cmax[:, :2] - cmin[:, :2])
    half_xy = np.repeat(half_xy.max(axis=1, keepdims=True), 2, axis=1)
    half_xy = np.maximum(half_xy, np.maximum(tiny, 1e-6 * half_xy.max(axis=1))[:, None])
    # Widen by the blur's reach (3 sigma texels) plus one texel for rasterization at the border.
    size = np.broadcast_to(np.asarray(shadow_size, np.float64), (len(basis),))[:, None]   # per light, or one for all
    half_xy = half_xy * (1.0 + 2.0 * (3.0 * np.asarray(sigma_texels, np.float64)[:, None] + 1.0) / size)
    # Stable texel grids: the casters' box follows the cloth every frame, and a footprint fitted to
    # it exactly would slide the texel grid under static geometry (a floor, the body) every frame,
    # so that shadow edges there shimmer. The footprint's size is rounded up to one of
    # FOOTPRINT_STEPS_PER_OCTAVE sizes per octave and its centre to whole texels: the grid moves
    # only when the size steps. The centre's rounding moves the box by up to half a texel: half a
    # texel more here, and the texel of rasterization border above, keep it inside.
    half_xy = half_xy * (1.0 + 1.0 / size)
    steps = np.ceil(np.log2(half_xy / unit) * FOOTPRINT_STEPS_PER_OCTAVE)
    half_xy = unit * np.exp2(steps / FOOTPRINT_STEPS_PER_OCTAVE)
    texel = 2.0 * half_xy / size
    centre = centre.copy()
    centre[:, :2] = np.round(centre[:, :2] / texel) * texel
    # At least MIN_DEPTH_TEXELS texels deep: a box thin along the light (a flat sheet lit along its
    # normal) would otherwise make a texel many depth ranges wide, and the variance floor, stated in
    # texels, would let light through the sheet onto receivers behind it.
    depth = np.maximum(cmax[:, 2] - cmin[:, 2], MIN_DEPTH_TEXELS * texel[:, 0])
    z0 = cmin[:, 2] - 0.01 * depth
    z_range = 1.02 * depth
    m = np.zeros((len(basis), 4, 4))
    m[:, 0, :3] = basis[:, 0] / half_xy[:, :1]
    m[:, 0, 3] = -centre[:, 0] / half_xy[:, 0]
    m[:, 1, :3] = basis[:, 1] / half_xy[:, 1:]
    m[:, 1, 3] = -centre[:, 1] / half_xy[:, 1]
    m[:, 2, :3] = basis[:, 2] / z_range[:, None]
    m[:, 2, 3] = -z0 / z_range
    m[:, 3, 3] = 1.0
    return m


def texel_sizes(view_proj: np.ndarray, shadow_size) -> np.ndarray:
    """(N, 2) float64: the width of one texel of each light's map (shadow_size texels a side, one
    size or each light's) in world units and in the light's depth units (its depth range is 1), read
    from the rows of `fit_light_view_projs`' matrices (x row: 1 / half width; z row: 1 / range)."""
    vp = np.asarray(view_proj, np.float64)
    width = 2.0 / np.linalg.norm(vp[:, 0, :3], axis=1) / np.asarray(shadow_size, np.float64)
    return np.stack([width, width * np.linalg.norm(vp[:, 2, :3], axis=1)], axis=1)


def disc_sine(radius_rad) -> np.ndarray:
    """Sine of a light's angular radius as the shading pass reads it (params.w, a glossy disc's):
    clamped to [1e-3 rad, 90 degrees], so that a point-like light keeps a finite lobe exponent."""
    return np.sin(np.clip(np.asarray(radius_rad, np.float64), 1e-3, np.pi / 2))


def small_lights(radius_rad) -> np.ndarray:
    """Which lights are small (a sun): the one rule, on the float32 sine the shaders are given; the
    light plan (sharp maps, closed-form terms) and the lighting pass (pack_lights' shadow.w) read it."""
    return disc_sine(radius_rad).astype(np.float32) <= np.float32(SMALL_LIGHT_MAX_SIN)


def pack_lights(directions, scales, solid_angle_sr, energy_rgb, view_proj, sigma, shadow_layer,
                radius_rad=None, sharp=None, texel=None, blocker=None) -> np.ndarray:
    """Build the std430 array of `struct Light` for n lights; shadow_layer[i] = -1: no shadow map
    (else its layer); radius_rad: angular radius of each light's energy (for the horizon term),
    default 0; sharp: the light's map is in the sharp array (default none); texel: (N, 2) the width
    of one texel of its map in world units and in its depth units (`texel_sizes`; default 0, 0);
    blocker: the light's penumbra follows the blocker's distance (FrameSettings.penumbra; default none)."""
    n = len(directions)
    arr = np.zeros(n, LIGHT_DTYPE)
    arr["view_proj"] = np.transpose(view_proj, (0, 2, 1)).reshape(n, 16)  # column-major for GLSL
    arr["dir_scale"][:, :3] = directions
    arr["dir_scale"][:, 3] = scales
    arr["params"][:, 0] = sigma
    arr["params"][:, 2] = solid_angle_sr
    arr["params"][:, 3] = disc_sine(radius_rad if radius_rad is not None else np.zeros(n))
    arr["energy"][:, :3] = energy_rgb
    arr["energy"][:, 3] = np.asarray(blocker, np.float32) if blocker is not None else 0.0
    arr["shadow"][:, 0] = shadow_layer
    arr["shadow"][:, 1] = np.asarray(sharp, np.float32) if sharp is not None else 0.0
    texel = np.zeros((n, 2)) if texel is None else np.asarray(texel, np.float64)
    arr["shadow"][:, 2] = texel[:, 0]
    # Small (a sun): decided here once, on the packed sine the shaders see, and read by both the light
    # plan (renderer.plan.light_kinds) and the lighting pass.
    arr["shadow"][:, 3] = small_lights(radius_rad if radius_rad is not None else np.zeros(n))
    arr["params"][:, 1] = texel[:, 1]
    return arr
