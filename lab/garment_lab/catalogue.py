"""The broad benchmark's scenes (`bench.broad`): every shared map x three garments on a body or form x
three fabrics x two views, and the fixed rule that splits the maps into a tuning and a held-out set.

Everything here decides what a reference image shows, so its source is part of the reference cache's
key (`broad.reference_code_digest`); the report's code is not.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from renderer.camera import Camera, bounds_sphere, default_camera
from renderer.mesh import Mesh, bounds, load_mesh
from renderer.shading.material import Material

from .scenes import TARGET_PROBES, shared_assets

# --- the scenes ---------------------------------------------------------------------------------

MAPS = ("adams_place_bridge_1k.hdr", "dikhololo_night_1k.hdr", "empty_warehouse_01_1k.hdr", "forest_slope_1k.hdr",
        "immenstadter_horn_1k.hdr", "kiara_1_dawn_1k.hdr", "lebombo_1k.hdr", "potsdamer_platz_1k.hdr",
        "rooitou_park_1k.hdr", "st_fagans_interior_1k.hdr", "ennis.hdr", "pisa.hdr", "wells.hdr",
        "openexr_StageEnvLatLong.exr", "openexr_KernerEnvLatLong.exr", "pmndrs_assets_hall.exr",
        "pmndrs_assets_sky.exr", "studio_small_03_1k.hdr")
# Tuning maps besides the ones the presets were already tuned on.
EXTRA_TUNING_MAPS = 4

GARMENTS = ("shirt", "polo", "dress")
# Linear albedo, weight of the glossy lobe, glossiness g: fabrics of increasing sheen.
FABRICS = {
    "cotton": Material((0.62, 0.58, 0.52), 0.04, 0.3),
    "sheen": Material((0.18, 0.28, 0.55), 0.3, 0.75),
    "satin": Material((0.55, 0.07, 0.12), 0.6, 0.93),
}
BODY = Material((0.6, 0.5, 0.45), 0.1, 0.3)
# Directions from the garment's centre to the camera (Y-up; the garments face +Z).
VIEWS = {"front": (0.0, 0.2, 1.0), "three-quarter": (-0.8, 0.3, 0.6)}
PRESETS = ("fast", "balanced", "accurate")
# The reference's cube: finer than any preset's PEM faces.
REFERENCE_FACE_SIZE = 256
# The 256 x 256 subset: one fabric and view of every map and garment.
LARGE_FABRIC, LARGE_VIEW = "sheen", "front"

# The targets on the held-out set at 256 x 256 (None: no target).
TARGETS = {
    "fast": {"rel_rmse": 0.10, "flip": None, "artefact_share": 0.02, "frame_ms": 40.0},
    "balanced": {"rel_rmse": 0.05, "flip": 0.05, "artefact_share": 0.005, "frame_ms": 100.0},
    "accurate": {"rel_rmse": 0.03, "flip": None, "artefact_share": 0.002, "frame_ms": 400.0},
}
# The least speed-up over the Monte Carlo tracer at the preset's own error (issue 35).
EQUAL_ERROR_TARGETS = {"fast": 10.0, "balanced": 10.0, "accurate": 3.0}


def split(maps=MAPS) -> dict[str, str]:
    """Each map's set, "tuning" or "held-out", by the rule of the module doc."""
    tuned = set(TARGET_PROBES.values())
    others = sorted((m for m in maps if m not in tuned), key=lambda m: hashlib.sha256(m.encode()).hexdigest())
    tuning = tuned | set(others[:EXTRA_TUNING_MAPS])
    return {m: ("tuning" if m in tuning else "held-out") for m in maps}


def fit_body_inside(body: np.ndarray, garment: np.ndarray, margin: float = 0.01, band: float = 0.02,
                    sectors: int = 36, reach: float = 1.6) -> np.ndarray:
    """A body's vertices moved so that it lies inside a garment made for another body: first the body
    is shifted across (x, z) so that its chest is centred in the garment's top quarter; then, in bands
    of `band` metres over the garment's height and `sectors` sectors around the garment's axis in each
    band, body vertices farther out than the garment's innermost vertex less `margin` are pulled in to
    it. Vertices beyond `reach` times the garment's radius there (an arm below a sleeve) are left.
    A rule, not a simulation: the dress's bodice still meets the bust at its neckline in a few places
    (both the reference and the renderer see the same geometry)."""
    g, b = garment.astype(np.float64), body.astype(np.float64).copy()
    lo, hi = float(g[:, 1].min()), float(g[:, 1].max())
    top = g[g[:, 1] >= hi - 0.25 * (hi - lo)]
    centre_top = 0.5 * (top[:, [0, 2]].min(0) + top[:, [0, 2]].max(0))
    half_width = 0.5 * float(top[:, 0].max() - top[:, 0].min())
    chest = b[(b[:, 1] >= hi - 0.25 * (hi - lo)) & (b[:, 1] <= hi)]
    chest = chest[np.abs(chest[:, 0] - np.median(chest[:, 0])) < half_width]
    if len(chest):
        b[:, [0, 2]] += centre_top - 0.5 * (chest[:, [0, 2]].min(0) + chest[:, [0, 2]].max(0))
    n_bands = max(1, int(np.ceil((hi - lo) / band)))

    def band_of(p):
        return np.clip(((p[:, 1] - lo) / band).astype(int), 0, n_bands - 1)

    gb = band_of(g)
    centre = np.full((n_bands, 2), np.nan)
    for k in np.unique(gb):
        sel = g[gb == k][:, [0, 2]]
        centre[k] = 0.5 * (sel.min(0) + sel.max(0))
    have = ~np.isnan(centre[:, 0])
    for j in range(2):
        centre[:, j] = np.interp(np.arange(n_bands), np.flatnonzero(have), centre[have, j])

    def polar(p, k):
        d = p[:, [0, 2]] - centre[k]
        sector = ((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors
        return d, np.hypot(d[:, 0], d[:, 1]), sector

    _, g_r, g_s = polar(g, gb)
    inner = np.full((n_bands, sectors), np.inf)
    np.minimum.at(inner, (gb, g_s), g_r)
    inside = (b[:, 1] >= lo) & (b[:, 1] <= hi)
    p = b[inside]
    k = band_of(p)
    d, r, s = polar(p, k)
    limit = inner[k, s] - margin
    move = np.isfinite(limit) & (limit > 0) & (r > limit) & (r < reach * inner[k, s])
    scale = np.where(move, limit / np.maximum(r, 1e-12), 1.0)
    p[:, 0] = centre[k, 0] + d[:, 0] * scale
    p[:, 2] = centre[k, 1] + d[:, 1] * scale
    b[inside] = p
    return b.astype(np.float32)


@cache
def garment_meshes(garment: str) -> tuple[Mesh, Mesh]:
    """(garment, body) in metres, Y-up."""
    assets = shared_assets()
    if garment == "shirt":
        return (load_mesh(assets / "sim" / "newton_shirt_drape_f060.obj", up="z"),
                load_mesh(assets / "sim" / "newton_shirt_drape_colliders.obj", up="z"))
    files = {"polo": "diffavatar_polo.obj", "dress": "diffavatar_dress_draped.obj"}
    cloth = load_mesh(assets / "meshes" / files[garment], scale=0.01)   # centimetres
    body = load_mesh(assets / "meshes" / "garmentcode_mean_all_body.obj")
    body = body.with_positions(fit_body_inside(body.positions, cloth.positions))
    return cloth, body


@cache
def environment_cube(name: str, face_size: int) -> np.ndarray:
    from renderer.envmap import load_environment

    return load_environment(shared_assets() / "hdri" / name, face_size=face_size, repair=True).cube


@dataclass(frozen=True)
class Scene:
    map: str
    garment: str
    fabric: str
    view: str
    size: int

    @property
    def name(self) -> str:
        return f"{self.garment}/{self.fabric}/{self.view}/{Path(self.map).stem}@{self.size}"

    def meshes(self) -> list[Mesh]:
        return list(garment_meshes(self.garment))

    def materials(self) -> list[Material]:
        return [FABRICS[self.fabric], BODY]

    def camera(self) -> Camera:
        centre, radius = bounds_sphere(*bounds([garment_meshes(self.garment)[0]]))
        return default_camera(centre, radius, 1.0, 35.0, VIEWS[self.view])


def scenes(quick: bool = False) -> list[Scene]:
    """The benchmark's scenes, in an order that mixes maps and garments (an interrupted run still
    covers both sets); quick: two maps of each set, two garments, one fabric and view, 128 x 128."""
    sets = split()
    if quick:
        tuning = [m for m in MAPS if sets[m] == "tuning"][:2]
        held = [m for m in MAPS if sets[m] == "held-out"][:2]
        return [Scene(m, g, LARGE_FABRIC, LARGE_VIEW, 128) for g in ("shirt", "polo") for m in tuning + held]
    out = [Scene(m, g, f, v, 128) for v in VIEWS for f in FABRICS for g in GARMENTS for m in MAPS]
    out += [Scene(m, g, LARGE_FABRIC, LARGE_VIEW, 256) for g in GARMENTS for m in MAPS]
    return out


