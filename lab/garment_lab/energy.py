"""`garment-render bench --energy`: each physically based material's energy against the Monte Carlo
reference, on a sphere under procedural maps that isolate one kind of light each.

A sphere (nothing else in the scene) is shaded at every view elevation at once, so a loss that
depends on n.v (the fit's grazing tail, the horizon clip) shows in its outer ring. Materials: GGX
at roughness 0.1 to 1, dielectric and metal, and two sheen layers over GGX. Maps (built here, no
asset): a uniform white map (a furnace: the renderer's lights cover the whole sphere), one small
light in front, one small light behind and above (it reflects at grazing views on the sphere's
upper rim), and four coloured windows around the sphere. Per material, map and shading mode (the
full method against the reference with occlusion; no occlusion against V = 1): the energy over the
sphere's pixels (sum of the image's RGB over the reference's, minus 1), the same over the grazing
ring (n.v < 0.5), rel. RMSE against the mean of two references (seeds 1 and 2) with its noise floor.

Both sides are supersampled (SUPERSAMPLE^2 samples a pixel, box-filtered): each renders its pixel
centres only, and a sharp highlight on the rim (roughness 0.1 under a 6-degree light) is a crescent
narrower than a pixel of a 64 x 64 image, which pixel centres catch or miss by its place. Point
sampled, the same material measured -12.8 % at 64 x 64 and +2.1 % at 128 x 128 (r0.1 m1 under the
light behind, no occlusion): the energy of the sampling, not of the material.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import trimesh

from renderer.camera import Camera
from renderer.envmap.cube import texel_directions
from renderer.mesh import Mesh
from renderer.presets import frame_settings, pem_settings, preset, presets_digest
from renderer.reference import relative_rmse
from renderer.reference.montecarlo import primary_rays
from renderer.renderer import Renderer, ShadingMode
from renderer.shading.material import Material

from .materials import ReferencePair, energy
from .report import machine_info

PRESET = "balanced"
CAMERA = Camera((0.0, 0.3, 3.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)
RADIUS = 0.5
GRAZING_N_DOT_V = 0.5
# Where a report calls a material's energy wrong (the fit's own error at grazing views is larger:
# docs/brdf-lobes.md; this is what a designer would see as a darker or brighter fabric).
ENERGY_TOLERANCE = 0.03
# Samples per pixel side, on both sides (the module doc); the reference's samples per sub-pixel are
# its spp / SUPERSAMPLE^2, so a pixel's count (and noise) is the same.
SUPERSAMPLE = 4


def box_down(image: np.ndarray, factor: int) -> np.ndarray:
    """(H * factor, W * factor, 4) RGBA with 0/1 coverage -> (H, W, 4): per pixel the mean over its
    factor x factor samples of the sphere's radiance where they hit it (RGB times coverage: the
    background the samples that miss see stays out) and its coverage."""
    h, w = image.shape[0] // factor, image.shape[1] // factor
    rgba = np.asarray(image, np.float64).copy()
    rgba[..., :3] *= rgba[..., 3:4]
    return rgba.reshape(h, factor, w, factor, 4).mean(axis=(1, 3)).astype(np.float32)


def _materials() -> dict[str, Material]:
    out = {}
    for metallic, base in ((0.0, (0.6, 0.3, 0.2)), (1.0, (0.9, 0.6, 0.3))):
        for roughness in (0.1, 0.25, 0.5, 0.75, 1.0):
            out[f"r{roughness:g} m{metallic:g}"] = Material(base, model="pbr", metallic=metallic, roughness=roughness)
    out["r0.25 sheen 0.3"] = Material((0.55, 0.07, 0.12), model="pbr", roughness=0.25,
                                      sheen_colour=(0.6, 0.3, 0.35), sheen_roughness=0.3)
    out["r0.75 sheen 0.5"] = Material((0.25, 0.04, 0.08), model="pbr", roughness=0.75,
                                      sheen_colour=(0.9, 0.4, 0.5), sheen_roughness=0.5)
    return out


MATERIALS = _materials()


def _direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Azimuth 0 towards the camera (+Z), 90 towards +X; elevation above the horizon (+Y up)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])


def _background(d: np.ndarray, sky, ground) -> np.ndarray:
    return np.where(d[..., 1:2] > 0, np.asarray(sky, np.float32), np.asarray(ground, np.float32)).astype(np.float32)


def _disc_light(face_size: int, azimuth: float, elevation: float, radius_deg: float, radiance: float) -> np.ndarray:
    d = texel_directions(face_size)
    cube = _background(d, (0.1, 0.15, 0.25), (0.05, 0.05, 0.05))
    cube[d @ _direction(azimuth, elevation) > np.cos(np.radians(radius_deg))] = radiance
    return cube


# The windows: (azimuth, elevation, half width, half height in degrees, RGB radiance).
WINDOWS = ((40.0, 20.0, 15.0, 12.0, (6.0, 4.5, 3.0)), (-70.0, 35.0, 10.0, 15.0, (2.0, 3.0, 5.0)),
           (170.0, 50.0, 18.0, 10.0, (5.0, 5.0, 5.0)), (110.0, 5.0, 12.0, 6.0, (1.0, 4.0, 2.0)))


def _windows(face_size: int) -> np.ndarray:
    d = texel_directions(face_size)
    cube = _background(d, (0.05, 0.05, 0.06), (0.02, 0.02, 0.02))
    az = np.degrees(np.arctan2(d[..., 0], d[..., 2]))
    el = np.degrees(np.arcsin(np.clip(d[..., 1], -1.0, 1.0)))
    for a, e, hw, hh, rgb in WINDOWS:
        da = (az - a + 180.0) % 360.0 - 180.0
        cube[(np.abs(da) < hw) & (np.abs(el - e) < hh)] = rgb
    return cube


MAPS = {
    "uniform": lambda f: np.full((6, f, f, 3), 1.0, np.float32),
    "light in front": lambda f: _disc_light(f, 30.0, 40.0, 6.0, 150.0),
    "light behind": lambda f: _disc_light(f, 160.0, 35.0, 6.0, 150.0),
    "windows": _windows,
}


def sphere() -> Mesh:
    s = trimesh.creation.icosphere(5, RADIUS)
    return Mesh.from_arrays(np.asarray(s.vertices), np.asarray(s.faces), name="sphere")


def sphere_n_dot_v(size: int) -> np.ndarray:
    """n.v of the analytic sphere through each pixel centre (NaN off it), (size, size)."""
    origins, dirs = primary_rays(CAMERA, size, size, np.zeros(3), RADIUS * 1.2)
    b = np.einsum("ij,ij->i", origins, dirs)
    disc = b * b - (np.einsum("ij,ij->i", origins, origins) - RADIUS ** 2)
    t = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    hit = origins + t[:, None] * dirs
    return (-np.einsum("ij,ij->i", hit / RADIUS, dirs)).reshape(size, size)


def run(out_dir: Path, quick: bool = False, size: int = 64, spp: int = 64, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    knobs = preset(PRESET)
    materials = MATERIALS if not quick else {k: v for k, v in MATERIALS.items()
                                              if k in ("r0.25 m0", "r0.5 m1", "r0.25 sheen 0.3")}
    maps = MAPS if not quick else {k: v for k, v in MAPS.items() if k in ("uniform", "light behind")}
    nv = sphere_n_dot_v(size)
    rows = []
    t_start = time.perf_counter()
    mesh = [sphere()]
    with Renderer() as r:
        for map_name, make in maps.items():
            ref_cube = make(256)
            pems = r.build_pems(make(int(knobs["face_size"])), pem_settings(knobs, "sqrt-cosine", None))
            try:
                for name, material in materials.items():
                    gs = r.create_scene(mesh, [material])
                    try:
                        for mode, occlusion in ((ShadingMode.FULL, True), (ShadingMode.NO_OCCLUSION, False)):
                            t0 = time.perf_counter()
                            a, b = (_reference(mesh, material, ref_cube, size, spp, s, occlusion) for s in (1, 2))
                            truth = ReferencePair(a, b, 0.5 * (a + b), (0.5 * (a + b))[..., 3] > 0.5,
                                                  relative_rmse(a, b, (0.5 * (a + b))[..., 3] > 0.5) / 2.0,
                                                  time.perf_counter() - t0)
                            # The method at SUPERSAMPLE^2 samples a pixel, as the references.
                            fs = frame_settings(knobs, size * SUPERSAMPLE, size * SUPERSAMPLE, mode=mode)
                            image = box_down(r.render(gs, pems, fs, CAMERA).image, SUPERSAMPLE)
                            mask = truth.mask & np.isfinite(nv)
                            grazing = mask & (nv < GRAZING_N_DOT_V)
                            row = {"map": map_name, "material": name, "mode": mode.value,
                                   "energy": energy(image, truth.image, mask),
                                   "energy_noise": energy_noise(a, b, mask),
                                   "grazing_energy": energy(image, truth.image, grazing),
                                   "rel_rmse": relative_rmse(image, truth.image, mask), "noise_floor": truth.floor}
                            rows.append(row)
                            log(f"{map_name:15s} {name:16s} {mode.value:5s} energy {100 * row['energy']:+6.1f} % "
                                f"(noise {100 * row['energy_noise']:.1f} %) "
                                f"(grazing {100 * row['grazing_energy']:+6.1f} %)  rel. RMSE {row['rel_rmse']:.3f} "
                                f"(floor {truth.floor:.3f})")
                    finally:
                        gs.release()
            finally:
                pems.release()
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "preset": PRESET, "size": size, "spp": spp,
            "supersample": SUPERSAMPLE, "quick": quick,
            "wall_s": time.perf_counter() - t_start, "rows": rows}
    (out_dir / "energy.json").write_text(json.dumps(data, indent=1))
    (out_dir / "energy.md").write_text(markdown(data))
    return data


def energy_noise(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """How far each of two references' energy over the mask is from their mean's, relative: the
    truth's own uncertainty in energy (a sharp highlight of a small bright light is found by few of a
    reference's paths: r0.1 m0 under the light behind, three seeds at 64 spp a pixel, spread by 15 %)."""
    sa, sb = float(a[mask][:, :3].sum()), float(b[mask][:, :3].sum())
    return abs(sa - sb) / (sa + sb) if sa + sb > 0 else float("nan")


def outside(row: dict) -> bool:
    """A row whose energy is off by more than ENERGY_TOLERANCE beyond the reference's own noise."""
    return abs(row["energy"]) > ENERGY_TOLERANCE + row.get("energy_noise", 0.0)


def _reference(mesh, material, cube, size, spp, seed, occlusion) -> np.ndarray:
    """The reference at size x size, SUPERSAMPLE^2 sub-pixels a pixel of spp / SUPERSAMPLE^2 samples each."""
    from renderer.reference import render_reference

    sub = max(1, spp // SUPERSAMPLE ** 2)
    return box_down(render_reference(mesh, [material], cube, CAMERA, size * SUPERSAMPLE, size * SUPERSAMPLE, sub,
                                     seed=seed, occlusion=occlusion).image, SUPERSAMPLE)


def markdown(data: dict) -> str:
    m = data["machine"]
    rows = data["rows"]
    lines = ["# Energy of the physically based materials against the reference", "",
             f"Made by `garment-render bench --energy{' --quick' if data['quick'] else ''}` on {m['gl_renderer']}, "
             f"{m['cores']} cores ({m['date']}): preset {data['preset']}, a sphere at {data['size']} x {data['size']}, "
             f"{data.get('supersample', 1) ** 2} samples a pixel on both sides (box-filtered), "
             f"references of {data['spp']} spp per technique a pixel (two seeds; the floor is their mean's own rel. RMSE), "
             f"{data['wall_s'] / 60:.0f} min in all (lab/garment_lab/energy.py).",
             "Energy: the image's RGB summed over the sphere against the reference's, minus 1; grazing: over "
             f"n.v < {GRAZING_N_DOT_V}. Full: the method with its shadow maps against the reference with occlusion; "
             "none: both without.", ""]
    off = [r for r in rows if outside(r)]
    lines.append(f"{len(rows) - len(off)} of {len(rows)} rows within {100 * ENERGY_TOLERANCE:.0f} % of the "
                 "reference's energy beyond its own noise (the energy noise column: how far each of the two "
                 "references' energy is from their mean's)" + (": outside it, " + ", ".join(
                     f"{r['material']} under {r['map']} ({r['mode']}) {100 * r['energy']:+.1f} %" for r in off)
                     if off else "") + ".")
    lines += ["", "| map | material | mode | energy | energy noise | grazing | rel. RMSE | floor |",
              "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['map']} | {r['material']} | {r['mode']} | {100 * r['energy']:+.1f} % | "
                     f"{100 * r.get('energy_noise', float('nan')):.1f} % | "
                     f"{100 * r['grazing_energy']:+.1f} % | {r['rel_rmse']:.3f} | {r['noise_floor']:.3f} |")
    return "\n".join(lines) + "\n"
