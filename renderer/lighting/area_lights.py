"""Arbree, Walter and Bala's decomposition of an environment map into area lights and an ambient
remainder ("Pre-processing Environment Maps for Dynamic Hardware Shadows", section 3), on the cube
with exact texel solid angles.

A bank of circular centre-surround filters (inner radius 75 % of the outer, weights +1 inside and
-10 in the ring, the response divided by the filter's angular extent, `SIZES` outer radii from 4.5 to
45 degrees) is applied at candidate directions, the brightest `CANDIDATE_SHARE` of the texels. The
strongest response gives a light: its direction is the filter's centre, its angular radius the inner
radius, its energy (rgb) the map's integral over the inner disc, which is then set to black. The
search repeats until a light carries less than `WEBER` (2 %) of all found before it, or no filter
responds positively (a region brighter than its surround by less than the 10:1 weights ask). What
is left is the ambient remainder; lights plus remainder are the map, exactly.

Responses are the seed's sums over texels (L times solid angle), computed at a search face size of
at most `SEARCH_FACE` texels (4.5 degrees is three texels there), from per-candidate histograms of
the texels' angles to it. The lights' energies are integrated, and their discs removed, at the full
face size. After a light is removed only the candidates within reach of its disc are computed again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..envmap.cube import cube_solid_angles, texel_directions
from ..threads import map_threads
from .median_cut import LUMINANCE_RGB

INNER_RATIO = 0.75
RING_WEIGHT = -10.0
SIZES = 20
MIN_OUTER_DEG, MAX_OUTER_DEG = 4.5, 45.0
CANDIDATE_SHARE = 0.10
WEBER = 0.02
SEARCH_FACE = 64
# The first search's work: a face in TILES_PER_EDGE^2 tiles of texels, and candidates in
# GROUPS_PER_EDGE^2 groups a face, each group compared with the tiles within reach of it alone; below
# _TILED_PAIRS candidate-texel pairs (the searches after a light's removal) everything is compared.
TILES_PER_EDGE = 16
GROUPS_PER_EDGE = 16
_TILED_PAIRS = 1 << 22
MAX_LIGHTS = 64


def outer_radii() -> np.ndarray:
    """The bank's outer radii (radians), geometric from MIN_OUTER_DEG to MAX_OUTER_DEG."""
    return np.radians(np.geomspace(MIN_OUTER_DEG, MAX_OUTER_DEG, SIZES))


@dataclass(frozen=True)
class AreaLight:
    """direction: unit (3,) towards the light; radius_rad: its disc's angular radius; energy_rgb:
    the map's integral over the disc (radiance times solid angle); share: of the whole map's luminous
    energy; response: the filter's (for reports)."""

    direction: tuple[float, float, float]
    radius_rad: float
    energy_rgb: tuple[float, float, float]
    share: float
    response: float


@dataclass(frozen=True)
class Decomposition:
    """lights, strongest first; ambient: the remainder (6, F, F, 3) float32; owner: int32 (6, F, F),
    the light whose disc took each texel (-1: the remainder); ambient_share: its share of the map's
    luminous energy; stopped_by: why the search ended ("weber", "no response", "max lights",
    "no candidates")."""

    lights: tuple[AreaLight, ...]
    ambient: np.ndarray
    owner: np.ndarray
    ambient_share: float
    total_luminance: float
    stopped_by: str


def _downsample(cube: np.ndarray, face: int) -> np.ndarray:
    n = cube.shape[1]
    while n > face and n % 2 == 0:
        w = cube_solid_angles(n)[..., None]
        num = (cube * w).reshape(6, n // 2, 2, n // 2, 2, -1).sum(axis=(2, 4))
        den = w.reshape(6, n // 2, 2, n // 2, 2, 1).sum(axis=(2, 4))
        cube, n = num / den, n // 2
    return cube


class _EdgeTable:
    """How many of the descending edges (float64) lie above each float32 cosine, as
    np.searchsorted(-edges, -cos, side="left") counts them, by a table instead of a search: cosines
    in cells of 1 / `cells` (1 - cos is exact in float32 for cos >= 0.5, and so is its cell), each
    cell holding at most one edge, which is compared exactly."""

    def __init__(self, edges: np.ndarray):
        cells = 1 << 12
        while np.min(-np.diff(edges)) <= 2.0 / cells:
            cells <<= 1
        self.cells = np.float32(cells)
        bottom = min(float(edges[-1]), 0.5)
        q = np.arange(int(np.ceil((1.0 - bottom) * cells)) + 1)
        top = 1.0 - q / cells                                      # a cell's cosines: (top - 1/cells, top]
        self.above = np.searchsorted(-edges, -top, side="left")    # edges above the whole cell
        first = edges[np.minimum(self.above, len(edges) - 1)]       # the first at or below its top
        within = (self.above < len(edges)) & (first > top - 1.0 / cells)
        self.edge = np.where(within, first, -np.inf)                # the cell's edge, compared exactly

    def __call__(self, cos: np.ndarray) -> np.ndarray:
        """cos: float32, each above min(edges[-1], 0.5)."""
        q = ((np.float32(1.0) - cos) * self.cells).astype(np.intp)
        np.maximum(q, 0, out=q)
        return self.above[q] + (cos < self.edge[q])


def _tile_of(n: int, size: int) -> np.ndarray:
    """Each texel's square tile of `size` texels a side on a cube of face n: int (6 n^2,)."""
    face, row, col = np.unravel_index(np.arange(6 * n * n), (6, n, n))
    per_edge = -(-n // size)
    return (face * per_edge + row // size) * per_edge + col // size


def _tiles(dirs: np.ndarray, n: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The search cube's texels in tiles (`_tile_of`): each texel's tile (N,), each tile's centre
    direction (T, 3) and its angular radius about it (T,), radians."""
    tile = _tile_of(n, size)
    centre = np.zeros((tile.max() + 1, 3))
    np.add.at(centre, tile, dirs)
    centre /= np.linalg.norm(centre, axis=1, keepdims=True)
    radius = np.zeros(len(centre))
    np.maximum.at(radius, tile, np.arccos(np.clip(np.einsum("ij,ij->i", dirs, centre[tile]), -1.0, 1.0)))
    return tile, centre, radius


class _Search:
    """The filter responses at the candidates, on the search cube: each candidate's integrals within
    every inner and outer radius, kept, so that a removed disc is subtracted from them (its texels'
    share alone) instead of every candidate being searched again."""

    def __init__(self, luminance: np.ndarray):
        n = luminance.shape[1]
        self.dirs = texel_directions(n).reshape(-1, 3)
        self._dirs32 = self.dirs.astype(np.float32)
        self.omega = np.ascontiguousarray(cube_solid_angles(n)).reshape(-1)
        self.y = luminance.reshape(-1).astype(np.float64).copy()
        self.outer = outer_radii()
        # Bin edges in cos of the angle, descending: each filter's inner and outer radius.
        radii = np.concatenate([INNER_RATIO * self.outer, self.outer])
        order = np.argsort(radii)
        self.cos_edges = np.cos(radii[order])                     # descending cosines
        position = np.empty_like(order)
        position[order] = np.arange(len(order))                 # each radius's place among the edges
        self.inner_bin, self.outer_bin = position[:SIZES], position[SIZES:]
        bright = self.y > 0
        k = max(1, int(np.ceil(CANDIDATE_SHARE * len(self.y))))
        top = np.argsort(-self.y)[:k]
        self.candidates = top[bright[top]]
        self._bins = _EdgeTable(self.cos_edges)
        self._tiles = _tiles(self.dirs, n, max(1, n // TILES_PER_EDGE))
        self._group = _tile_of(n, max(1, n // GROUPS_PER_EDGE))
        rows = np.arange(len(self.candidates))
        self.inner, self.outer_sum = self._integrals(rows, np.arange(len(self.y)))
        self.responses = np.full((len(self.candidates), SIZES), -np.inf)
        self._respond(rows)

    def _integrals(self, rows: np.ndarray, texels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integrals (L times solid angle) of `texels` within each inner and outer radius about
        each candidate of `rows`: (R, SIZES) each.

        Candidates are taken in groups close on the sphere (a block of a face), each group against the
        texels of the tiles within reach of it alone (the widest filter plus both bounds' angular
        radii): some 15 % of the sphere lies within reach of a candidate, so most of the sphere is
        never compared. Texels keep their order, so each sum adds the same terms in the same order as
        comparing all of them does (a smaller product's cosines may differ in the last bit, which
        moves a texel lying exactly on an edge to the next bin: the lights found on every shared map
        are the same)."""
        cos_max = float(np.cos(self.outer[-1]))
        weighted = self.y * self.omega
        width = 2 * SIZES + 1
        inner = np.zeros((len(rows), SIZES))
        outer = np.zeros((len(rows), SIZES))
        tiled = len(rows) * len(texels) >= _TILED_PAIRS
        if tiled:
            tiles, tile_dirs, tile_radius = self._tiles
            tile_of = tiles[texels]
            group_of = self._group[self.candidates[rows]]
            order = np.argsort(group_of, kind="stable")
            starts = np.flatnonzero(np.diff(group_of[order], prepend=-1))
            groups = np.split(order, starts[1:])
        else:
            groups = [np.arange(len(rows))]
        work = [(g, k) for g in groups for k in range(0, len(g), 256)]

        def chunk_of(job) -> None:
            group, k = job
            at = group[k:k + 256]
            who = self.candidates[rows[at]]
            if tiled:
                # The group's bounding cone: its centre and the widest angle from it to a candidate.
                cand = self.dirs[who]
                centre = cand.sum(axis=0)
                centre /= np.linalg.norm(centre)
                spread = float(np.arccos(np.clip((cand @ centre).min(), -1.0, 1.0)))
                reach = np.cos(np.minimum(np.pi, self.outer[-1] + spread + tile_radius + 1e-6))
                near = (tile_dirs @ centre) >= reach
                sub = texels[near[tile_of]]
            else:
                sub = texels
            c = self._dirs32[who] @ self._dirs32[sub].T   # (R, T) cosines
            pair = np.flatnonzero(c > cos_max)
            cos = c.ravel()[pair]
            r, t = np.divmod(pair, len(sub))
            # Bin b: the texel lies within edge b (angle below radius b) but outside edge b - 1, i.e.
            # b edges are above its cosine (np.searchsorted(-cos_edges, -cos), by table: `_EdgeTable`).
            b = self._bins(cos)
            sums = np.bincount(r * width + b, weights=weighted[sub][t], minlength=len(at) * width).reshape(-1, width)
            cum = np.cumsum(sums, axis=1)                                        # within edge b: cum[:, b]
            inner[at] = cum[:, self.inner_bin]
            outer[at] = cum[:, self.outer_bin]

        map_threads(chunk_of, work)   # the chunks on every core
        return inner, outer

    def _respond(self, rows: np.ndarray) -> None:
        inner, outer = self.inner[rows], self.outer_sum[rows]
        self.responses[rows] = (inner + RING_WEIGHT * (outer - inner)) / self.outer
        self.responses[rows[self.y[self.candidates[rows]] <= 0]] = -np.inf

    def best(self) -> tuple[int, int, float]:
        flat = int(np.argmax(self.responses))
        i, s = divmod(flat, SIZES)
        return i, s, float(self.responses[i, s])

    def remove(self, direction: np.ndarray, radius: float) -> None:
        """Black out the disc: its texels' share leaves the integrals of the candidates it reaches."""
        inside = np.flatnonzero((self.dirs @ direction >= np.cos(radius)) & (self.y > 0))
        reach = np.flatnonzero(self.dirs[self.candidates] @ direction >= np.cos(min(np.pi, radius + self.outer[-1])))
        if len(inside) and len(reach):
            inner, outer = self._integrals(reach, inside)
            self.inner[reach] -= inner
            self.outer_sum[reach] -= outer
        self.y[inside] = 0.0
        self._respond(reach)


def decompose(cube: np.ndarray, weber: float = WEBER, max_lights: int = MAX_LIGHTS) -> Decomposition:
    """The area lights and ambient remainder of a cube map (6, F, F, 3) linear RGB; at most
    `max_lights` lights (the strongest first)."""
    cube = np.asarray(cube, np.float64)[..., :3]
    n = cube.shape[1]
    omega = np.ascontiguousarray(cube_solid_angles(n))[..., None]
    dirs = texel_directions(n)
    ambient = cube.copy()
    owner = np.full(cube.shape[:3], -1, np.int32)
    total = float(np.sum((cube * omega) @ LUMINANCE_RGB))
    search = _Search(_downsample(cube, SEARCH_FACE) @ LUMINANCE_RGB)
    lights: list[AreaLight] = []
    found = 0.0
    stopped = "max lights"
    for _ in range(max_lights):
        if not len(search.candidates):
            stopped = "no candidates"
            break
        i, s, response = search.best()
        if not response > 0.0:
            stopped = "no response"
            break
        centre = search.dirs[search.candidates[i]]
        radius = float(INNER_RATIO * search.outer[s])
        inside = dirs @ centre >= np.cos(radius)
        energy = (ambient[inside] * omega[inside]).sum(axis=0)
        lum = float(energy @ LUMINANCE_RGB)
        if lights and lum < weber * found:
            stopped = "weber"
            break
        ambient[inside] = 0.0
        owner[inside & (owner < 0)] = len(lights)
        search.remove(centre, radius)
        found += lum
        lights.append(AreaLight(tuple(float(c) for c in centre), radius, tuple(float(e) for e in energy),
                                lum / total if total > 0 else 0.0, response))
    ambient_lum = float(np.sum((ambient * omega) @ LUMINANCE_RGB))
    return Decomposition(tuple(lights), ambient.astype(np.float32), owner, ambient_lum / total if total > 0 else 0.0,
                         total, stopped)


def light_regions(cube: np.ndarray, n_lights: int, whole_sources: bool, lights_from: str):
    """A PEM set's regions by `PEMSettings.lights_from`: "median-cut", "area" or "auto"."""
    from .median_cut import median_cut_to

    if lights_from == "area":
        return area_regions(cube, n_lights, whole_sources)[0]
    if lights_from == "auto":
        return auto_regions(cube, n_lights, whole_sources)[0]
    return median_cut_to(cube, n_lights, whole_sources)


# `lights_from` "auto": the area decomposition where it found lights and none is wider than this
# (angular radius), else the median cut. Chosen on the tuning maps of `garment-render bench --area`
# at equal frame time: area won on the three whose widest light was 3.4-8.9 degrees and lost on the two
# whose widest was 23.5 and 30 degrees (one disc standing for a window or a sky is too coarse a light);
# the share of energy the lights hold did not separate them (docs/area-lights.md). Since wide lights
# are cut in pieces area wins on those two as well, but loses on the bundled studio dress (its
# softboxes wider than this), so the rule stays. It is also the widest piece an area light is
# shadowed as (`_light_pieces`): a wider one is cut.
MAX_PIECE_RADIUS_DEG = 15.0


def auto_regions(cube: np.ndarray, n_lights: int, whole_sources: bool = False):
    """(RegionSet, Decomposition, what was used): `area_regions` where the decomposition found lights
    and none is wider than MAX_PIECE_RADIUS_DEG, else the median cut."""
    from .median_cut import median_cut_to

    dec = decompose(cube, max_lights=max(0, n_lights - 6))
    if dec.lights and max(lt.radius_rad for lt in dec.lights) <= np.radians(MAX_PIECE_RADIUS_DEG):
        return area_regions(cube, n_lights, whole_sources, dec)[0], dec, "area"
    return median_cut_to(cube[..., :3], n_lights, whole_sources), dec, "median-cut"


def _light_pieces(dec: Decomposition, energy: np.ndarray, n_lights: int) -> np.ndarray:
    """Each texel's piece of an area light (int32 (6, F, F); -1: the remainder), at most n_lights - 6
    pieces in all (room for the remainder's six). A light wider than MAX_PIECE_RADIUS_DEG is cut, so
    that a window or a bright sky is seen past a fold from several directions (each piece a region
    with its own shadow map), the way the median cut sees it: into as many pieces as the median cut
    would give its energy (its share of the n_lights), at least ceil((radius / that)^2) so that none is
    wider, and none narrower than the filter bank's smallest disc."""
    n = dec.owner.shape[1]
    d = texel_directions(n).reshape(-1, 3)
    owner, e = dec.owner.reshape(-1), energy.reshape(-1)
    limit, finest = np.radians(MAX_PIECE_RADIUS_DEG), np.radians(MIN_OUTER_DEG * INNER_RATIO)
    wanted = [1 if lt.radius_rad <= limit else
              max(int(np.ceil((lt.radius_rad / limit) ** 2)),
                  min(int(round(lt.share * n_lights)), int((lt.radius_rad / finest) ** 2)))
              for lt in dec.lights]
    max_pieces = n_lights - 6
    while sum(wanted) > max_pieces and max(wanted) > 1:   # the budget first: the most cut gives up pieces
        wanted[int(np.argmax(wanted))] -= 1
    out = np.full(owner.shape, -1, np.int32)
    next_id = 0
    for i, (light, count) in enumerate(zip(dec.lights, wanted)):
        parts = [np.flatnonzero(owner == i)]
        t, b = disc_tangents(np.asarray(light.direction))
        while len(parts) < count:   # halve the widest part where its energy is halved
            widths = [np.ptp(d[p] @ t) + np.ptp(d[p] @ b) if len(p) > 1 else -1.0 for p in parts]
            j = int(np.argmax(widths))
            if widths[j] < 0:
                break
            p = parts.pop(j)
            axis = t if np.ptp(d[p] @ t) >= np.ptp(d[p] @ b) else b
            x = d[p] @ axis
            order = np.argsort(x, kind="stable")
            cum = np.cumsum(e[p][order])
            cut = int(np.clip(np.searchsorted(cum, 0.5 * cum[-1]) + 1, 1, len(p) - 1)) if cum[-1] > 0 else len(p) // 2
            parts += [p[order[:cut]], p[order[cut:]]]
        for part in parts:
            if len(part):
                out[part] = next_id
                next_id += 1
    return out.reshape(dec.owner.shape)


def disc_tangents(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 1.0, 0.0]) if abs(c[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t = np.cross(c, helper)
    t /= np.linalg.norm(t)
    return t, np.cross(c, t)


def area_regions(cube: np.ndarray, n_lights: int, whole_sources: bool = False, dec: Decomposition | None = None):
    """The PEM set's regions from the decomposition (`PEMSettings.lights_from` "area"): one region
    per area light (its disc's texels; a light wider than MAX_PIECE_RADIUS_DEG in pieces, a region
    each, `_light_pieces`), and the ambient remainder median-cut into the n_lights - k
    regions the k area lights leave (`median_cut_to`; at least 6), each a light with its own PEM
    and shadow map like any other. Returns (RegionSet, Decomposition); a map without area lights
    gets the median cut (median_cut_to). `dec`: the decomposition, if made already (at most n_lights - 6 lights,
    room for the remainder's six)."""
    from .median_cut import RegionSet, _region_stats, median_cut_to

    if dec is None:
        dec = decompose(cube, max_lights=max(0, n_lights - 6))
    if not dec.lights:
        return median_cut_to(cube[..., :3], n_lights, whole_sources), dec
    n = cube.shape[1]
    rgb = np.asarray(cube[..., :3], np.float64)
    energy = np.maximum(rgb @ LUMINANCE_RGB, 0.0) * cube_solid_angles(n)
    pieces = _light_pieces(dec, energy, n_lights)
    k = int(pieces.max()) + 1
    m = max(6, n_lights - k)   # the whole budget: the remainder gets every light the area lights leave
    rest = median_cut_to(dec.ambient.astype(np.float64), m, whole_sources)
    labels = np.where(pieces >= 0, m + pieces, rest.labels).astype(np.int32)
    rects = [tuple(r) for r in rest.rects]
    for i in range(k):   # a piece's rect: its first texel (read by nothing but the stored format)
        f, r, c = (int(x[0]) for x in np.nonzero(pieces == i)) if (pieces == i).any() else (0, 0, 0)
        rects.append((f, r, r + 1, c, c + 1))
    dirs, omega, energy_rgb, spread, mean_cos = _region_stats(rgb, energy, labels, m + k)
    regions = RegionSet(labels, dirs, omega, energy_rgb, np.asarray(rects, np.int32), spread, mean_cos,
                        np.concatenate([np.zeros(m, bool), np.ones(k, bool)]))
    for a in vars(regions).values():
        a.setflags(write=False)
    return regions, dec


def report(dec: Decomposition, wall_ms: float) -> dict:
    return {"lights": [{"direction": [round(c, 5) for c in lt.direction],
                        "angular_radius_deg": round(float(np.degrees(lt.radius_rad)), 3),
                        "energy_share": round(lt.share, 5)} for lt in dec.lights],
            "ambient_share": round(dec.ambient_share, 5), "stopped_by": dec.stopped_by, "wall_ms": round(wall_ms, 1)}
