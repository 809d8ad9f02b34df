"""What a PEM set is and costs, without a GL context: its settings (PEMSettings, the cache key), the
levels a scene reads, its memory and build cost (pem_cost) and the layout constants the set and the
lighting pass share. The set itself, built and bound on the GPU, is renderer/lighting/pem.py's; the
service judges requests from here without importing GL."""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass, field, make_dataclass, replace

import numpy as np

from .. import config
from .filters import Filter
from .glossiness import Calibration, lobe_table
from .pem_reference import mip_levels

# Entries of a PEM set's gloss table (PEMSet.gloss_table; the lighting pass interpolates it).
GLOSS_TABLE_SIZE = 257


def finest_level_needed(face_size: int, kind: Filter | str, max_glossiness: float,
                        calibration: Calibration | str = Calibration.L2, levels: int | None = None) -> int:
    """The base level a scene needs: the finest level any of its lookups reads (the trilinear lookup at
    the level of its glossiest material reads floor(level)); the diffuse level is always deeper."""
    table = lobe_table(face_size, Filter.parse(kind))
    full = mip_levels(face_size) if levels is None else levels
    # The shader interpolates the gloss table (GLOSS_TABLE_SIZE entries, non-increasing in g): a g below
    # g_max reads no finer a level than the entry at or above g_max, which can be far finer than the
    # level of g_max itself in the table's last step (its last entry is the mirror, level 0).
    steps = GLOSS_TABLE_SIZE - 1
    g_entry = min(np.ceil(float(max_glossiness) * steps) / steps, 1.0)
    level = min(table.level_for_glossiness(g_entry, calibration), full - 1)
    return int(np.clip(np.floor(level), 0, full - 1))

SCRATCH_BUDGET_BYTES = 64 << 20  # bound on the two float32 scratch buffers of one batch
# GL_MAX_ARRAY_TEXTURE_LAYERS is 2048 on Mesa and NVIDIA: 341 cubes. 192 regions per texture keeps
# power-of-two light counts in whole textures; 384 lights use two (the shader has two samplers).
REGIONS_PER_TEXTURE = 192
# Bytes per disc of sub_lights_bytes: (direction, sine of its radius), (rgb energy, 0) as float32.
SUB_LIGHT_BYTES = 32
MAX_TEXTURES = 2


def scratch_batch(n: int) -> tuple[int, int]:
    """The regions one batch of the build filters at once and the bytes of one region's scratch level
    (two float32 buffers of a batch fit SCRATCH_BUDGET_BYTES; a batch never straddles two textures)."""
    per_region_bytes = 6 * max(1, (n // 2) ** 2) * 16
    batch = int(max(1, min(REGIONS_PER_TEXTURE, SCRATCH_BUDGET_BYTES // (2 * per_region_bytes))))
    while REGIONS_PER_TEXTURE % batch:
        batch -= 1
    return batch, per_region_bytes



class _PEMChecks:
    """PEMSettings' checks, key and variant for a scene's materials (its fields are made below)."""

    def __post_init__(self):
        for name in config.PEM_FIELDS:   # each setting against its declared limits (renderer/config.py)
            object.__setattr__(self, name, config.check(name, getattr(self, name)))

    def key(self) -> tuple:
        base = (self.lights, self.filter.value, self.levels, self.base_level, self.whole_sources)
        return base if self.lights_from == "median-cut" else base + (self.lights_from,)

    def for_materials(self, face_size: int, materials, calibration: Calibration | str = Calibration.L2) -> PEMSettings:
        """These settings storing only the levels the materials' glossiest lookup reads
        (`finest_level_needed`): the same image, a fraction of the memory."""
        g_max = max((m.max_glossiness() for m in materials), default=0.0)
        return replace(self, base_level=finest_level_needed(face_size, self.filter, g_max, calibration, self.levels))


PEMSettings = make_dataclass(
    "PEMSettings",
    [*config.fields(("lights",)), ("_", KW_ONLY),   # the light count by position, the rest by name
     *config.fields(tuple(n for n in config.PEM_FIELDS if n != "lights")),
     ("filter", Filter, field(default=Filter(config.OPTION["filter"].default))),
     ("levels", int | None, field(default=None)),
     ("base_level", int, field(default=0))],
    bases=(_PEMChecks,), frozen=True, namespace={"__module__": __name__, "__doc__": (
        "Everything that changes a PEM set (its cache key): the registry's PEM settings but the face size, which "
        "is the cube's (renderer/config.py: each one's type, limits, default and what it does), the MIP filter, "
        "the chain's length (levels; None: down to 1x1 faces) and its finest level stored (base_level: the levels "
        "above it are computed on the way down but not kept, since no lookup of the scene reads them, "
        "finest_level_needed; 0: the whole chain). PEMSettings() is the paper's median cut; a preset's come from "
        "presets.resolve(...).pems().")})
PAPER_PEMS = PEMSettings()   # a PEM set's default settings: the paper's median cut


@dataclass(frozen=True)
class PEMCost:
    """What a PEM set takes, from its settings alone (`pem_cost`; nothing is allocated).

    stored_bytes: the GPU memory of its chain (PEMSet.nbytes: the stored levels of every light's
    RGBA16F cube and the RGBA32F normalizer), what a cache holds. peak_bytes: the most memory the
    build holds at once, GPU and host together (the chain, the map's texture, the source cube and
    its weighted copy on both sides, the labels, the batch scratch, and with `export` the float16
    copy written to a disk cache plus the float32 read of its largest level). texel_lights: the
    chain's texels, every level computed (those above the base level too), times the lights: what
    the build's time grows with."""

    stored_bytes: int
    peak_bytes: int
    texel_lights: int


def pem_cost(face_size: int, settings: PEMSettings, export: bool = False) -> PEMCost:
    """The cost of the PEM set of a (6, face_size, face_size) cube for `settings` (see PEMCost)."""
    n, lights = int(face_size), int(settings.lights)
    full = mip_levels(n)
    levels = full if settings.levels is None else int(np.clip(settings.levels, 1, full))
    base = min(int(settings.base_level), levels - 1)
    texels = [6 * max(1, n >> lv) ** 2 for lv in range(levels)]
    stored_texels = sum(texels[base:])
    stored = lights * stored_texels * 8 + stored_texels * 16
    face = 6 * n * n
    batch, per_region_bytes = scratch_batch(n)
    # Host: the float32 cube, its brightest channel, the weighted RGBA copy, the labels, the median
    # cut's float64 sums and the normalizer's chain and RGBA upload copy; GPU: the map's texture, the
    # weighted copy and labels again, two scratch buffers.
    build = face * (12 + 4 + 16 + 4 + 32 + 16 + 16) + face * (12 + 16 + 4) + 2 * batch * per_region_bytes
    peak = stored + build
    if export:   # the float16 copy, and while a level is read: one texture's float32 and the level's parts
        peak += lights * stored_texels * 8 + min(lights, REGIONS_PER_TEXTURE) * texels[base] * 16 \
            + lights * texels[base] * 8
    return PEMCost(stored, peak, lights * sum(texels))
