"""`garment-render bench --sizes`: does balanced's accuracy hold as the image grows?

Per scene (the knob sweep's newton shirt under its four probes: tuning; the polo on two held-out
maps), at each image size of `SIZES`, two references of `spp` samples per technique (their mean the
truth, its own rel. RMSE the floor) and the balanced preset, whose shadow maps keep their side
whatever the image. Beside it, from the second size on, two ways for the maps to follow the image
(balanced's side x size / 256):

- "maps follow": the maps grow, the knobs counted in map texels (normal offset, least blur, contact
  reach) keep their counts, so penumbrae, bias and the contact search shrink in the scene with the
  texels;
- "maps follow, same scene widths": the maps grow and those knobs grow with them (within their
  ranges), so every width in the scene stays balanced's, only finer sampled.

Two errors per row: rel. RMSE at the image's own size, and at 256 x 256 (frame, truth and the two
references box-filtered to 256 first: the same surface seen at the bench's pixel size). Each is also
given as its excess over the floor, sqrt(e^2 - floor^2), since the references' per-pixel noise does
not shrink with size. "rim": the share of the squared error in the object's outermost pixel ring
(where the silhouette is nearly edge-on, 1 / (size / 256) of the 256 ring's width in the scene).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.camera import frame_meshes
from renderer.config import BY_NAME
from renderer.presets import frame_settings, pem_settings, preset
from renderer.reference import relative_rmse
from renderer.reference.metrics import relative_squared_errors
from renderer.renderer import Renderer

from .catalogue import LARGE_FABRIC, LARGE_VIEW, MAPS, Scene, environment_cube, split
from .materials import ReferencePair
from .report import machine_info
from .run import time_frames
from .scenes import shared_scenes

SIZES = (256, 512, 1024)
BASE_SIZE = 256
# The knobs counted in main-map texels: "same scene widths" scales them with the maps.
TEXEL_KNOBS = ("normal_offset_texels", "min_sigma_texels", "contact_shadow_texels")
HELD_OUT_MAPS = 2


def variants(size: int) -> dict[str, dict]:
    """The settings compared at one image size: balanced, and (above BASE_SIZE) its maps following the image."""
    base = preset("balanced")
    out = {"balanced": {}}
    k = size // BASE_SIZE
    if k > 1:
        out["maps follow"] = {"shadow_size": base["shadow_size"] * k}
        # Within each knob's range (the contact reach stops at its most texels: at 1024 its width in
        # the scene is 64 / 96 of balanced's).
        out["maps follow, same scene widths"] = {"shadow_size": base["shadow_size"] * k,
                                                 **{name: min(base[name] * k, BY_NAME[name].maximum)
                                                    for name in TEXEL_KNOBS}}
    return out


def box_down(image: np.ndarray, k: int) -> np.ndarray:
    """(H, W, C) averaged over k x k blocks."""
    if k == 1:
        return image
    h, w = image.shape[:2]
    return image.reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def excess(error: float, floor: float) -> float:
    return float(np.sqrt(max(error * error - floor * floor, 0.0)))


def _rim(mask: np.ndarray) -> np.ndarray:
    """The mask's pixels with a 4-neighbour outside it."""
    from scipy.ndimage import binary_erosion

    return mask & ~binary_erosion(mask, border_value=1)   # the image edge is not the object's edge


def _scenes(quick: bool):
    """(set, name, meshes, materials, camera, cube loader)."""
    out = []
    for bs in shared_scenes()[: 1 if quick else None]:
        out.append(("tuning", bs.name, bs.meshes, bs.materials, frame_meshes(bs.meshes, 1.0), bs.cube))
    held = [m for m in MAPS if split()[m] == "held-out"][: 1 if quick else HELD_OUT_MAPS]
    for m in held:
        s = Scene(m, "polo", LARGE_FABRIC, LARGE_VIEW, BASE_SIZE)
        out.append(("held-out", f"polo/{Path(m).stem}", s.meshes(), s.materials(), s.camera(),
                    lambda f, m=m: environment_cube(m, f)))
    return out


def run(out_dir: Path, quick: bool = False, spp: int = 64, frames: int = 3, sizes=SIZES, log=print) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sizes = tuple(sizes[:2]) if quick else tuple(sizes)
    base = preset("balanced")
    rows = []
    t_start = time.perf_counter()
    with Renderer() as r:
        for which, name, meshes, materials, camera, cube in _scenes(quick):
            gs = r.create_scene(meshes, materials)
            pems = r.build_pems(cube(int(base["face_size"])), pem_settings(base, "sqrt-cosine", None))
            try:
                for size in sizes:
                    truth = ReferencePair.render(meshes, materials, cube(256), camera, size, spp)
                    k = size // BASE_SIZE
                    low = box_down(truth.image, k)
                    low_mask = low[..., 3] > 0.999   # wholly covered at 256
                    low_floor = relative_rmse(box_down(truth.a, k), box_down(truth.b, k), low_mask) / 2.0
                    rim = _rim(truth.mask)[truth.mask]
                    for label, knobs in variants(size).items():
                        fs = frame_settings({**base, **knobs}, size, size)
                        f, frame_ms, _ = time_frames(r, gs, pems, fs, camera, frames)
                        per_pixel = relative_squared_errors(f.image, truth.image, truth.mask)
                        err = float(np.sqrt(per_pixel.mean()))
                        err_low = relative_rmse(box_down(f.image, k), low, low_mask)
                        row = {"set": which, "scene": name, "size": size, "settings": label,
                               "shadow_size": int(fs.shadow_size), "rel_rmse": err, "floor": truth.floor,
                               "excess": excess(err, truth.floor), "rel_rmse_at_256": err_low,
                               "floor_at_256": low_floor, "excess_at_256": excess(err_low, low_floor),
                               "rim_share": float(per_pixel[rim].sum() / max(per_pixel.sum(), 1e-300)),
                               "frame_ms": frame_ms, "reference_s": truth.wall_s}
                        rows.append(row)
                        log(f"{name:28s} {size:5d} {label:31s}: rel. RMSE {err:.4f} (floor {truth.floor:.4f}, "
                            f"excess {row['excess']:.4f}); at 256 {err_low:.4f} (excess {row['excess_at_256']:.4f}); "
                            f"rim {row['rim_share']:.0%}; {frame_ms:.0f} ms")
            finally:
                pems.release()
                gs.release()
        machine = machine_info(r.gl)
    data = {"machine": machine, "spp": spp, "frames": frames, "quick": quick, "sizes": list(sizes),
            "wall_s": time.perf_counter() - t_start, "rows": rows, "summary": summary(rows)}
    (out_dir / "sizes.json").write_text(json.dumps(data, indent=1))
    (out_dir / "sizes.md").write_text(markdown(data))
    return data


def summary(rows: list[dict]) -> list[dict]:
    """Per scene and size above the first, balanced's excess against its own at the first size, at
    the image's size and at 256."""
    out = []
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    for scene in scenes:
        mine = [r for r in rows if r["scene"] == scene and r["settings"] == "balanced"]
        first = min(mine, key=lambda r: r["size"])
        for r in mine:
            if r is first:
                continue
            out.append({"set": r["set"], "scene": scene, "size": r["size"],
                        "excess_ratio": r["excess"] / max(first["excess"], 1e-12),
                        "excess_at_256_ratio": r["excess_at_256"] / max(first["excess_at_256"], 1e-12)})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Balanced's accuracy as the image grows", "",
             f"Made by `garment-render bench --sizes` on {m['gl_renderer']}, {m['cores']} cores ({m['date']}): "
             f"references of {data['spp']} spp per technique, two seeds; frame times the median of "
             f"{data['frames']} frames ({data['wall_s'] / 60:.0f} min in all). 'excess': sqrt(e^2 - floor^2); "
             "'at 256': frame and truth box-filtered to 256 x 256 first; 'rim': the share of the squared error "
             "in the object's outermost pixel ring.", "",
             "| set | scene | size | settings | shadow map | rel. RMSE | floor | excess | at 256 | excess at 256 "
             "| rim | frame ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(f"| {r['set']} | {r['scene']} | {r['size']} | {r['settings']} | {r['shadow_size']} | "
                     f"{r['rel_rmse']:.3f} | {r['floor']:.3f} | {r['excess']:.3f} | {r['rel_rmse_at_256']:.3f} | "
                     f"{r['excess_at_256']:.3f} | {r['rim_share']:.0%} | {r['frame_ms']:.0f} |")
    lines += ["", "Balanced at each size against itself at the first size (excess over the floor):", "",
              "| set | scene | size | at its size | at 256 |", "|---|---|---|---|---|"]
    for s in data["summary"]:
        lines.append(f"| {s['set']} | {s['scene']} | {s['size']} | {s['excess_ratio']:.2f}x | "
                     f"{s['excess_at_256_ratio']:.2f}x |")
    for which in ("tuning", "held-out"):
        sel = [s for s in data["summary"] if s["set"] == which]
        if sel:
            lines.append("")
            lines.append(f"- {which}: at its own size the excess is {np.median([s['excess_ratio'] for s in sel]):.2f}x "
                         f"the first size's (median), at 256 {np.median([s['excess_at_256_ratio'] for s in sel]):.2f}x.")
    follow = {}
    for r in data["rows"]:
        if r["settings"] != "balanced":
            bal = next(b for b in data["rows"] if b["scene"] == r["scene"] and b["size"] == r["size"]
                       and b["settings"] == "balanced")
            follow.setdefault(r["settings"], []).append(r["excess"] / max(bal["excess"], 1e-12))
    for label, ratios in follow.items():
        lines.append(f"- {label}: excess {np.median(ratios):.2f}x balanced's at the same size (median of "
                     f"{len(ratios)}; range {min(ratios):.2f}-{max(ratios):.2f}x).")
    return "\n".join(lines) + "\n"
