"""Median-cut subdivision of a cube map into regions of equal energy, one directional light each.

Debevec, "A median cut algorithm for light probe sampling" (SIGGRAPH 2008 classes), applied to
each of the six cube faces separately as in Knuth et al. 2014, section 4: every face is cut k
times, each time every region is split across its longer side where its energy is halved, giving
N = 6 * 2^k regions (`median_cut`). Any other count N >= 6 (`median_cut_to`, what a PEM set's
regions come from): the cut to the largest 6 * 2^k below it, then its most energetic regions halved
once more, each by the same rule. Energy of a texel = luminance x exact texel solid angle, so regions near face
corners (smaller texels) are not over-weighted. Every texel belongs to exactly one region
(Knuth et al. Eq. 1): the partition is stored as a label per texel.

With `whole_sources` (our addition, PEMSettings.whole_sources), a cut that would pass through a
compact bright source (a sun, a lamp: a run of rows or columns at most an eighth of the region's
side wide, or two rows, each with at least SOURCE_PEAK of the brightest one's energy, together
holding at least SOURCE_SHARE of the region's) moves to the source's edge nearer the energy median, so that the
source stays in one region. Plain median cut halves the energy through the sun's disc at every
level: with 2^k regions a face, the last cuts leave parts of the sun in large regions whose single
light sits at their energy centroid, degrees away from the sun, with a wide disc.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import regions_per_face
from ..envmap.cube import cube_solid_angles, texel_directions
from ..errors import InvalidInputError

# whole_sources: a compact source's rows each carry at least this share of the brightest row's
# energy, and together at least SOURCE_SHARE of the region's (chosen on the benchmark's scenes).
SOURCE_PEAK, SOURCE_SHARE = 0.1, 0.5
# Rec. ITU-R BT.709 luminance weights (linear RGB).
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class RegionSet:
    """The partition of a cube map and its lights.

    labels: int32 (6, F, F), region id of every texel; ids are face-major (face * 2^k + i).
    directions: float64 (N, 3), unit direction of each light (energy centroid of its region).
    solid_angle_sr: float64 (N,), solid angle of each region.
    energy_rgb: float64 (N, 3), integral of radiance over the region (W/m^2 per channel if the map
        is in W/(m^2 sr)).
    rects: int32 (N, 5): face, row0, row1, col0, col1 (half-open) of each region.
    spread_rad: float64 (N,), angular radius of the region's light as seen from the scene: sqrt(2)
        times the energy-weighted RMS angle between the region's texels and its light (exact for a
        uniform disc). A large region whose energy sits in a small sun has a small spread: the
        shadow's softness follows where the energy is, not the region's outline.
    mean_cos: float64 (N,), energy-weighted mean cosine between the region's texels and its light
        (the length of the region's mean direction vector): E_i * mean_cos_i * (n . l_i) is the exact
        cosine-weighted integral over a region entirely above the horizon of n.
    """

    labels: np.ndarray
    directions: np.ndarray
    solid_angle_sr: np.ndarray
    energy_rgb: np.ndarray
    rects: np.ndarray
    spread_rad: np.ndarray
    mean_cos: np.ndarray
    # bool (N,): the region is an area light's disc (lighting/area_lights.py, area_regions); None: a
    # plain median cut. A disc region's rect is one texel of it (its peak and sub-lights come from
    # the labels, not the rect).
    area: np.ndarray | None = None

    @property
    def n_regions(self) -> int:
        return int(self.directions.shape[0])

    @property
    def energy_luminance(self) -> np.ndarray:
        return self.energy_rgb @ LUMINANCE_RGB

    def angular_radius_rad(self) -> np.ndarray:
        """Radius of the cone with the region's solid angle: Omega = 2*pi*(1 - cos r)."""
        return np.arccos(np.clip(1.0 - self.solid_angle_sr / (2.0 * np.pi), -1.0, 1.0))

    def disc_radius_rad(self) -> np.ndarray:
        """Radius of the uniform disc with the region's mean cosine ((1 + cos r) / 2 = mean_cos)."""
        return np.arccos(np.clip(2.0 * self.mean_cos - 1.0, -1.0, 1.0))

    @property
    def area_mask(self) -> np.ndarray:
        """bool (N,): which regions are area lights' discs (all False for a plain median cut)."""
        return self.area if self.area is not None else np.zeros(self.n_regions, bool)

    def light_radius_rad(self) -> np.ndarray:
        """Angular radius that sets the shadow softness: the energy spread, at most the region's cone."""
        return np.minimum(self.spread_rad, self.angular_radius_rad())


def _split(energy: np.ndarray, rect: tuple[int, int, int, int], whole_sources: bool = False):
    """Split one rectangle across its longer side where its energy is halved (two rectangles); with
    whole_sources, not through a compact bright source (see the module doc)."""
    r0, r1, c0, c1 = rect
    h, w = r1 - r0, c1 - c0
    axis = 0 if h >= w else 1  # split across the longer side (rows if taller)
    length = h if axis == 0 else w
    profile = energy[r0:r1, c0:c1].sum(axis=1 - axis)  # energy per row (axis 0) or per column (axis 1)
    cum = np.cumsum(profile)
    total = cum[-1]
    if total > 0:
        # First index where the cumulative energy reaches half: the median line; then take the side
        # of the median texel that balances better.
        split = int(np.searchsorted(cum, 0.5 * total)) + 1
        if split - 1 >= 1 and abs(cum[split - 2] - 0.5 * total) <= abs(cum[split - 1] - 0.5 * total):
            split -= 1
    else:
        split = length // 2  # no energy: cut geometrically
    split = min(max(split, 1), length - 1)
    if whole_sources and total > 0:
        split = _beside_source(profile, cum, split)
    if axis == 0:
        return (r0, r0 + split, c0, c1), (r0 + split, r1, c0, c1)
    return (r0, r1, c0, c0 + split), (r0, r1, c0 + split, c1)


def _beside_source(profile: np.ndarray, cum: np.ndarray, split: int) -> int:
    """The median split (rows [0, split) | [split, length)) moved to the nearer edge of a compact
    bright source it would pass through; unchanged when it passes through none."""
    length = len(profile)
    bright = profile >= SOURCE_PEAK * profile.max()
    if not (bright[split - 1] and bright[split]):
        return split
    lo, hi = split - 1, split   # the bright run around the cut: rows lo..hi
    while lo > 0 and bright[lo - 1]:
        lo -= 1
    while hi < length - 1 and bright[hi + 1]:
        hi += 1
    if hi - lo + 1 > max(2, length // 8) or cum[hi] - (cum[lo - 1] if lo else 0.0) < SOURCE_SHARE * cum[-1]:
        return split   # not compact, or not where the region's energy is: a plain median cut
    edges = [e for e in (lo, hi + 1) if 1 <= e <= length - 1]
    return min(edges, key=lambda e: abs(cum[e - 1] - 0.5 * cum[-1])) if edges else split


def _cut_face(energy: np.ndarray, cuts: int, whole_sources: bool = False) -> list[tuple[int, int, int, int]]:
    """Median-cut one face's energy grid (F, F) `cuts` times; returns 2^cuts (r0, r1, c0, c1) rectangles.

    A region that has shrunk to one texel (a very bright texel) cannot be halved; it is kept, and
    the largest splittable region of the face is split once more instead, so the count stays 2^k.
    """
    rects = [(0, energy.shape[0], 0, energy.shape[1])]
    size = lambda r: (r[1] - r[0]) * (r[3] - r[2])  # noqa: E731
    for _ in range(cuts):
        target = 2 * len(rects)
        nxt = []
        for rect in rects:
            nxt += list(_split(energy, rect, whole_sources)) if size(rect) > 1 else [rect]
        while len(nxt) < target:
            big = max(range(len(nxt)), key=lambda i: size(nxt[i]))
            if size(nxt[big]) < 2:
                raise InvalidInputError(
                    "the cube face is too small for this many lights: every region is one texel; "
                    "use a larger --face-size or fewer --lights")
            nxt[big:big + 1] = list(_split(energy, nxt[big], whole_sources))
        rects = nxt
    return rects


def median_cut(cube: np.ndarray, n_lights: int, whole_sources: bool = False) -> RegionSet:
    """Partition `cube` (6, F, F, 3) float into `n_lights` = 6 * 2^k regions, one light per region;
    whole_sources: no cut through a compact bright source (the module doc)."""
    per_face = regions_per_face(n_lights)
    cuts = per_face.bit_length() - 1
    n = cube.shape[1]
    if per_face > n * n:
        raise InvalidInputError(f"{n_lights} lights need at least {per_face} texels per face; face size {n} has {n * n}")
    omega = cube_solid_angles(n)
    rgb = np.asarray(cube, np.float64)
    lum = np.maximum(rgb @ LUMINANCE_RGB, 0.0)
    energy = lum * omega

    labels = np.empty((6, n, n), np.int32)
    out_rects = np.empty((n_lights, 5), np.int32)
    for face in range(6):
        for j, (r0, r1, c0, c1) in enumerate(_cut_face(energy[face], cuts, whole_sources)):
            rid = face * per_face + j
            labels[face, r0:r1, c0:c1] = rid
            out_rects[rid] = (face, r0, r1, c0, c1)

    out_dirs, out_omega, out_energy, out_spread, out_mean_cos = _region_stats(rgb, energy, labels, n_lights)
    for arr in (labels, out_dirs, out_omega, out_energy, out_rects, out_spread, out_mean_cos):
        arr.setflags(write=False)
    return RegionSet(labels, out_dirs, out_omega, out_energy, out_rects, out_spread, out_mean_cos)


def median_cut_to(cube: np.ndarray, count: int, whole_sources: bool = False) -> RegionSet:
    """`count` regions (at least 6, any number): the median cut into the largest 6 * 2^k <= count,
    then the most energetic of its regions halved once more (by the same rule) until there are
    `count`. Median cut's own principle, equal energy per light, says where the extra lights go: the
    faces it splits alike carry unequal energy, so their regions do. For count = 6 * 2^k this is
    `median_cut`."""
    if count < 6:
        raise InvalidInputError(f"at least 6 regions (one a cube face), got {count}")
    base_count = 6 * 2 ** ((count // 6).bit_length() - 1)
    base = median_cut(cube, base_count, whole_sources)
    if count == base_count:
        return base
    n = cube.shape[1]
    rgb = np.asarray(cube[..., :3], np.float64)
    energy = np.maximum(rgb @ LUMINANCE_RGB, 0.0) * cube_solid_angles(n)
    labels, rects = base.labels.copy(), [tuple(int(v) for v in r) for r in base.rects]
    splittable = [i for i in np.argsort(-base.energy_rgb @ LUMINANCE_RGB, kind="stable")
                  if (rects[i][2] - rects[i][1]) * (rects[i][4] - rects[i][3]) > 1]
    if len(splittable) < count - base_count:
        raise InvalidInputError(f"{count} regions need more texels than face size {n} has; use a larger face size")
    for rid in splittable[:count - base_count]:
        face = rects[rid][0]
        first, second = _split(energy[face], rects[rid][1:], whole_sources)
        new = len(rects)
        rects[rid] = (face, *first)
        rects.append((face, *second))
        labels[face, second[0]:second[1], second[2]:second[3]] = new
    out = _region_stats(rgb, energy, labels, count)
    out_rects = np.asarray(rects, np.int32)
    for arr in (labels, out_rects, *out):
        arr.setflags(write=False)
    dirs, omega, energy_rgb, spread, mean_cos = out
    return RegionSet(labels, dirs, omega, energy_rgb, out_rects, spread, mean_cos)


@dataclass(frozen=True)
class SubLights:
    """Each region cut into `per_region` sub-regions (the same median cut within its rectangle),
    each a light for the glossy term in closed form only (FrameSettings.sub_lights): region i's are
    i * per_region ... i * per_region + per_region - 1. One disc per region is exact for the
    diffuse term of a region above the horizon, but a glossy lobe about as wide as the region sees
    where in it the light comes from (a blue sky above green grass). Visibility stays the region's
    (one shadow map per region).

    directions: float64 (N * per_region, 3); disc_radius_rad: float64 (N * per_region,), the
    uniform disc with the sub-region's mean cosine; energy_rgb: float64 (N * per_region, 3), zero
    for the padding of a region too small to cut (one texel)."""

    per_region: int
    directions: np.ndarray
    disc_radius_rad: np.ndarray
    energy_rgb: np.ndarray


def sub_lights(cube: np.ndarray, regions: RegionSet, per_region: int, whole_sources: bool = False) -> SubLights:
    """Cut every region of `regions` (the median cut of `cube`, (6, F, F, 3)) into `per_region`
    (a power of two) sub-regions by the same rule (`_split`, whole_sources as the regions were
    cut), each one light (see SubLights)."""
    if per_region < 1 or per_region & (per_region - 1):
        raise InvalidInputError(f"sub-lights per region must be a power of two, got {per_region}")
    n = cube.shape[1]
    rgb = np.asarray(cube[..., :3], np.float64)
    energy = np.maximum(rgb @ LUMINANCE_RGB, 0.0) * cube_solid_angles(n)
    labels = np.empty((6, n, n), np.int32)
    n_sub = regions.n_regions * per_region
    area = regions.area_mask
    cut = energy   # what the remainder's regions are halved by
    if area.any():   # an area light's disc is one sub-light; the remainder's regions are cut without it
        inside = area[regions.labels]
        cut = np.where(inside, 0.0, energy)
        labels[inside] = regions.labels[inside] * per_region
    for rid, (face, r0, r1, c0, c1) in enumerate(regions.rects):
        if area[rid]:
            continue
        rects = [(r0, r1, c0, c1)]
        while len(rects) < per_region:
            rects = [half for rect in rects for half in _halves(cut[face], rect, whole_sources)]
        for j, rect in enumerate(rects):
            if rect is not None:
                block = labels[face, rect[0]:rect[1], rect[2]:rect[3]]
                keep = inside[face, rect[0]:rect[1], rect[2]:rect[3]] if area.any() else False
                labels[face, rect[0]:rect[1], rect[2]:rect[3]] = np.where(keep, block, rid * per_region + j)
    # Each sub-light's direction and disc from its texels' own energy (an area light's too: its
    # disc is where the light is, the sun's half a degree within the few degrees found around it).
    with np.errstate(invalid="ignore", divide="ignore"):   # the padding's empty sums, replaced below
        dirs, omega, energy_rgb, _, mean_cos = _region_stats(rgb, energy, labels, n_sub)
    # Padding (a one-texel region cannot be cut): no texels, no energy, any direction.
    empty = omega == 0.0
    dirs[empty] = regions.directions[np.nonzero(empty)[0] // per_region]
    mean_cos[empty] = 1.0
    energy_rgb[empty] = 0.0
    radius = np.arccos(np.clip(2.0 * mean_cos - 1.0, -1.0, 1.0))
    for arr in (dirs, radius, energy_rgb):
        arr.setflags(write=False)
    return SubLights(per_region, dirs, radius, energy_rgb)


def _halves(energy: np.ndarray, rect, whole_sources: bool):
    """`_split` of a rectangle, or (rect, None) for one that cannot be cut (one texel; None: nothing)."""
    if rect is None or (rect[1] - rect[0]) * (rect[3] - rect[2]) <= 1:
        return rect, None
    return _split(energy, rect, whole_sources)


def _region_stats(rgb: np.ndarray, energy: np.ndarray, labels: np.ndarray, n_regions: int):
    """Per region of `labels` (6, F, F; ids 0..n_regions-1): unit light direction (energy centroid,
    a black region's solid-angle centroid), solid angle, RGB energy, spread and mean cosine (the
    RegionSet fields of the same names); all regions at once (bincount over the labels)."""
    n = labels.shape[1]
    omega = cube_solid_angles(n)
    dirs = texel_directions(n)
    lab = labels.reshape(-1)

    def per_region(values: np.ndarray) -> np.ndarray:
        return np.bincount(lab, weights=values.reshape(-1), minlength=n_regions)

    w = np.broadcast_to(omega, (6, n, n)).reshape(-1)
    e = energy.reshape(-1)
    d = dirs.reshape(-1, 3)
    out_omega = per_region(w)
    # Light at the energy centroid; a black region falls back to its solid-angle centroid.
    black = per_region(e) <= 0.0
    weights = np.where(black[lab], w, e)
    c = np.stack([per_region(weights * d[:, k]) for k in range(3)], axis=1)
    out_dirs = c / np.linalg.norm(c, axis=1, keepdims=True)
    cos_t = np.clip(np.einsum("ij,ij->i", d, out_dirs[lab]), -1.0, 1.0)
    total = per_region(weights)
    out_spread = np.sqrt(2.0 * per_region(weights * np.arccos(cos_t) ** 2) / total)
    out_mean_cos = per_region(weights * cos_t) / total
    rgb_flat = rgb.reshape(-1, 3)
    out_energy = np.stack([per_region(rgb_flat[:, k] * w) for k in range(3)], axis=1)
    return out_dirs, out_omega, out_energy, out_spread, out_mean_cos
