"""`garment-render error-split`: where a preset's error against the reference comes from.

The benchmark gives one number per scene; a user deciding which knob to turn needs to know what
that number is made of. Per scene, at one preset:

* **lighting alone**: the renderer without occlusion against a reference without occlusion
  (V = 1): the PEM lookups and lobe calibration, with every shadow term left out on both sides;
* **the worst 1 % of pixels**: their share of the squared relative error (relMSE), and the error
  of the rest, since a few pixels (a shadow edge, a contact shadow) can carry most of it;
* **the worst ten pixels**: their share, and where the worst one is (row, column from the top left),
  since a handful of dark pixels rendered bright can decide the relative RMSE;
* **the silhouette**: the covered pixels with an uncovered neighbour, and their share;

each beside the references' own noise floors (two seeds compared). An image per scene shows the
reference, the render and the per-pixel relative error.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..camera import frame_meshes
from ..errors import InvalidInputError
from ..presets import frame_settings as preset_frame_settings
from ..presets import merge_knobs, pem_settings, presets
from ..reference import mean_flip, relative_rmse, relative_squared_errors, render_reference
from ..renderer import Renderer, ShadingMode
from .run import BALANCED
from .scenes import bundled_scene, shared_scenes

WORST_SHARE = 0.01   # "the worst 1 % of pixels"
WORST_PIXELS = 10    # "the worst ten pixels"


def _silhouette(mask: np.ndarray) -> np.ndarray:
    """Covered pixels with an uncovered 4-neighbour (the image border counts as uncovered)."""
    m = np.pad(mask, 1, constant_values=False)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    return mask & ~inner


def split_scene(r: Renderer, bs, knobs: dict, size: int, spp: int, log=print) -> tuple[dict, dict]:
    """The split of one scene's error; returns (row, images for the figure)."""
    camera = frame_meshes(bs.meshes, 1.0)
    cube = bs.cube(2 * BALANCED["face_size"])     # the benchmark's reference cube
    t0 = time.perf_counter()
    refs = [render_reference(bs.meshes, bs.materials, cube, camera, size, size, spp, seed=s, occlusion=occ).image
            for occ, s in ((True, 1), (True, 2), (False, 3), (False, 4))]
    ref_s = time.perf_counter() - t0
    truth, free = 0.5 * (refs[0] + refs[1]), 0.5 * (refs[2] + refs[3])
    mask = truth[..., 3] > 0.5
    pem = pem_settings(knobs, "sqrt-cosine", None, bs.materials)
    pems = r.build_pems(bs.cube(int(knobs["face_size"])), pem)
    scene = r.create_scene(bs.meshes, bs.materials)
    try:
        full = r.render(scene, pems, preset_frame_settings(knobs, size, size), camera).image
        unoccluded = r.render(scene, pems, preset_frame_settings(knobs, size, size, mode=ShadingMode.NO_OCCLUSION),
                              camera).image
    finally:
        scene.release()
        pems.release()
    per_px = relative_squared_errors(full, truth, mask)
    if per_px.size < 2 or per_px.sum() <= 0:
        raise InvalidInputError(f"{bs.name}: {per_px.size} covered pixels and a total error of "
                                f"{per_px.sum():.3g}: nothing to split (a larger --size?)")
    ranked = np.argsort(per_px)[::-1]
    order = per_px[ranked]
    worst_row, worst_col = (int(v[ranked[0]]) for v in np.nonzero(mask))   # per_px is in the mask's row-major order
    n_worst = max(1, int(round(WORST_SHARE * len(order))))
    rim = _silhouette(mask)[mask]
    # The noise floors: one seed against the other is sqrt(2) x one image's noise; the averaged
    # references used here carry 1/sqrt(2) of one image's, so half of the pair's difference.
    row = {
        "scene": bs.name, "env": bs.env_name, "pixels": int(mask.sum()),
        "rel_rmse": float(np.sqrt(per_px.mean())), "flip": mean_flip(full, truth, mask),
        "noise_rel_rmse": relative_rmse(refs[1], refs[0], mask) / 2.0,
        "lighting_rel_rmse": relative_rmse(unoccluded, free, mask),
        "lighting_flip": mean_flip(unoccluded, free, mask),
        "lighting_noise_rel_rmse": relative_rmse(refs[3], refs[2], mask) / 2.0,
        "worst_share": float(order[:n_worst].sum() / order.sum()),
        "rel_rmse_without_worst": float(np.sqrt(order[n_worst:].mean())),
        "worst_pixels_share": float(order[:WORST_PIXELS].sum() / order.sum()),
        "worst_pixel": [worst_row, worst_col],
        "silhouette_pixels": float(rim.mean()), "silhouette_share": float(per_px[rim].sum() / per_px.sum()),
        "reference_s": ref_s,
    }
    err = np.zeros(mask.shape)
    err[mask] = np.sqrt(per_px)
    log(f"  {bs.name}: rel. RMSE {row['rel_rmse']:.3f} (noise {row['noise_rel_rmse']:.3f}); lighting alone "
        f"{row['lighting_rel_rmse']:.3f} (noise {row['lighting_noise_rel_rmse']:.3f}); worst 1 % of pixels "
        f"{100 * row['worst_share']:.0f} % of relMSE, the rest {row['rel_rmse_without_worst']:.3f}; worst "
        f"{WORST_PIXELS} pixels {100 * row['worst_pixels_share']:.0f} % (the worst at {tuple(row['worst_pixel'])}); silhouette "
        f"{100 * row['silhouette_pixels']:.0f} % of pixels, {100 * row['silhouette_share']:.0f} % of relMSE")
    return row, {"reference": truth, "render": full, "error": err, "mask": mask}


def run_split(out: Path, preset: str = "balanced", size: int = 128, spp: int = 512, shared: bool = True,
              log=print) -> dict:
    table, source = presets()
    knobs = merge_knobs(table[preset], {})
    scenes = [bundled_scene()] + (shared_scenes() if shared else [])
    out.mkdir(parents=True, exist_ok=True)
    rows, images = [], []
    with Renderer() as r:
        for bs in scenes:
            row, img = split_scene(r, bs, knobs, size, spp, log)
            rows.append(row)
            images.append((bs.name, img))
    result = {"preset": preset, "presets": source, "knobs": knobs, "size": size, "spp": spp, "rows": rows}
    (out / "split.json").write_text(json.dumps(result, indent=1, default=float))
    (out / "split.md").write_text(markdown(result) + "\n")
    _figure(out / "split.png", images)
    return result


def markdown(result: dict) -> str:
    lines = [f"Preset {result['preset']} at {result['size']}x{result['size']}, references 2 x {result['spp']} spp "
             "per term (with and without occlusion), noise floors of their averages in brackets.", "",
             "| scene | rel. RMSE | FLIP | lighting alone (no occlusion) | worst 1 % of pixels: share of relMSE | "
             f"rel. RMSE of the other 99 % | worst {WORST_PIXELS} pixels: share (worst at row, column) | "
             "silhouette: pixels, share of relMSE |",
             "|---|---|---|---|---|---|---|---|"]
    for w in result["rows"]:
        lines.append(f"| {w['scene']} | {w['rel_rmse']:.3f} ({w['noise_rel_rmse']:.3f}) | {w['flip']:.3f} | "
                     f"{w['lighting_rel_rmse']:.3f} ({w['lighting_noise_rel_rmse']:.3f}) | "
                     f"{100 * w['worst_share']:.0f} % | {w['rel_rmse_without_worst']:.3f} | "
                     f"{100 * w['worst_pixels_share']:.0f} % ({w['worst_pixel'][0]}, {w['worst_pixel'][1]}) | "
                     f"{100 * w['silhouette_pixels']:.0f} %, {100 * w['silhouette_share']:.0f} % |")
    return "\n".join(lines)


def _figure(path: Path, images: list) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..shading.tonemap import ToneCurve, auto_exposure_ev, tonemap

    fig, axes = plt.subplots(len(images), 3, figsize=(9, 3 * len(images)), squeeze=False)
    for ax_row, (name, img) in zip(axes, images):
        ev = auto_exposure_ev(img["reference"][..., :3], img["reference"][..., 3])
        for ax, key in zip(ax_row[:2], ("reference", "render")):
            ax.imshow(tonemap(img[key][..., :3], ev, ToneCurve.FILMIC))
            ax.set_title(f"{name}: {key}", fontsize=8)
        shown = ax_row[2].imshow(np.where(img["mask"], img["error"], np.nan), cmap="magma", vmin=0.0, vmax=1.0)
        ax_row[2].set_title("relative error per pixel", fontsize=8)
        fig.colorbar(shown, ax=ax_row[2], fraction=0.046)
        for ax in ax_row:
            ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
