"""The PEM set: one partial environment map per median-cut region, each with its MIP chain, built on
the GPU with compute shaders (Knuth et al. 2014, sections 3.1, 3.2 and 4).

Storage is one GL_TEXTURE_CUBE_MAP_ARRAY in RGBA16F (the paper's format, Fig. 8), layer i = region
i. Each region is stored divided by its own scale (its brightest channel value at level 0), so every
stored texel is <= 1 and a sun of 1e6 never overflows half floats (65504); the shading pass multiplies
the scale back in float32. The chain is solid-angle weighted (pem_reference's module doc): the stored
levels are A = chain(L * w), and a one-layer float32 texture holds B = chain(w), the same for every
region, by which the shading pass divides once per lookup direction. The build works on batches of regions so that its float32 scratch
buffers stay bounded whatever the region count.
"""

from __future__ import annotations

import copy
import time
from dataclasses import replace
from functools import cache

import numpy as np

from ..envmap.cube import face_uv_to_dir
from ..errors import InvalidInputError
from ..gpu.context import GLContext, StageTimer
from ..gpu.contract import Image, PEMBuffer
from ..gpu.rawgl import GL_RGBA16F, GL_RGBA32F, CubeMapArray
from ..gpu.shaders import compute_shader
from ..shadows.lights import disc_sine
from .area_lights import light_regions
from .filters import taps_1d
from .glossiness import Calibration, LobeTable, lobe_table
from .median_cut import RegionSet, sub_lights
from .pem_plan import (
    GLOSS_TABLE_SIZE,
    MAX_TEXTURES,
    PAPER_PEMS,
    REGIONS_PER_TEXTURE,
    PEMSettings,
    scratch_batch,
)
from .pem_reference import mip_levels, texel_weights, weight_chain

# The build's workgroups: 8 x 8 texels of one face of one region (shaders/pem/*.comp).
TILE = 8
# The largest face whose workgroups are judged (`_live_tiles`): the reach of a level's tiles is a
# dense (6 t^2)^2 table, t = 8 tiles a face at a 128^2 level (256^2 faces: 2.4 M entries). Larger faces
# build every workgroup, as before the judgement (a 1024^2 face's table would take GiBs).
MAX_JUDGED_FACE = 256


@cache
def _tile_reach(m: int) -> np.ndarray:
    """bool (6 t^2, 6 t^2) for the t x t tiles of each face of a level of m^2 texels: True where a texel
    of the first tile may read a texel of the second through the 5 x 5 filter, across face edges too.

    Each tile is bounded by a cone about the direction of its centre (the angle to its farthest texel
    centre: on a face's plane that is a corner). A tap is at most two texels away in each axis on the
    face's plane, extended past its edge (2 sqrt(2) x 2/m in plane units, and an angle is at most the
    planar distance since the plane is at distance 1), and the texel that resolve_texel reads contains
    the tap's direction (sqrt(2)/m from its centre): 7.1/m in all, taken 1.25 times for the float
    arithmetic of either side. Conservative: a tile judged out of reach reads zeros only."""
    t = max(1, -(-m // TILE))
    first = np.arange(t) * TILE
    last = np.minimum(first + TILE, m) - 1
    def uv(i):   # texel index -> face coordinate of its centre
        return (np.asarray(i, np.float64) + 0.5) * (2.0 / m) - 1.0
    ty, tx = np.meshgrid(np.arange(t), np.arange(t), indexing="ij")
    centres, radii = [], []
    for face in range(6):
        c = face_uv_to_dir(face, uv((first[tx] + last[tx]) / 2), uv((first[ty] + last[ty]) / 2))
        c /= np.linalg.norm(c, axis=-1, keepdims=True)
        r = np.zeros((t, t))
        for rows in (first, last):
            for cols in (first, last):
                d = face_uv_to_dir(face, uv(cols[tx]), uv(rows[ty]))
                d /= np.linalg.norm(d, axis=-1, keepdims=True)
                r = np.maximum(r, np.arccos(np.clip(np.sum(c * d, axis=-1), -1.0, 1.0)))
        centres.append(c.reshape(-1, 3))
        radii.append(r.reshape(-1))
    c, r = np.concatenate(centres), np.concatenate(radii)
    angle = np.arccos(np.clip(c @ c.T, -1.0, 1.0))
    return angle <= r[:, None] + r[None, :] + 1.25 * 5.0 * np.sqrt(2.0) / m


def _live_tiles(labels: np.ndarray, n_regions: int, levels: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per level 1.. of the build: (reduced, filtered), bool (regions, 6, t, t) each, the workgroups of
    the 2 x 2 reduction and of the filter that may see a texel of their region; every other one reads
    zeros only and writes zeros (the shaders skip its arithmetic, same result bit for bit). A region is
    one rectangle of one face (the median cut's) or a disc, so at the finer levels most of a region's
    tiles are empty. Faces larger than MAX_JUDGED_FACE: {} (every workgroup live)."""
    n = labels.shape[1]
    if n > MAX_JUDGED_FACE:
        return {}
    t0 = max(1, -(-n // TILE))
    rows = np.arange(n) // TILE
    tile_of = (np.arange(6)[:, None, None] * t0 + rows[None, :, None]) * t0 + rows[None, None, :]
    support = np.zeros((n_regions, 6 * t0 * t0), bool)        # level 0: the region's own texels
    support[labels.reshape(-1), tile_of.reshape(-1)] = True
    support = support.reshape(n_regions, 6, t0, t0)
    out = {}
    for level in range(1, levels):
        m = max(1, n >> level)
        t = max(1, -(-m // TILE))
        if support.shape[2] == 2 * t:                            # a tile reduces 2 x 2 tiles above it
            reduced = support.reshape(n_regions, 6, t, 2, t, 2).any(axis=(3, 5))
        else:
            reduced = support
        filtered = (reduced.reshape(n_regions, -1).astype(np.float32) @ _tile_reach(m).astype(np.float32)) > 0
        support = filtered.reshape(n_regions, 6, t, t)
        out[level] = (reduced, support)
    return out


class PEMSet:
    """The GPU-resident PEMs of one environment map. Owns its texture; `release()` frees it."""

    def __init__(self, gl: GLContext, cube: np.ndarray, settings: PEMSettings = PAPER_PEMS,
                 timer: StageTimer | None = None, stored: dict | None = None):
        """Build the PEMs of `cube` (6, F, F, 3) on the GPU, or upload a set saved by `export()`
        (`stored`, e.g. from a disk cache) for the same cube and settings without rebuilding."""
        gl.check_thread()
        cube = np.asarray(cube, np.float32)
        if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[1] != cube.shape[2] or cube.shape[3] < 3:
            raise InvalidInputError(f"cube map must have shape (6, F, F, 3), got {cube.shape}")
        n = cube.shape[1]
        if n < 4 or n & (n - 1):
            raise InvalidInputError(f"PEM face size must be a power of two >= 4, got {n}")
        if not np.all(np.isfinite(cube)) or np.any(cube < 0):
            raise InvalidInputError("cube map has NaN, Inf or negative texels; load it with repair=True")
        self.gl = gl
        self.settings = settings
        self.source = "built"   # or "disk": read from a cache folder (Renderer.pem_set)
        self._gloss_tables: dict[Calibration, np.ndarray] = {}
        self.face_size = n
        full = mip_levels(n)
        self.levels = full if settings.levels is None else int(np.clip(settings.levels, 1, full))
        base = settings.base_level
        if isinstance(base, bool) or not isinstance(base, (int, np.integer)) or not 0 <= base < self.levels:
            raise InvalidInputError(f"base level must be an integer in [0, {self.levels - 1}], got {base!r}")
        self.base_level = int(base)
        self.stored_size = n >> self.base_level

        t0 = time.perf_counter()
        if stored is None:
            self.regions: RegionSet = light_regions(cube[..., :3], settings.lights, settings.whole_sources,
                                                    settings.lights_from)
            # Per-region scale: the brightest channel of the region's texels (1 for a black region).
            brightest = cube[..., :3].max(axis=-1).astype(np.float64)
            peak = np.zeros(self.regions.n_regions)
            np.maximum.at(peak, self.regions.labels.reshape(-1), brightest.reshape(-1))
            self.scale = np.where(peak > 0, peak, 1.0).astype(np.float64)
        else:
            self.regions = RegionSet(**{k: np.asarray(stored["regions_" + k]) for k in RegionSet.__dataclass_fields__
                                        if "regions_" + k in stored})
            self.scale = np.asarray(stored["scale"], np.float64)
            # An area set has its decomposition's count of lights (at most `lights`), not `lights`.
            area = bool(self.regions.area_mask.any())
            lights = settings.lights if not area else min(settings.lights, self.regions.n_regions)
            have = (self.regions.n_regions, int(stored["levels"]), int(stored.get("base_level", 0)),
                    bool(stored.get("whole_sources", False)), str(stored.get("lights_from", "median-cut")))
            want = (lights, self.levels, self.base_level, settings.whole_sources, settings.lights_from)
            if have != want:
                raise InvalidInputError(f"stored PEM set has (lights, levels, base level, whole sources) {have}, the "
                                        f"request {want}: "
                                        "build it anew (omit `stored`) or pass the settings it was built with")
        # The lights' regions, however made: for "area" and "auto" the decomposition is in it too.
        self.median_cut_ms = (time.perf_counter() - t0) * 1e3
        self._cube = cube  # float32, kept for the SH9 coefficients, computed on first use
        self._sub_lights: dict[int, bytes] = {}
        # The map's frame in the world's: a set turned about the up axis (`turned`) reads its textures
        # through the inverse turn (lighting.frag, background.frag: u_env_from_world).
        self.rotation_deg = 0.0
        self.env_from_world = np.eye(3)
        self._turned: dict[float, PEMSet] = {}
        n_regions = self.regions.n_regions

        if n_regions > REGIONS_PER_TEXTURE * MAX_TEXTURES:
            raise InvalidInputError(f"at most {REGIONS_PER_TEXTURE * MAX_TEXTURES} lights are supported, got {n_regions}")
        stored_levels = self.levels - self.base_level
        self.textures = [CubeMapArray(gl.gl, self.stored_size, min(REGIONS_PER_TEXTURE, n_regions - first),
                                      stored_levels, GL_RGBA16F)
                         for first in range(0, n_regions, REGIONS_PER_TEXTURE)]
        self.norm_texture = CubeMapArray(gl.gl, self.stored_size, 1, stored_levels, GL_RGBA32F)
        t0 = time.perf_counter()
        try:
            with gl.stage(timer, "pem_build" if stored is None else "pem_upload"):
                self._norm = weight_chain(n, settings.filter, self.levels)
                for level in range(self.base_level, self.levels):
                    self.norm_texture.write_level(level - self.base_level, np.repeat(self._norm[level][None], 4, axis=-1))
                if stored is None:
                    self._build(cube)
                else:
                    self._upload(stored)
        except Exception:
            for t in self.textures + [self.norm_texture]:
                t.release()
            raise
        self.build_ms = (time.perf_counter() - t0) * 1e3
        self.lobes: LobeTable = lobe_table(n, settings.filter)
        # The map itself, for the background seen behind the scene (level 0 only).
        self.env_texture = gl.ctx.texture_cube((n, n), 3, dtype="f4")
        for face in range(6):
            self.env_texture.write(face, np.ascontiguousarray(cube[face, ..., :3]).tobytes())

    GLOSS_TABLE_SIZE = GLOSS_TABLE_SIZE

    def gloss_table(self, calibration: Calibration | str = Calibration.L2) -> np.ndarray:
        """Texture lookup level for g = k / 256, k = 0..256 (the chain level, clamped to the levels built,
        counted from the base level): float32 (257,). Computed once per set and calibration."""
        calibration = Calibration.parse(calibration)
        if calibration not in self._gloss_tables:
            g = np.linspace(0.0, 1.0, self.GLOSS_TABLE_SIZE)
            self._gloss_tables[calibration] = np.array(
                [self.lookup_level(self.level_for_glossiness(x, calibration)) for x in g], np.float32)
        return self._gloss_tables[calibration]

    # -- build ------------------------------------------------------------------------------
    def _build(self, cube: np.ndarray) -> None:
        ctx = self.gl.ctx
        n, n_regions = self.face_size, self.regions.n_regions
        env4 = np.zeros((6, n, n, 4), np.float32)
        env4[..., :3] = cube[..., :3] * texel_weights(n)  # A = chain(L * w), see the module doc
        buffers = [ctx.buffer(env4.tobytes()),
                   ctx.buffer(np.ascontiguousarray(self.regions.labels, np.int32).tobytes()),
                   ctx.buffer((1.0 / self.scale).astype(np.float32).tobytes())]
        batch, per_region_bytes = scratch_batch(n)
        buffers.append(ctx.buffer(reserve=batch * per_region_bytes))  # the filtered level
        buffers.append(ctx.buffer(reserve=batch * per_region_bytes))  # the reduced level
        live = _live_tiles(self.regions.labels, n_regions, self.levels)
        progs = {}
        try:
            units = (PEMBuffer.ENV, PEMBuffer.LABELS, PEMBuffer.INV_SCALE, PEMBuffer.FILTERED, PEMBuffer.REDUCED)
            for unit, b in zip(units, buffers, strict=True):
                b.bind_to_storage_buffer(unit)
            for name, file, defines in (("level0", "pem/level0.comp", None),
                                        ("down_env", "pem/downsample.comp", {"FROM_ENV": 1}),
                                        ("down", "pem/downsample.comp", None), ("filter", "pem/filter.comp", None)):
                progs[name] = self.gl.cached(("pem", name), lambda f=file, d=defines: compute_shader(ctx, f, d))
            progs["filter"]["u_taps"].value = tuple(float(t) for t in taps_1d(self.settings.filter))

            for first in range(0, n_regions, batch):
                count = min(batch, n_regions - first)
                groups = lambda size, count=count: ((size + 7) // 8, (size + 7) // 8, 6 * count)  # noqa: E731
                texture = self.textures[first // REGIONS_PER_TEXTURE]
                texture_first = first - first % REGIONS_PER_TEXTURE
                for name in ("level0", "filter"):
                    progs[name]["u_texture_first_region"].value = texture_first
                # This batch's live workgroups, every judged level's reduction and filter in one buffer
                # (a level not judged: first entry -1, every workgroup live).
                flags, offsets, at = [], {}, 0
                for level in range(1, self.levels):
                    for k in (0, 1):
                        offsets[level, k] = at if level in live else -1
                        if level in live:
                            flags.append(live[level][k][first:first + count].reshape(-1))
                            at += flags[-1].size
                tiles = ctx.buffer(np.concatenate(flags or [np.zeros(1, bool)]).astype(np.int32).tobytes())
                buffers.append(tiles)
                tiles.bind_to_storage_buffer(PEMBuffer.TILES)
                texture.bind_image(Image.PEM_OUT, 0)
                if self.base_level == 0:
                    p = progs["level0"]
                    p["u_n"].value, p["u_first_region"].value = n, first
                    p.run(*groups(n))
                for level in range(1, self.levels):
                    size = n >> level
                    p = progs["down_env"] if level == 1 else progs["down"]
                    p["u_n"].value = size
                    p["u_tiles_first"].value = offsets[level, 0]
                    if "u_first_region" in p:
                        p["u_first_region"].value = first
                    ctx.memory_barrier()
                    p.run(*groups(size))
                    ctx.memory_barrier()
                    # Levels above the base are computed (the next reduction reads them) but not stored.
                    store = level >= self.base_level
                    texture.bind_image(Image.PEM_OUT, level - self.base_level if store else 0)
                    p = progs["filter"]
                    p["u_n"].value, p["u_first_region"].value = size, first
                    p["u_tiles_first"].value = offsets[level, 1]
                    p["u_store"].value = store
                    p.run(*groups(size))
            ctx.memory_barrier()
        finally:
            for b in buffers:   # the programs stay with the context (GLContext.cached)
                b.release()

    def _upload(self, stored: dict) -> None:
        for level in range(self.base_level, self.levels):
            data = np.asarray(stored[f"level_{level}"])
            for k, texture in enumerate(self.textures):
                first = k * REGIONS_PER_TEXTURE
                texture.write_level(level - self.base_level, data[first:first + texture.layers])

    def export(self) -> dict[str, np.ndarray]:
        """Everything needed to restore this set without rebuilding (the stored half floats, the
        scales, the partition): arrays for np.savez. Restore with PEMSet(gl, cube, settings, stored=...)."""
        # Each texture's level read and halved on its own: the float32 of the whole level never exists.
        out = {f"level_{level}": np.concatenate([t.read_level(level - self.base_level).astype(np.float16)
                                                 for t in self.textures])
               for level in range(self.base_level, self.levels)}
        out.update({"regions_" + k: getattr(self.regions, k) for k in RegionSet.__dataclass_fields__
                    if getattr(self.regions, k) is not None})
        out["lights_from"] = np.str_(self.settings.lights_from)
        out["scale"] = self.scale
        out["levels"] = np.int64(self.levels)
        out["base_level"] = np.int64(self.base_level)
        out["whole_sources"] = np.bool_(self.settings.whole_sources)
        return out

    # -- queries ----------------------------------------------------------------------------
    def prepare_tables(self, sub_lights: int = 1) -> bool:
        """Make the per-set tables a frame will read (`sub_lights_bytes(sub_lights)` when it is > 1)
        if they are not made yet; True when something was made, so that a renderer can time it as its
        own stage rather than inside the shading pass."""
        if sub_lights > 1 and sub_lights not in self._sub_lights:
            self.sub_lights_bytes(sub_lights)
            return True
        return False

    def sub_lights_bytes(self, per_region: int) -> bytes:
        """Every region cut into `per_region` discs for the closed-form terms (median_cut.SubLights)
        as the shading pass reads them: per disc (unit direction, sine of its radius; rgb energy, 0),
        float32; computed once per count."""
        if per_region not in self._sub_lights and self.rotation_deg != 0.0:
            out = np.frombuffer(self._base.sub_lights_bytes(per_region), np.float32).reshape(-1, 2, 4).copy()
            out[:, 0, :3] = out[:, 0, :3] @ self.env_from_world.astype(np.float32)   # world = env_from_world^T env
            self._sub_lights[per_region] = out.tobytes()
        if per_region not in self._sub_lights:
            sub = sub_lights(self._cube[..., :3], self.regions, per_region, self.settings.whole_sources)
            out = np.zeros((len(sub.energy_rgb), 2, 4), np.float32)
            out[:, 0, :3] = sub.directions
            out[:, 0, 3] = disc_sine(sub.disc_radius_rad)
            out[:, 1, :3] = sub.energy_rgb
            self._sub_lights[per_region] = out.tobytes()
        return self._sub_lights[per_region]

    def turned(self, degrees: float) -> PEMSet:
        """This set with its map turned `degrees` about the up axis (+Y; counter-clockwise seen from
        above: light from direction d comes from R d): its lights' directions and sub-lights turned,
        the same textures read through the inverse turn. Nothing is built again; one view per angle is
        kept (a frame's light plan is kept while its set is the same object). Not to be released: the
        set it views owns the textures."""
        degrees = float(degrees) % 360.0
        if degrees == self.rotation_deg:
            return self
        base = self if self.rotation_deg == 0.0 else self._base
        if degrees == 0.0:
            return base
        if degrees not in base._turned:
            a = np.radians(degrees)
            turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
            view = copy.copy(base)
            view._base, view.rotation_deg, view.env_from_world = base, degrees, turn.T
            view.regions = replace(base.regions, directions=base.regions.directions @ turn.T)
            view._sub_lights = {}
            view._turned = {}
            base._turned[degrees] = view
        return base._turned[degrees]

    @property
    def n_regions(self) -> int:
        return self.regions.n_regions

    @property
    def nbytes(self) -> int:
        # The PEMs and their normalizer B; the float32 background cube is extra.
        return sum(t.nbytes for t in self.textures) + self.norm_texture.nbytes

    def diffuse_level(self, calibration: Calibration | str = Calibration.L2) -> float:
        return min(self.lobes.level_for_glossiness(0.0, calibration), self.levels - 1)

    def level_for_glossiness(self, g: float, calibration: Calibration | str = Calibration.L2) -> float:
        return min(self.lobes.level_for_glossiness(g, calibration), self.levels - 1)

    def lookup_level(self, level: float) -> float:
        """A chain level as the stored textures number it (their level 0 is the base level)."""
        return max(float(level) - self.base_level, 0.0)

    def read_level_raw(self, level: int) -> np.ndarray:
        """Stored (scaled) texels of one chain level (>= the base level): float32 (N, 6, s, s, 4)."""
        if not self.base_level <= level < self.levels:
            raise InvalidInputError(f"level {level} is not stored: this set keeps levels {self.base_level}.."
                                    f"{self.levels - 1}")
        return np.concatenate([t.read_level(level - self.base_level) for t in self.textures])

    def bind(self, first_unit: int, second_unit: int, norm_unit: int) -> None:
        """Bind the PEM textures for shading (regions 0..191 and 192..383) and the normalizer B."""
        self.textures[0].bind_sampler(first_unit)
        self.textures[-1].bind_sampler(second_unit)
        self.norm_texture.bind_sampler(norm_unit)

    def read_level(self, level: int) -> np.ndarray:
        """All regions' texels of one level as radiance (A * scale / B at the texel centres): float32
        (N, 6, s, s, 3)."""
        data = self.read_level_raw(level)[..., :3]
        inv_b = (1.0 / self._norm[level]).astype(np.float32)[None]
        return data * self.scale.astype(np.float32)[:, None, None, None, None] * inv_b

    def summary(self) -> dict:
        lights = None
        if self.regions.area_mask.any():
            idx = np.flatnonzero(self.regions.area_mask)
            total = float(self.regions.energy_luminance.sum())
            lights = [{"direction": [round(float(c), 5) for c in self.regions.directions[i]],
                       "angular_radius_deg": round(float(np.degrees(self.regions.disc_radius_rad()[i])), 3),
                       "energy_share": round(float(self.regions.energy_luminance[i]) / total, 5)} for i in idx]
        extra = {"lights_from": self.settings.lights_from,
                 "lights_from_used": "area" if lights is not None else "median-cut", "area_lights": lights,
                 "ambient_share": None if lights is None else round(1.0 - sum(x["energy_share"] for x in lights), 5)}
        return {**extra, "n_regions": self.n_regions, "face_size": self.face_size, "levels": self.levels,
                "base_level": self.base_level,
                "filter": self.settings.filter.value, "build_ms": round(self.build_ms, 2),
                "median_cut_ms": round(self.median_cut_ms, 2), "bytes": self.nbytes,
                "diffuse_level": round(self.diffuse_level(), 3)}

    def release(self) -> None:
        if self.rotation_deg != 0.0:
            raise InvalidInputError("a turned view of a PEM set is released with the set it views")
        for t in self.textures:
            t.release()
        self.norm_texture.release()
        self.env_texture.release()
        self._turned.clear()
