"""`garment-render error-split`: where each preset's error comes from, split against an oracle.

The benchmark gives one number per scene; deciding where a frame's time should go needs to know what
that number is made of. Per scene of the broad catalogue's 256 x 256 subset (every map x the shirt,
the polo and the dress on their bodies, the sheen fabric, front view; held-out maps by default), for
each of `configs()` (the presets, and balanced at the other LIGHT_COUNTS), three renders of the same lights
and PEMs against the reference:

* **(a) the lights alone**: the no-occlusion mode against a reference without occlusion (V = 1 on
  both sides): the median cut, the PEMs and the closed forms;
* **(b) exact visibility**: the full mode with each light's VIS_i from rays towards its region
  (renderer/reference/visibility.py) instead of the shadow maps and the contact search: what perfect
  shadow maps of these lights would give. (b) against the truth is what the light count costs;
* **(c) the renderer's shadow maps**: the frame as it ships. (c) against (b) is what the maps cost.

Errors are relative RMSEs over the object's pixels, each beside its excess over the references' own
noise (sqrt(e^2 - floor^2); the references are cheap, 2 x `spp`); (c) against (b) has no reference and
no floor. Both the light-count and the maps' errors are split by pixel class: **contact** (a surface
point within CONTACT_M of another mesh: the garment over the body), **silhouette** (a covered pixel
with an uncovered 4-neighbour) and **open** (the rest): each class's share of the pixels, its share of
the relMSE and its own rel. RMSE.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from renderer.errors import InvalidInputError
from renderer.presets import frame_settings, pem_settings, preset, presets_digest
from renderer.reference import relative_rmse, relative_squared_errors, render_reference
from renderer.reference.visibility import ExactVisibility
from renderer.renderer import Renderer, ShadingMode

from .catalogue import GARMENTS, LARGE_FABRIC, LARGE_VIEW, MAPS, Scene, environment_cube, split
from .materials import SEEDS, ReferencePair
from .report import machine_info
from .sizes import excess

SIZE = 256
REFERENCE_FACE = 256
# A pixel is "contact" when its surface point lies within this distance of another mesh's vertex.
CONTACT_M = 0.03
CLASSES = ("contact", "silhouette", "open")
# Balanced's settings over these light counts (its own count is balanced itself).
LIGHT_COUNTS = (24, 48, 96, 192)
QUICK_CONFIGS = ("fast", "balanced")


def configs() -> tuple[tuple[str, str, dict], ...]:
    """(label, preset, knobs changed): every preset, and balanced at each other light count."""
    own = preset("balanced")["lights"]
    return (("fast", "fast", {}), ("balanced", "balanced", {}), ("accurate", "accurate", {}),
            *((f"balanced, {n} lights", "balanced", {"lights": n}) for n in LIGHT_COUNTS if n != own))


class _Recording(ExactVisibility):
    """The oracle, keeping the surface points it was given (for the pixel classes)."""

    points: np.ndarray | None = None
    covered: np.ndarray | None = None

    def __call__(self, points, geometric, covered):
        self.points, self.covered = points.copy(), covered.copy()
        return super().__call__(points, geometric, covered)


def pixel_classes(meshes, points_top_down: np.ndarray, mask: np.ndarray) -> dict[str, np.ndarray]:
    """bool (H, W) per class of `CLASSES`, within `mask` and disjoint (contact first, then silhouette)."""
    from scipy.ndimage import binary_erosion
    from scipy.spatial import cKDTree

    trees = [cKDTree(m.positions.astype(np.float64)) for m in meshes]
    p = points_top_down[mask].astype(np.float64)
    d = np.stack([t.query(p)[0] for t in trees])          # (meshes, pixels)
    own = np.argmin(d, axis=0)
    d[own, np.arange(len(own))] = np.inf
    near = d.min(axis=0) < CONTACT_M if len(trees) > 1 else np.zeros(len(p), bool)
    contact = np.zeros(mask.shape, bool)
    contact[mask] = near
    rim = mask & ~binary_erosion(mask, border_value=1) & ~contact
    return {"contact": contact, "silhouette": rim, "open": mask & ~contact & ~rim}


def _by_class(image: np.ndarray, against: np.ndarray, mask: np.ndarray, classes: dict) -> dict:
    per_px = np.zeros(mask.shape)
    per_px[mask] = relative_squared_errors(image, against, mask)
    total = max(float(per_px[mask].sum()), 1e-300)
    return {c: {"pixels": float(m.sum() / max(mask.sum(), 1)), "share": float(per_px[m].sum() / total),
                "rel_rmse": float(np.sqrt(per_px[m].mean())) if m.any() else 0.0} for c, m in classes.items()}


def split_scene(r: Renderer, scene: Scene, configs, spp: int, rays: int, log=print) -> dict:
    meshes, camera, materials = scene.meshes(), scene.camera(), scene.materials()
    t0 = time.perf_counter()
    truth = ReferencePair.render(meshes, materials, environment_cube(scene.map, REFERENCE_FACE), camera, SIZE, spp)
    free_a, free_b = (render_reference(meshes, materials, environment_cube(scene.map, REFERENCE_FACE), camera, SIZE,
                                       SIZE, spp, seed=s, occlusion=False).image for s in SEEDS)
    free = 0.5 * (free_a + free_b)
    free_floor = relative_rmse(free_a, free_b, truth.mask) / 2.0
    ref_s = time.perf_counter() - t0
    gs = r.create_scene(meshes, materials)
    row = {"map": scene.map, "garment": scene.garment, "floor": truth.floor, "free_floor": free_floor,
           "reference_s": ref_s, "configs": {}}
    classes = None
    try:
        for label, name, knobs in configs:
            base = {**preset(name), **knobs}
            cube = environment_cube(scene.map, int(base["face_size"]))
            pems = r.build_pems(cube, pem_settings(base, "sqrt-cosine", None))
            try:
                fs = frame_settings(base, SIZE, SIZE)
                maps = r.render(gs, pems, fs, camera).image
                lights = r.render(gs, pems, frame_settings(base, SIZE, SIZE, mode=ShadingMode.NO_OCCLUSION),
                                  camera).image
                oracle = _Recording(meshes, cube, pems.regions, rays)
                t1 = time.perf_counter()
                exact = r.render(gs, pems, fs, camera, visibility=oracle).image
                oracle_s = time.perf_counter() - t1
                n = pems.regions.n_regions
            finally:
                pems.release()
            if classes is None:
                classes = pixel_classes(meshes, oracle.points[::-1], truth.mask)
            e = {k: relative_rmse(img, truth.image, truth.mask) for k, img in (("maps", maps), ("exact", exact))}
            lights_err = relative_rmse(lights, free, truth.mask)
            got = {"lights": n, "lights_alone": lights_err, "lights_alone_excess": excess(lights_err, free_floor),
                   "exact": e["exact"], "exact_excess": excess(e["exact"], truth.floor),
                   "maps": e["maps"], "maps_excess": excess(e["maps"], truth.floor),
                   "maps_vs_exact": relative_rmse(maps, exact, truth.mask),
                   "exact_classes": _by_class(exact, truth.image, truth.mask, classes),
                   "maps_vs_exact_classes": _by_class(maps, exact, truth.mask, classes),
                   "oracle_s": oracle_s, "oracle_rays": oracle.rays_cast}
            row["configs"][label] = got
            log(f"  {scene.garment:6s} {scene.map:30s} {label:22s} lights alone {lights_err:.3f} | exact visibility "
                f"{e['exact']:.3f} (excess {got['exact_excess']:.3f}) | maps {e['maps']:.3f} (excess "
                f"{got['maps_excess']:.3f}) | maps vs exact {got['maps_vs_exact']:.3f} | floor {truth.floor:.3f}")
    finally:
        gs.release()
    return row


def run(out_dir: Path, which: str = "held-out", spp: int = 64, rays: int = 8, quick: bool = False,
        log=print) -> dict:
    if which not in ("held-out", "tuning"):
        raise InvalidInputError(f"the set must be held-out or tuning, got {which!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    maps = [m for m in MAPS if split()[m] == which]
    garments = GARMENTS
    every = configs()
    if quick:
        maps, garments = maps[:1], GARMENTS[1:2]
        every = tuple(c for c in every if c[0] in QUICK_CONFIGS)
    t_start = time.perf_counter()
    rows = []
    with Renderer() as r:
        for garment in garments:
            for name in maps:
                rows.append(split_scene(r, Scene(name, garment, LARGE_FABRIC, LARGE_VIEW, SIZE), every, spp, rays,
                                        log))
        machine = machine_info(r.gl)
    data = {"machine": machine, "presets_digest": presets_digest(), "set": which, "spp": spp, "rays_per_light": rays, "size": SIZE, "quick": quick,
            "contact_m": CONTACT_M, "configs": {c[0]: {"preset": c[1], "knobs": c[2]} for c in every},
            "wall_s": time.perf_counter() - t_start, "rows": rows, "summary": summary(rows, [c[0] for c in every])}
    (out_dir / "error_split.json").write_text(json.dumps(data, indent=1))
    (out_dir / "error_split.md").write_text(markdown(data))
    figure(data, out_dir / "error_split.png")
    return data


def summary(rows: list[dict], labels: list[str]) -> list[dict]:
    """Per config: medians over the scenes of each part, and the share of scenes where the maps'
    part (maps vs exact) is larger than the light count's (the exact render's excess)."""
    out = []
    for label in labels:
        got = [r["configs"][label] for r in rows if label in r["configs"]]
        if not got:
            continue

        def med(key, g=got):
            return float(np.median([x[key] for x in g]))

        out.append({"config": label, "scenes": len(got), "lights": int(got[0]["lights"]),
                    "lights_alone": med("lights_alone"), "exact": med("exact"), "exact_excess": med("exact_excess"),
                    "maps": med("maps"), "maps_excess": med("maps_excess"), "maps_vs_exact": med("maps_vs_exact"),
                    "maps_dominate": float(np.mean([x["maps_vs_exact"] > x["exact_excess"] for x in got])),
                    "classes": {c: {part: float(np.median([x[key][c]["share"] for x in got]))
                                    for part, key in (("exact", "exact_classes"), ("maps", "maps_vs_exact_classes"))}
                                for c in CLASSES},
                    "class_pixels": {c: float(np.median([x["exact_classes"][c]["pixels"] for x in got]))
                                     for c in CLASSES}})
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Where the error comes from: the light count against the shadow maps", "",
             f"Made by `garment-render error-split` on {m['gl_renderer']}, {m['cores']} cores ({m['date']}): the broad "
             f"catalogue's {data['size']} x {data['size']} scenes on the {data['set']} maps (sheen, front), "
             f"{len(data['rows'])} scenes, against the mean of two references of {data['spp']} spp per technique "
             f"(with and without occlusion); exact visibility from {data['rays_per_light']} rays per light and "
             f"pixel; {data['wall_s'] / 60:.0f} min.", "",
             "Medians over the scenes. *lights alone*: the no-occlusion mode against a reference without "
             "occlusion. *exact*: the same lights and PEMs with each light's visibility from rays (perfect shadow "
             "maps); its excess over the references' noise is what the light count costs. *maps*: the frame as "
             "it ships. *maps vs exact*: what the shadow maps cost (no reference involved). *maps larger*: the "
             "share of scenes where the maps' part exceeds the light count's.", "",
             "| config | lights | lights alone | exact (excess) | maps (excess) | maps vs exact | maps larger |",
             "|---|---|---|---|---|---|---|"]
    for s in data["summary"]:
        lines.append(f"| {s['config']} | {s['lights']} | {s['lights_alone']:.3f} | {s['exact']:.3f} "
                     f"({s['exact_excess']:.3f}) | {s['maps']:.3f} ({s['maps_excess']:.3f}) | "
                     f"{s['maps_vs_exact']:.3f} | {100 * s['maps_dominate']:.0f} % |")
    lines += ["", f"By pixel class (contact: within {100 * data['contact_m']:.0f} cm of another mesh; silhouette: "
              "a covered pixel with an uncovered neighbour; open: the rest): the class's share of the pixels, "
              "then its share of the light count's relMSE (exact against the truth) and of the maps' (maps "
              "against exact), medians over the scenes.", "",
              "| config | " + " | ".join(f"{c}: pixels, light count, maps" for c in CLASSES) + " |",
              "|---|" + "---|" * len(CLASSES)]
    for s in data["summary"]:
        lines.append(f"| {s['config']} | " + " | ".join(
            f"{100 * s['class_pixels'][c]:.0f} %, {100 * s['classes'][c]['exact']:.0f} %, "
            f"{100 * s['classes'][c]['maps']:.0f} %" for c in CLASSES) + " |")
    lines += ["", "Per scene (balanced):", "",
              "| garment | map | floor | lights alone | exact (excess) | maps (excess) | maps vs exact |",
              "|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        b = r["configs"].get("balanced")
        if b:
            lines.append(f"| {r['garment']} | {r['map']} | {r['floor']:.3f} | {b['lights_alone']:.3f} | "
                         f"{b['exact']:.3f} ({b['exact_excess']:.3f}) | {b['maps']:.3f} ({b['maps_excess']:.3f}) | "
                         f"{b['maps_vs_exact']:.3f} |")
    return "\n".join(lines) + "\n"


def figure(data: dict, path: Path) -> None:
    """Light count's part (exact's excess) and the maps' part (maps vs exact) against the light count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweep = [s for s in data["summary"] if s["config"].startswith("balanced")]
    sweep.sort(key=lambda s: s["lights"])
    fig, ax = plt.subplots(figsize=(6, 4))
    x = [s["lights"] for s in sweep]
    ax.plot(x, [s["exact_excess"] for s in sweep], "o-", label="light count (exact visibility, excess)")
    ax.plot(x, [s["maps_vs_exact"] for s in sweep], "s-", label="shadow maps (maps vs exact)")
    ax.plot(x, [s["maps_excess"] for s in sweep], "^--", label="the frame (maps, excess)")
    for s in data["summary"]:
        if s["config"] in ("fast", "accurate"):
            ax.plot([s["lights"]], [s["maps_excess"]], "k*")
            ax.annotate(s["config"], (s["lights"], s["maps_excess"]))
    ax.set_xscale("log", base=2)
    ax.set_xlabel("lights (balanced otherwise)")
    ax.set_ylabel("median rel. RMSE")
    ax.set_title(f"error split, {data['set']} scenes ({len(data['rows'])})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
