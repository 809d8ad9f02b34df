"""`garment-render bench --broad`: the presets' accuracy on light and garments they were not chosen on.

Scenes: every shared environment map x three garments on a body or form (the newton shirt's last
simulated frame on its dress form, DiffAvatar's polo and draped dress on GarmentCode's mean body) x
three fabrics (matte cotton, a mid sheen, satin) x two views (front, three-quarter), at 128 x 128;
one fabric and view of each map and garment again at 256 x 256, where the targets are judged, and
those of the held-out maps at 512 x 512 (`bench_scenes`, `--size 512`), where the equal-error targets
are judged again.

The split is fixed by a rule in the code, not chosen after looking (`split`): the four maps the presets
and constants were tuned on before this benchmark existed (`scenes.TARGET_PROBES`) are in the tuning
set, with the first four of the other maps in the order of the SHA-256 of their file names; the other
nine maps are held out. Only the tuning set may be looked at when a preset or constant is chosen; the
held-out set is reported on its own.

Per scene the truth is the mean of two independent reference renders; their difference is the noise
floor, and the artefact share (`reference.metrics`) judges only the pixels where they agree. The truth
is off by half the floor itself (the mean of two renders, each off by the floor / sqrt(2)), and that
noise adds to a setting's error in quadrature: a row's rel. RMSE is the excess over it,
sqrt(e^2 - (floor / 2)^2), e the error against the truth (`excess_rel_rmse`; e itself is kept in
the row's `extra`). So the references can be cheap: at 256 x 256 two of 256 samples each (floor about
0.06 rel. RMSE) measure the presets' errors without their noise, and the held-out set runs from a cold
cache in under twenty minutes on two cores (the run records each set's wall time, its references
included, and how many of its references it rendered). FLIP and the artefact share are read against
the truth as it is (noisier references judge fewer pixels: the share judged is in each row).
References are cached on disk (`ReferenceCache`), keyed by the scene's inputs, their samples, seed and
pixel samples and by the source of the code that renders them: a rerun renders only what changed.

Edges: the references integrate each pixel's area over `BroadConfig.pixel_samples`^2 jittered strata
(`reference.strata`; 4 x 4 by default): their alpha is the covered share of the pixel, their foreground
the premultiplied radiance over black, and their edge mask the pixels whose strata do not all see one
surface. The object's metrics above (rel. RMSE, FLIP, the artefact share, the mean ratio) are read on the
pixels both references cover wholly, the background's on those neither covers at all (with one stratum,
the pixels of alpha 1 and 0 as before). At the edges each setting renders one more frame, untimed, over a
black background: its silhouette error (`reference.metrics.silhouette_error`) is the rel. RMSE of that
frame against the pair's mean foreground over the union of their edge masks, the excess over half the
pair's own (as the rows' rel. RMSE), and the RMSE of its alpha there (the coverage error, likewise). The
window share (`reference.metrics.window_share`) counts the 5 x 5 windows wholly inside the object whose
mean luminance is off by more than 1.5x either way, where the two references agree: a band or a blotch
the per-pixel share's 2x misses. Runs made before these columns existed report without them.

Equal error is estimated, not laddered (a ladder per scene would cost more than the whole sweep): the
reference is unbiased, so its relMSE falls as 1/spp; from the pair's floor (one render against the
other: sqrt(2) x each one's error) the samples that reach the preset's error follow, and their time
at the tracer's rate measured beside the presets' frames, scene by scene in the same run (two short
renders in a process of one thread, `_tracer_rate`: the cached references' own times were taken on
another day), the tracer on every core (its samples split evenly over them: the ideal split, which
favours the tracer; its rate is measured at one stratum a pixel, where a stratified pixel costs the same
shadow rays for the same samples). A preset within twice the truth's own error is unresolved. `retime`
measures a stored run's times again on another day or machine, the tracer's beside the presets'.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import io
import json
import os
import time
from dataclasses import asdict, dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np

import renderer
from renderer.atomic import atomic_file
from renderer.mesh import FALLBACK_NORMAL, vertex_normals
from renderer.presets import PRESET_NAMES as PRESETS  # every preset, paper's included (targets: TARGETS)
from renderer.reference import (
    artefact_share,
    mean_flip,
    relative_rmse,
    render_reference,
    silhouette_error,
    window_share,
)
from renderer.reference.metrics import FULL_COVERAGE
from renderer.shading.background import background_truth

from .catalogue import (
    EQUAL_ERROR_TARGETS,
    REFERENCE_FACE_SIZE,
    TARGETS,
    Scene,
    garment_meshes,
    scenes,
    split,
)
from .processes import one_thread_pool
from .report import machine_info
from .scenes import shared_assets

# --- references, cached -------------------------------------------------------------------------

# The source of what turns a scene's inputs into a reference image. What the environment and mesh code
# make of the files enters the key as data instead (`reference_inputs_digest`): the cube the tracer
# reads and the meshes with the normals it shades with, so that code can be made faster without
# rendering every reference anew, and any change to what it produces still does.
# Each source by its name in the hash and where it lives (a folder: its .py files, named below it): the
# names enter the hash, not the places (the lab's two kept the names they had in the product's package).
# A change that moves code without changing what a reference is (a file's imports) changes the digest
# all the same: scripts/fill_reference_cache.py --rekey-from OLD_DIGEST renames the cached references.
_PRODUCT = Path(renderer.__file__).resolve().parent
_LAB = Path(__file__).resolve().parent
_REFERENCE_SOURCES = {**{name: _PRODUCT / name for name in ("reference", "envmap/cube.py", "camera.py",
                                                            "shading/material.py", "shading/brdf.py")},
                      "bench/catalogue.py": _LAB / "catalogue.py", "bench/scenes.py": _LAB / "scenes.py"}
CACHE_VARIABLE = "GARMENT_RENDER_REFERENCE_CACHE"


def reference_code_digest() -> str:
    """SHA-256 of the source of everything that makes a reference image from a scene's inputs."""
    h = hashlib.sha256()
    for name, p in _REFERENCE_SOURCES.items():
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            named = f"{name}/{f.relative_to(p).as_posix()}" if p.is_dir() else name
            h.update(named.encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def _arrays_digest(*arrays: np.ndarray | None) -> str:
    h = hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
    return h.hexdigest()


def _reference_cube(map_name: str) -> np.ndarray:
    """`environment_cube`'s cube of a map at the references' face size, kept in the user's cache folder
    between runs (renderer/user_cache.py: the same array, its entry named by the resampling code)."""
    from renderer.envmap import environment_from_array, read_hdr_image
    from renderer.user_cache import user_cache_dir

    path = shared_assets() / "hdri" / map_name
    return environment_from_array(read_hdr_image(path), "auto", REFERENCE_FACE_SIZE, name=path.stem, repair=True,
                                  cube_cache=user_cache_dir("cubes")).cube


@cache
def _cube_digest(map_name: str) -> str:
    return _arrays_digest(_reference_cube(map_name))


@cache
def _garment_digest(garment: str) -> str:
    return _arrays_digest(*(a for m in garment_meshes(garment)
                            for a in (m.positions, m.faces, m.uvs, vertex_normals(m.positions, m.faces))))


def reference_inputs_digest(scene: Scene) -> str:
    """What a reference of `scene` is made from, as data: the cube the tracer samples, the meshes and
    their normals (and the normal it gives a point whose own is degenerate), the materials and the camera."""
    spec = {"cube": _cube_digest(scene.map), "meshes": _garment_digest(scene.garment),
            "fallback_normal": list(FALLBACK_NORMAL), "materials": [asdict(m) for m in scene.materials()],
            "camera": asdict(scene.camera()), "size": scene.size}
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()


def default_cache_dir() -> Path:
    if os.environ.get(CACHE_VARIABLE):
        return Path(os.environ[CACHE_VARIABLE])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "garment-render" / "references"


class ReferenceCache:
    """Reference renders on disk, one .npz per (scene, samples, seed, pixel samples, reference code); a
    cache holds the references of one pixel_samples (k x k strata a pixel)."""

    def __init__(self, folder: Path, *, pixel_samples: int):
        self.folder = Path(folder)
        self.code = reference_code_digest()
        self.pixel_samples = int(pixel_samples)

    def key(self, scene: Scene, spp: int, seed: int, code: str | None = None) -> str:
        """The entry's name: the scene's inputs, the samples, the seed, the strata and the reference's
        code digest (`code`; default today's)."""
        spec = {"inputs": reference_inputs_digest(scene), "spp": spp, "seed": seed, "code": code or self.code,
                "pixel_samples": self.pixel_samples}
        return hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()[:32]

    def path(self, scene: Scene, spp: int, seed: int) -> Path:
        return self.folder / f"{self.key(scene, spp, seed)}.npz"

    def rekey(self, scenes: list[Scene], spp_of, old_code: str) -> int:
        """The references of `scenes` made under the code digest `old_code` renamed to today's, for a
        change that moved the reference's code without changing what it computes (say so in its commit);
        returns how many. Entries today's code already has are left as they are."""
        moved = 0
        for scene in scenes:
            for seed in SEEDS:
                old = self.folder / f"{self.key(scene, spp_of(scene), seed, old_code)}.npz"
                new = self.path(scene, spp_of(scene), seed)
                if old.exists() and not new.exists():
                    old.rename(new)
                    moved += 1
        return moved

    def get(self, scene: Scene, spp: int, seed: int) -> dict | None:
        """{"image", "foreground": (H, W, 4) float32, "edge": (H, W) bool, "spp": samples a pixel taken,
        "wall_s"} (`ReferenceFrame`'s), or None."""
        p = self.path(scene, spp, seed)
        if not p.exists():
            return None
        try:
            with np.load(p) as z:
                return {"image": z["image"], "foreground": z["foreground"], "edge": z["edge"].astype(bool),
                        "spp": int(z["spp"]), "wall_s": float(z["wall_s"])}
        except Exception:   # a damaged file is rendered again, never trusted
            return None

    def put(self, scene: Scene, spp: int, seed: int, ref: dict, wall_s: float) -> None:
        """ref: `_reference_job`'s arrays (image, foreground, edge, spp)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez_compressed(buf, image=ref["image"].astype(np.float32), foreground=ref["foreground"].astype(np.float32),
                            edge=ref["edge"].astype(bool), spp=np.int64(ref["spp"]), wall_s=np.float64(wall_s))
        with atomic_file(self.path(scene, spp, seed)) as f:
            f.write(buf.getvalue())


def _reference_job(scene: Scene, spp: int, seed: int, pixel_samples: int = 1) -> tuple[dict, float]:
    """One reference render in a worker process: ({"image", "foreground", "edge", "spp"}, wall seconds)."""
    cube = _reference_cube(scene.map)
    t0 = time.perf_counter()
    ref = render_reference(scene.meshes(), scene.materials(), cube, scene.camera(), scene.size, scene.size, spp,
                           seed=seed, pixel_samples=pixel_samples)
    return ({"image": np.array(ref.image), "foreground": np.array(ref.foreground), "edge": np.array(ref.edge),
             "spp": ref.spp}, time.perf_counter() - t0)


SEEDS = (1, 2)


def ensure_references(todo: list[Scene], spp_of, cache: ReferenceCache, workers: int, log=print) -> int:
    """Render the missing references of `todo` (both seeds), `workers` processes of one thread each;
    how many it rendered."""
    missing = [(s, spp_of(s), seed) for s in todo for seed in SEEDS if cache.get(s, spp_of(s), seed) is None]
    if not missing:
        return 0
    log(f"rendering {len(missing)} references ({len(todo) * len(SEEDS) - len(missing)} cached) in {workers} processes")
    t0 = time.perf_counter()
    with one_thread_pool(workers) as pool:
        jobs = {pool.submit(_reference_job, s, spp, seed, cache.pixel_samples): (s, spp, seed)
                for s, spp, seed in missing}
        for k, job in enumerate(cf.as_completed(jobs), 1):
            s, spp, seed = jobs[job]
            ref, wall = job.result()
            cache.put(s, spp, seed, ref, wall)
            if k % 10 == 0 or k == len(jobs):
                log(f"  {k}/{len(jobs)} references, {time.perf_counter() - t0:.0f} s")
    return len(missing)


# --- the fast method ------------------------------------------------------------------------------

@dataclass
class BroadRow:
    scene: str
    map: str
    set: str
    garment: str
    fabric: str
    view: str
    size: int
    preset: str
    frame_ms: float
    rel_rmse: float
    flip: float
    artefact_share: float
    artefact_judged: float
    too_bright: int
    too_dark: int
    mean_ratio: float          # the object's mean luminance against the truth's
    background_rel_rmse: float
    ref_noise_rel_rmse: float
    ref_noise_flip: float
    ref_spp: int
    ref_ms_per_spp: float     # the tracer's time per sample on one thread
    equal_error_speedup: float | None   # None: unresolved (within twice the truth's own error)
    extra: dict = field(default_factory=dict)
    # At the references' edge pixels (module doc); None in runs made before them.
    silhouette_rel_rmse: float | None = None   # the frame over black against the truth's foreground (excess)
    coverage_rmse: float | None = None          # its alpha against the truth's (excess)
    window_share: float | None = None           # 5 x 5 windows off by more than 1.5x, of those judged


def _luminance_mean(img: np.ndarray, mask: np.ndarray) -> float:
    from renderer.reference.metrics import LUMINANCE_RGB

    return float((img[..., :3][mask].astype(np.float64) @ LUMINANCE_RGB).mean())


@dataclass(frozen=True)
class Truth:
    """A scene's truth, made once for all its rows: the mean of the reference pair, their floor
    (one against the other), the reference's time per sample, and the background's truth; at the
    edges the pair's mean foreground, the union of their edge masks and their floors there."""

    a: np.ndarray
    b: np.ndarray
    image: np.ndarray
    mask: np.ndarray         # covered wholly by both references: the object's metrics
    floor_rel_rmse: float
    floor_flip: float
    ms_per_spp: float
    background: np.ndarray
    setup_ms: float   # the tracer's time before its first sample
    empty: np.ndarray        # covered by neither at all: the background's metric
    foreground: np.ndarray   # the pair's mean foreground (premultiplied over black)
    edge: np.ndarray
    floor_silhouette: float  # the pair's silhouette error, one against the other
    floor_coverage: float
    spp: int                 # samples a pixel each reference took

    @classmethod
    def of(cls, ref_a: dict, ref_b: dict, background: np.ndarray, rate: tuple[float, float]) -> Truth:
        """ref_a, ref_b: `ReferenceCache.get`'s; rate: the tracer's (setup ms, ms a sample) measured in
        this run (`_tracer_rate`)."""
        a, b = ref_a["image"], ref_b["image"]
        mask = (a[..., 3] >= FULL_COVERAGE) & (b[..., 3] >= FULL_COVERAGE)
        empty = (a[..., 3] <= 0) & (b[..., 3] <= 0)
        edge = ref_a["edge"] | ref_b["edge"]
        pair = silhouette_error(ref_b["foreground"], ref_a["foreground"], edge)
        setup, per = rate
        return cls(a, b, 0.5 * (a + b), mask, relative_rmse(b, a, mask), mean_flip(b, a, mask), per, background,
                   setup, empty, 0.5 * (ref_a["foreground"] + ref_b["foreground"]), edge, pair.rel_rmse,
                   pair.coverage_rmse, ref_a["spp"])


def excess_rel_rmse(error: float, floor: float) -> float:
    """A setting's rel. RMSE against the noise-free truth, from its error against the mean of the
    reference pair: that mean is off by half the pair's floor, independently of the setting, so the
    two add in quadrature (0 where the error is within the truth's own noise)."""
    return float(np.sqrt(max(error * error - 0.25 * floor * floor, 0.0)))


def measure(scene: Scene, preset: str, image: np.ndarray, frame_ms: float, truth: Truth, spp: int,
            sets: dict, black: np.ndarray | None = None) -> BroadRow:
    """One setting's row against the scene's truth; `black`: its frame over a black background, for
    the silhouette error (none without)."""
    mask, floor = truth.mask, truth.floor_rel_rmse
    measured = relative_rmse(image, truth.image, mask)
    err = excess_rel_rmse(measured, floor)
    art = artefact_share(image, truth.a, truth.b, mask)
    background = truth.empty
    bg_err = relative_rmse(image[..., :3], truth.background, background) if background.any() else float("nan")
    # Equal error (module doc): one render of spp samples is off by floor / sqrt(2); the truth, the
    # mean of two, by half the floor.
    speedup = None
    if measured > floor:   # twice the truth's own error
        # The tracer on every core: its samples split evenly (its rate is one thread's, setup included).
        speedup = tracer_time_ms(spp_at_error(err, floor, spp), truth.setup_ms, truth.ms_per_spp,
                                 len(os.sched_getaffinity(0))) / frame_ms
    row = BroadRow(scene.name, scene.map, sets[scene.map], scene.garment, scene.fabric, scene.view, scene.size, preset,
                   frame_ms, err, mean_flip(image, truth.image, mask), art.share, art.judged, art.too_bright,
                   art.too_dark, _luminance_mean(image, mask) / max(_luminance_mean(truth.image, mask), 1e-30), bg_err,
                   floor, truth.floor_flip, spp, truth.ms_per_spp, speedup, {"rel_rmse_measured": measured})
    windows = window_share(image, truth.a, truth.b, mask)
    row.window_share = windows.share
    row.extra.update(window_judged=windows.judged, windows_too_bright=windows.too_bright,
                     windows_too_dark=windows.too_dark)
    if black is not None:
        sil = silhouette_error(black, truth.foreground, truth.edge)
        row.silhouette_rel_rmse = excess_rel_rmse(sil.rel_rmse, truth.floor_silhouette)
        row.coverage_rmse = excess_rel_rmse(sil.coverage_rmse, truth.floor_coverage)
        row.extra.update(silhouette_measured=sil.rel_rmse, silhouette_floor=truth.floor_silhouette,
                         coverage_measured=sil.coverage_rmse, coverage_floor=truth.floor_coverage,
                         edge_pixels=sil.pixels)
    return row


# A preset with one knob changed ("PRESET:KNOB=VALUE", a row of its own), on the 256 x 256 scenes of
# both sets (the sheen fabric) and the held-out 128 x 128 scenes of KNOB_SMALL_FABRIC (satin, whose
# narrow lobe reads the PEMs where the sheen's terms are all in closed form): what each knob costs and
# buys against its preset on the scenes the presets are chosen on and away from them (the report's
# knob table; a knob that does not pay goes). Balanced's knobs, and fast's light count: fast holds
# fewer lights than balanced for its frame budget (renderer/presets/fast.toml), and these rows show
# what more of them cost and buy on the held-out scenes. A variant may change several knobs where
# one trade is weighed against another: the maps' size with the contact search's reach kept in the
# scene, and balanced as it was before its lights were bought with cheaper maps.
KNOB_SMALL_FABRIC = "satin"
# The contact search's reach in texels of 256^2 main maps (balanced's 36 of 384^2): a variant of the
# maps' side keeps the reach in the scene.
CONTACT_TEXELS_AT_256 = 24.0


def maps_of_side(side: int) -> dict:
    """Main maps of `side`^2 with the contact search's reach kept in the scene (its texels follow the side)."""
    return {"shadow_size": side, "contact_shadow_texels": CONTACT_TEXELS_AT_256 * side / 256}


KNOB_VARIANTS = {
    # The light count either side of balanced's 56.
    "balanced:lights=48": {"lights": 48},
    "balanced:lights=64": {"lights": 64},
    # Its maps' size either side, the contact search's reach kept in the scene (48 texels of 512^2).
    "balanced:shadow_size=256,contact_shadow_texels=24": maps_of_side(256),
    "balanced:shadow_size=512,contact_shadow_texels=48": maps_of_side(512),
    # Its casters' proxy either side of a half.
    "balanced:caster_detail=0.25": {"caster_detail": 0.25},
    "balanced:caster_detail=1": {"caster_detail": 1.0},
    # The preset before the shadow pass drew front faces alone.
    "balanced:lights=40,caster_detail=0.25": {"lights": 40, "caster_detail": 0.25},
    # Chebyshev's variance floor: the preset before.
    "balanced:min_sigma_texels=3": {"min_sigma_texels": 3.0},
    # Auto's area lights where a map has them (the preset before), against the paper's median cut.
    "balanced:lights_from=auto": {"lights_from": "auto"},
    "balanced:sub_lights=1": {"sub_lights": 1},
    "balanced:small_light_scale=1": {"small_light_scale": 1},
    "balanced:contact_shadow_texels=0": {"contact_shadow_texels": 0.0},
    "balanced:whole_sources=off": {"whole_sources": False},
    # Fast's light count either side of its 28, and the preset before (20 lights, 128^2 maps, a tenth of
    # the casters).
    "fast:lights=24": {"lights": 24},
    "fast:lights=32": {"lights": 32},
    "fast:lights=20,caster_detail=0.1,shadow_size=128,contact_shadow_texels=12":
        {"lights": 20, "caster_detail": 0.1, **maps_of_side(128)},
    # Accurate's light count either side of its 160, and its casters at half (the preset before).
    "accurate:lights=128": {"lights": 128},
    "accurate:lights=192": {"lights": 192},
    "accurate:caster_detail=0.5": {"caster_detail": 0.5},
}


def knob_base(variant: str) -> str:
    """The preset a knob variant's row changes ("fast" of "fast:lights=24")."""
    return variant.split(":", 1)[0]


class MapResources:
    """One map's GPU objects for the scenes that use it (the scenes come map by map): its PEM sets per
    setting, its background map, and its source image (for the background's truth)."""

    def __init__(self, r, name: str):
        from renderer.envmap import read_hdr_image
        from renderer.envmap.layouts import detect_layout
        from renderer.shading.background import background_source

        self.r, self.name = r, name
        self.raw = read_hdr_image(shared_assets() / "hdri" / name)   # cubes from it, repaired as the reference's
        self.image = np.maximum(np.nan_to_num(self.raw), 0.0)          # the background's truth
        self.layout = detect_layout(*self.image.shape[:2])
        self.pems: dict = {}
        self.background = r.background_map(background_source(self.raw, self.layout, repair=True, name=name))

    def pem_set(self, knobs: dict, materials):
        from renderer import presets as presets_mod
        from renderer.envmap import environment_from_array

        pem = presets_mod.pem_settings(knobs, knobs["filter"], None, materials)
        key = (knobs["face_size"], pem.key())
        if key not in self.pems:
            env = environment_from_array(self.raw, self.layout, int(knobs["face_size"]), name=self.name, repair=True)
            self.pems[key] = self.r.build_pems(env.cube, pem)
        return self.pems[key]

    def release(self) -> None:
        for p in self.pems.values():
            p.release()
        self.background.release()


def render_presets(r, scene: Scene, knobs_of: dict, frames: int, res: MapResources,
                   black: bool = False) -> dict[str, tuple[np.ndarray, float, np.ndarray | None]]:
    """Each setting's image of the scene (`knobs_of`: name -> knobs), its median frame time (after
    one warm-up frame) and, with `black`, one more frame over a black background (untimed; else None)."""
    from renderer import presets as presets_mod
    from renderer.renderer import Background

    meshes, materials = scene.meshes(), scene.materials()
    gl_scene = r.create_scene(meshes, materials)
    out = {}
    try:
        for preset, knobs in knobs_of.items():
            pems = res.pem_set(knobs, materials)
            fs = presets_mod.frame_settings(knobs, scene.size, scene.size)
            cam = scene.camera()
            r.render(gl_scene, pems, fs, cam, background=res.background)
            timed = [r.render(gl_scene, pems, fs, cam, background=res.background) for _ in range(frames)]
            over_black = (np.array(r.render(gl_scene, pems, replace(fs, background=Background.BLACK), cam).image)
                          if black else None)
            out[preset] = (np.array(timed[-1].image), float(np.median([f.timings["frame_wall_ms"] for f in timed])),
                           over_black)
    finally:
        gl_scene.release()
    return out


@dataclass
class BroadConfig:
    quick: bool = False
    frames: int = 5                  # timed frames per preset from 256 x 256 up, where speed is judged (after one warm-up)
    frames_small: int = 1            # ... at 128 x 128 (accuracy only)
    spp_small: int = 512             # samples per technique of each reference at 128 x 128
    spp_large: int = 256             # ... at 256 x 256 (the rows' error is the excess over the truth's noise)
    pixel_samples: int = 4           # the references' k x k strata a pixel (module doc: edges)
    knobs: bool = True               # each of KNOB_VARIANTS on the 256 x 256 scenes too
    sizes: tuple = (128, 256)        # which of the sweep's image sizes to run
    workers: int | None = None       # reference processes (default: one per core)
    cache: str | None = None         # reference cache folder (default: default_cache_dir())

    @classmethod
    def quick_config(cls) -> BroadConfig:
        return cls(quick=True, frames=2, frames_small=2, spp_small=256, spp_large=512)

    def spp_of(self, scene: Scene) -> int:
        return self.spp_small if scene.size <= 128 else self.spp_large


# The held-out scenes at 512 x 512 as well (`--size 512`): the 256 x 256 scenes' maps, garments,
# fabric and view, where the equal-error targets are judged again (the frame budgets are 256 x 256's).
# Made here rather than in the catalogue, whose source keys every reference.
LARGEST = 512


def bench_scenes(quick: bool = False) -> list[Scene]:
    """The catalogue's scenes and, but for a quick run, the held-out 256 x 256 ones at LARGEST."""
    out = scenes(quick)
    if quick:
        return out
    sets = split()
    return out + [replace(s, size=LARGEST) for s in out if s.size == 256 and sets[s.map] == "held-out"]


def run_broad(out_dir: Path, cfg: BroadConfig, log=print, only: list[Scene] | None = None) -> list[BroadRow]:
    from renderer import presets as presets_mod
    from renderer.gpu.context import GLContext
    from renderer.renderer import Renderer

    out_dir.mkdir(parents=True, exist_ok=True)
    todo = only if only is not None else [s for s in bench_scenes(cfg.quick) if s.size in cfg.sizes]
    if not todo:
        raise ValueError(f"no scene of the broad benchmark at {' or '.join(map(str, cfg.sizes))} px"
                         + (" in a quick run (its scenes are 128 x 128)" if cfg.quick else ""))
    if not (shared_assets() / "hdri").is_dir():
        raise FileNotFoundError(f"the broad benchmark needs the shared assets ({shared_assets()})")
    cache = ReferenceCache(Path(cfg.cache) if cfg.cache else default_cache_dir(), pixel_samples=cfg.pixel_samples)
    workers = max(1, cfg.workers or len(os.sched_getaffinity(0)))
    in_use, source = presets_mod.presets()
    knobs_of = setting_knobs(in_use)
    sets = split()
    rows: list[BroadRow] = []
    gl = GLContext()
    machine = machine_info(gl)
    res: MapResources | None = None
    # The held-out set first, whole (its references, then its scenes), then the tuning set: each set's
    # wall time from a cold cache is the run's own measurement (`sets_timed`).
    ref_s, set_wall_s, set_refs, k = 0.0, {}, {}, 0
    rates: dict[str, tuple[float, float]] = {}   # the tracer's (setup ms, ms a sample) per scene
    with Renderer(gl) as r, one_thread_pool(1) as tracer:
        for part in ("held-out", "tuning"):
            mine = sorted((s for s in todo if sets[s.map] == part), key=lambda s: (s.map, s.garment, s.size))
            if not mine:
                continue
            t0 = time.perf_counter()
            set_refs[part] = {"rendered": ensure_references(mine, cfg.spp_of, cache, workers, log),
                              "in_all": len(mine) * len(SEEDS)}
            ref_s += time.perf_counter() - t0
            for scene in mine:
                k += 1
                spp = cfg.spp_of(scene)
                ref_a, ref_b = (cache.get(scene, spp, seed) for seed in SEEDS)
                if res is None or res.name != scene.map:
                    if res is not None:
                        res.release()
                    res = MapResources(r, scene.map)
                knob_scene = cfg.knobs and (scene.size > 128 or (part == "held-out" and scene.fabric == KNOB_SMALL_FABRIC))
                settings = {p: kn for p, kn in knobs_of.items() if knob_scene or ":" not in p}
                images = render_presets(r, scene, settings, cfg.frames if scene.size > 128 else cfg.frames_small, res,
                                        black=True)
                setup, per = rates[scene.name] = _tracer_rate(scene, tracer)   # beside the presets' frames
                truth = Truth.of(ref_a, ref_b,
                                 background_truth(res.image, res.layout, scene.camera(), scene.size, scene.size),
                                 (setup, per))
                for preset, (image, ms, black) in images.items():
                    rows.append(measure(scene, preset, image, ms, truth, truth.spp, sets, black))
                b = next(x for x in rows[-len(images):] if x.preset == "balanced")
                log(f"[{k}/{len(todo)}] {scene.name} ({part}): balanced rel. RMSE {b.rel_rmse:.3f}, FLIP {b.flip:.3f}, "
                    f"artefacts {100 * b.artefact_share:.2f} %, silhouette {b.silhouette_rel_rmse:.3f}, "
                    f"{b.frame_ms:.0f} ms; floor {b.ref_noise_rel_rmse:.3f}")
                if k % 20 == 0:
                    write(out_dir, rows, machine, cfg, source, ref_s, tracer=_rates_json(rates))
            set_wall_s[part] = time.perf_counter() - t0
        if res is not None:
            res.release()
    gl.release()
    write(out_dir, rows, machine, cfg, source, ref_s, {"wall_s": set_wall_s, "references": set_refs},
          _rates_json(rates))
    return rows


# --- the report -------------------------------------------------------------------------------------

def summary(rows: list[BroadRow]) -> dict:
    """Per set, size and preset: medians and worst values, and the worst scene."""
    out = {}
    for key in sorted({(r.set, r.size, r.preset) for r in rows if r.preset in PRESETS}):
        sel = [r for r in rows if (r.set, r.size, r.preset) == key]
        worst = max(sel, key=lambda r: r.rel_rmse)
        speed = [r.equal_error_speedup for r in sel if r.equal_error_speedup is not None]
        out["/".join(map(str, key))] = {
            "set": key[0], "size": key[1], "preset": key[2], "scenes": len(sel),
            **{f"{m}_median": float(np.median([getattr(r, m) for r in sel])) for m in
               ("rel_rmse", "flip", "artefact_share", "frame_ms", "mean_ratio", "ref_noise_rel_rmse")},
            **{f"{m}_max": float(np.max([getattr(r, m) for r in sel])) for m in ("rel_rmse", "flip", "artefact_share", "frame_ms")},
            "mean_ratio_min": float(np.min([r.mean_ratio for r in sel])),
            "worst_scene": worst.scene, "equal_error_min": float(min(speed)) if speed else None,
            "equal_error_median": float(np.median(speed)) if speed else None,
            "unresolved": len(sel) - len(speed), **_edge_summary(sel)}
    return out


def _edge_summary(sel: list[BroadRow]) -> dict:
    """The silhouette and window columns' medians and worst values over `sel` (NaN-free: a scene without
    edge pixels or judged windows has none); absent where no row has them (runs made before)."""
    out = {}
    for m, stats in (("silhouette_rel_rmse", ("median", "max")), ("coverage_rmse", ("median",)),
                     ("window_share", ("median", "max"))):
        values = [getattr(r, m) for r in sel if getattr(r, m) is not None]
        if not values:
            continue
        finite = [v for v in values if np.isfinite(v)]
        for stat in stats:
            out[f"{m}_{stat}"] = float(getattr(np, stat)(finite)) if finite else float("nan")
    return out


# The size the frame budgets and error targets are set at; the equal-error targets hold at every size
# from it up (LARGEST too).
TARGET_SIZE = 256


def target_misses(rows: list[BroadRow], size: int = TARGET_SIZE) -> list[dict]:
    """Every held-out scene and preset beyond a target at `size`: which target, the value and its factor.
    At TARGET_SIZE every target, at a larger size the equal-error target alone."""
    misses = []
    for r in rows:
        if r.set != "held-out" or r.size != size or r.preset not in TARGETS:
            continue
        for metric, limit in (TARGETS[r.preset] if size == TARGET_SIZE else {}).items():
            if limit is not None and getattr(r, metric) > limit:
                misses.append({"scene": r.scene, "size": r.size, "preset": r.preset, "metric": metric,
                               "value": getattr(r, metric), "target": limit, "factor": getattr(r, metric) / limit})
        want = EQUAL_ERROR_TARGETS[r.preset]
        if r.equal_error_speedup is not None and r.equal_error_speedup < want:
            misses.append({"scene": r.scene, "size": r.size, "preset": r.preset, "metric": "equal_error_speedup",
                           "value": r.equal_error_speedup, "target": want, "factor": want / r.equal_error_speedup})
    return misses


def all_misses(rows: list[BroadRow]) -> list[dict]:
    """target_misses at every size of the run's rows from TARGET_SIZE up."""
    return [m for size in sorted({r.size for r in rows if r.size >= TARGET_SIZE}) for m in target_misses(rows, size)]


def _rates_json(rates: dict[str, tuple[float, float]]) -> dict:
    return {name: {"setup_ms": setup, "ms_per_spp": per} for name, (setup, per) in rates.items()}


def write(out_dir: Path, rows: list[BroadRow], machine: dict, cfg: BroadConfig, source: str, ref_s: float,
          sets_timed: dict | None = None, tracer: dict | None = None) -> None:
    from renderer.presets import presets_digest

    data = {"machine": machine, "config": asdict(cfg), "presets": source, "presets_digest": presets_digest(),
            "reference_code": reference_code_digest(), "split": split(), "tracer": tracer or {},
            "reference_s": ref_s, "sets_timed": sets_timed or {}, "summary": summary(rows),
            "misses": all_misses(rows),
            "rows": [asdict(r) for r in rows]}
    (out_dir / "broad.json").write_text(json.dumps(data, indent=1, default=float))
    (out_dir / "broad.md").write_text(markdown(data))


# The README's quality table: generated from the stored held-out run at 256 x 256 (tests/test_readme.py
# checks that the README holds what this makes of docs/broad/broad-256.json).
README_RUN = "docs/broad/broad-256.json"
README_BEGIN = "<!-- quality table: generated from docs/broad/broad-256.json (garment_lab.broad.readme_table) -->"
README_END = "<!-- end of the generated table -->"


def with_readme_table(text: str, data: dict) -> str:
    """The README's text with the table between its markers made anew from the run `data`
    (readme_table); the text as it was where it already holds that table."""
    start, end = text.index(README_BEGIN), text.index(README_END) + len(README_END)
    return text[:start] + readme_table(data) + text[end:]


def readme_table(data: dict) -> str:
    """The presets on the held-out scenes at 256 x 256: light count, frame budget and measured frame,
    error, artefact share and the tracer's time at the same error, as markdown between the markers."""
    from renderer.presets import presets

    from .catalogue import TARGETS

    in_use, _ = presets()
    lines = [README_BEGIN,
             "| preset | lights | frame: budget, held-out median | rel. RMSE beyond the reference's noise, median / worst | "
             "pixels > 2x off | "
             "tracer's time at equal error |", "|---|---|---|---|---|---|"]
    scenes = 0
    for preset in PRESETS:
        s = data["summary"].get(f"held-out/256/{preset}")
        if s is None:
            continue
        scenes = max(scenes, s["scenes"])
        budget = TARGETS.get(preset, {}).get("frame_ms")
        ee = s.get("equal_error_median")
        lines.append(f"| {preset} | {in_use[preset]['lights']} | {f'{budget:.0f} ms, ' if budget else ''}"
                     f"{s['frame_ms_median']:.0f} ms | {s['rel_rmse_median']:.3f} / {s['rel_rmse_max']:.3f} | "
                     f"{100 * s['artefact_share_median']:.2f} % | {'-' if ee is None else f'{ee:.1f}x'} |")
    m, t = data["machine"], data.get("retimed")
    lines += ["", f"Measured by `garment-render bench --broad --size 256` on {m['gl_renderer']}, {m['cores']} cores "
              f"({m['date']}): {scenes} held-out scenes, medians over them"
              + (f"; frame and tracer times by `--retime` ({t['machine']['date']}), the tracer on every core."
                 if t else "."), README_END]
    return "\n".join(lines)


def rewrite(path: Path) -> dict:
    """A stored run's summary, misses and report made again from its rows (under today's targets)."""
    data = json.loads(Path(path).read_text())
    rows = [BroadRow(**r) for r in data["rows"]]
    data["summary"], data["misses"] = summary(rows), all_misses(rows)
    Path(path).write_text(json.dumps(data, indent=1, default=float))
    Path(path).with_suffix(".md").write_text(markdown(data))
    return data


# The tracer's rate for retime: two renders of a scene, at RETIME_SPP[0] and [1] samples, in one thread.
RETIME_SPP = (4, 12)


def tracer_time_ms(spp: float, setup_ms: float, ms_per_spp: float, cores: int) -> float:
    """The tracer's wall time for `spp` samples on `cores` cores: its setup, then the samples split
    evenly over the cores (each core's share in one thread, as the references are made): the ideal
    split, which favours the tracer."""
    return setup_ms + spp * ms_per_spp / cores


def error_at_spp(spp: float, floor: float, ref_spp: int) -> float:
    """The tracer's rel. RMSE at `spp` samples: one render of `ref_spp` is off by the pair's floor /
    sqrt(2), and its relMSE falls as 1/spp (it is unbiased)."""
    return floor / np.sqrt(2.0) * np.sqrt(ref_spp / spp)


def spp_at_error(error: float, floor: float, ref_spp: int) -> float:
    """The samples at which the tracer reaches `error` (at least one): error_at_spp's inverse."""
    return max(1.0, ref_spp * (floor / np.sqrt(2.0) / error) ** 2)


def setting_knobs(in_use: dict) -> dict[str, dict]:
    """Every setting the benchmark renders, by its row name: the presets (`in_use`, presets.presets()'s
    table, as the CLI and service apply them) and each knob variant ("PRESET:KNOB=VALUE", KNOB_VARIANTS)."""
    from renderer import presets as presets_mod

    knobs = {p: {**presets_mod.merge_knobs(in_use[p], {}), "filter": "sqrt-cosine"} for p in PRESETS}
    knobs.update({name: {**knobs[knob_base(name)], **v} for name, v in KNOB_VARIANTS.items()})
    return knobs


def _tracer_rate(scene: Scene, pool) -> tuple[float, float]:
    """(setup ms, ms per sample) of one thread rendering `scene` in `pool` (one_thread_pool): the line
    through RETIME_SPP's times."""
    (lo, t_lo), (hi, t_hi) = ((spp, pool.submit(_reference_job, scene, spp, 1, pixel_samples=1).result()[1])
                              for spp in RETIME_SPP)
    per = max((t_hi - t_lo) / (hi - lo), 1e-9) * 1e3
    return max(t_lo * 1e3 - lo * per, 0.0), per


def retime(path: Path, out: Path, frames: int = BroadConfig.frames, log=print) -> dict:
    """A stored run's times measured again on this machine: every row's frame time (its setting
    rendered again, `frames` after a warm-up) and the tracer's rate beside it (`_tracer_rate`), and
    the equal-error speed-ups from them with the tracer on every core of this machine
    (`tracer_time_ms`). The errors stay the stored run's: the images of the code that retimes must be
    the ones the run measured (a change that alters them re-runs the benchmark). Written to `out`
    (.json and .md) with the retime's machine and date, the preset files' digest and the tracer's rates."""
    from renderer import presets as presets_mod
    from renderer.gpu.context import GLContext
    from renderer.renderer import Renderer

    data = json.loads(Path(path).read_text())
    rows = [BroadRow(**r) for r in data["rows"]]
    cores = len(os.sched_getaffinity(0))
    knobs = setting_knobs(presets_mod.presets()[0])
    unknown = sorted({r.preset for r in rows} - set(knobs))
    if unknown:
        raise ValueError(f"{path} has rows of settings this code does not define ({', '.join(unknown)}): "
                         "run the benchmark again instead")
    by_name = {r.scene: Scene(r.map, r.garment, r.fabric, r.view, r.size) for r in rows}
    todo = sorted(by_name, key=lambda n: (by_name[n].map, by_name[n].garment, by_name[n].size))
    rates: dict[str, dict] = {}
    gl = GLContext()
    machine = machine_info(gl)
    res: MapResources | None = None
    try:
        # The tracer timed as its references are made: in a process of one thread.
        with Renderer(gl) as r, one_thread_pool(1) as pool:
            for k, name in enumerate(todo):
                scene = by_name[name]
                mine = [x for x in rows if x.scene == name]
                if res is None or res.name != scene.map:
                    if res is not None:
                        res.release()
                    res = MapResources(r, scene.map)
                times = render_presets(r, scene, {x.preset: knobs[x.preset] for x in mine}, frames, res)
                setup, per = _tracer_rate(scene, pool)
                rates[name] = {"setup_ms": setup, "ms_per_spp": per}
                for x in mine:
                    x.frame_ms = times[x.preset][1]
                    x.ref_ms_per_spp = per
                    x.equal_error_speedup = None
                    if x.extra.get("rel_rmse_measured", x.rel_rmse) > x.ref_noise_rel_rmse:   # as `measure`
                        spp = spp_at_error(x.rel_rmse, x.ref_noise_rel_rmse, x.ref_spp)
                        x.equal_error_speedup = tracer_time_ms(spp, setup, per, cores) / x.frame_ms
                b = next((x for x in mine if x.preset == "balanced"), mine[0])
                log(f"[{k + 1}/{len(todo)}] {name}: {b.preset} {b.frame_ms:.0f} ms, tracer {per:.0f} ms a sample "
                    f"on one thread (+{setup:.0f} ms)")
            if res is not None:
                res.release()
    finally:
        gl.release()
    from renderer.presets import presets_digest

    data["retimed"] = {"machine": machine, "from": str(path), "cores": cores, "frames": frames,
                       "presets_digest": presets_digest(), "tracer": rates}
    data["rows"] = [asdict(x) for x in rows]
    data["summary"], data["misses"] = summary(rows), all_misses(rows)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1, default=float))
    out.with_suffix(".md").write_text(markdown(data))
    return data


def knob_table(rows: list[dict]) -> list[dict]:
    """Per knob variant, image size and set: the medians over scenes of its change against its preset
    in the same scene (rel. RMSE and FLIP as differences, artefact share in points, time as a ratio),
    and on how many scenes its rel. RMSE is lower."""
    base = {(r["preset"], r["scene"], r["size"]): r for r in rows if r["preset"] in PRESETS}
    out = []
    for size in sorted({r["size"] for r in rows}, reverse=True):
        for name in KNOB_VARIANTS:
            preset = knob_base(name)
            for part in ("tuning", "held-out"):
                pairs = [(r, base[preset, r["scene"], size]) for r in rows if r["preset"] == name
                         and r["set"] == part and r["size"] == size and (preset, r["scene"], size) in base]
                if pairs:
                    out.append(_knob_change(name, size, part, pairs))
    return out


def _knob_change(name: str, size: int, part: str, pairs: list) -> dict:
    """One variant's row of the knob table: `pairs` are (its row, its preset's row) per scene."""
    return {"knob": name, "size": size, "set": part, "scenes": len(pairs),
            "d_rel_rmse": float(np.median([v["rel_rmse"] - b["rel_rmse"] for v, b in pairs])),
            "d_flip": float(np.median([v["flip"] - b["flip"] for v, b in pairs])),
            "d_artefacts": float(np.median([v["artefact_share"] - b["artefact_share"] for v, b in pairs])),
            "time_ratio": float(np.median([v["frame_ms"] / b["frame_ms"] for v, b in pairs])),
            "better": sum(v["rel_rmse"] < b["rel_rmse"] for v, b in pairs)}


def knob_lines(rows: list[dict]) -> list[str]:
    table = knob_table(rows)
    if not table:
        return []
    lines = ["", "## Knobs around the presets", "",
             "A preset with one knob changed, against that preset on the same scenes (medians over the scenes; "
             f"time as the ratio of the two settings' medians in the same run; negative changes are better): at "
             f"256 x 256 and above the sheen scenes, at 128 x 128 the {KNOB_SMALL_FABRIC} scenes.", "",
             "| variant | size | set | scenes | rel. RMSE change | FLIP change | artefact share change | time | "
             "lower rel. RMSE on |",
             "|---|---|---|---|---|---|---|---|---|"]
    for t in table:
        lines.append(f"| {t['knob']} | {t['size']} | {t['set']} | {t['scenes']} | {t['d_rel_rmse']:+.4f} | {t['d_flip']:+.4f} | "
                     f"{100 * t['d_artefacts']:+.2f} pt | {t['time_ratio']:.2f}x | {t['better']} of {t['scenes']} |")
    return lines


def garment_lines(rows: list[dict]) -> list[str]:
    """Per set, preset and garment at 256 x 256: the medians over its maps (do the maps carry over,
    and do the garments?)."""
    sel = [r for r in rows if r["size"] == 256 and r["preset"] in PRESETS]
    if not sel:
        return []
    lines = ["", "## By garment at 256 x 256 (medians over the maps)", "",
             "| set | preset | garment | scenes | rel. RMSE | FLIP | artefact share | frame ms |", "|---|---|---|---|---|---|---|---|"]
    for part in ("held-out", "tuning"):
        for preset in PRESETS:
            for garment in sorted({r["garment"] for r in sel}):
                mine = [r for r in sel if (r["set"], r["preset"], r["garment"]) == (part, preset, garment)]
                if mine:
                    med = {m: float(np.median([r[m] for r in mine])) for m in ("rel_rmse", "flip", "artefact_share", "frame_ms")}
                    lines.append(f"| {part} | {preset} | {garment} | {len(mine)} | {med['rel_rmse']:.3f} | {med['flip']:.3f} | "
                                 f"{_pct(med['artefact_share'])} | {med['frame_ms']:.0f} |")
    return lines


def _size_flag(cfg: dict) -> str:
    sizes = tuple(cfg.get("sizes", (128, 256)))
    return f" --size {sizes[0]}" if len(sizes) == 1 else ""


def _times(x: float) -> str:
    return f"{x:.0f}x" if x >= 10 else f"{x:.1f}x"


def _pct(x: float) -> str:
    return f"{100 * x:.2f} %"


def _excess_lines(rows: list[dict]) -> list[str]:
    """What a row's rel. RMSE is: runs made before the excess was taken out hold the error against the
    mean of the pair."""
    if not rows or "rel_rmse_measured" not in rows[0].get("extra", {}):
        return ["rel. RMSE: against the mean of the two references (this run predates the excess)."]
    return ["rel. RMSE: the excess over the truth's own noise (half the floor), sqrt(e^2 - (floor / 2)^2), e the "
            "error against the mean of the two references; FLIP and the artefact share against that mean."]


def _set_lines(data: dict) -> list[str]:
    """Each set's wall time in the run, its references included, and how many of them it rendered
    (the others were in the cache); absent from runs made before."""
    timed = data.get("sets_timed") or {}
    if not timed.get("wall_s"):
        return []
    refs = timed.get("references", {})
    return ["Wall time of each set, its references included: " + ", ".join(
        f"{name} {s / 60:.1f} min (rendering {refs[name]['rendered']} of its {refs[name]['in_all']} references; "
        "the cache held the others)" if name in refs else f"{name} {s / 60:.1f} min" for name, s in timed["wall_s"].items()) + "."]


def _retimed_lines(data: dict) -> list[str]:
    """A retimed run's line: where its times come from (its errors are the run's above)."""
    t = data.get("retimed")
    if t is None:
        return []
    m = t["machine"]
    return [f"Times retimed by `garment-render bench --broad --retime {t['from']}` on {m['gl_renderer']}, {t['cores']} "
            f"cores, {m['date']}: every frame time ({t['frames']} frames after a warm-up) and the tracer's rate "
            "(one thread, its setup and time per sample) measured then; the errors are the run's."]


def _target_lines(rows: list[dict], misses: list[dict]) -> list[str]:
    """Each preset's targets on the held-out set at TARGET_SIZE (all) and at every larger size of the
    run (equal error alone): met, or on how many scenes and by how much not."""
    held_sizes = sorted({r["size"] for r in rows if r["set"] == "held-out" and r["size"] >= TARGET_SIZE})
    lines = []
    for size in held_sizes or [TARGET_SIZE]:
        lines += ["", f"## Targets on the held-out set at {size} x {size}", ""]
        held = [r for r in rows if r["set"] == "held-out" and r["size"] == size]
        if not held:
            lines.append(f"No held-out scene at {size} x {size} in this run.")
            continue
        if size != TARGET_SIZE:
            lines.append(f"The equal-error targets (the frame budgets and error targets are {TARGET_SIZE} x "
                         f"{TARGET_SIZE}'s).")
            lines.append("")
        for preset, targets in TARGETS.items():
            named = ", ".join(f"{k} <= {v:g}" for k, v in targets.items() if v is not None and size == TARGET_SIZE)
            named = ", ".join(x for x in (named, f"equal error >= {EQUAL_ERROR_TARGETS[preset]:g}x") if x)
            mine = [x for x in misses if x["preset"] == preset and x["size"] == size]
            n = len({r["scene"] for r in held if r["preset"] == preset})
            unresolved = sum(1 for r in held if r["preset"] == preset and r["equal_error_speedup"] is None)
            within = (f"; equal error unresolved on {unresolved} (the error within the truth's own noise)"
                      if unresolved else "")
            if not mine:
                met = f"met on the {n - unresolved} resolved of {n} scenes" if unresolved else f"met on all {n} scenes"
                lines.append(f"- **{preset}** ({named}): {met}{within}.")
                continue
            by_metric: dict[str, list] = {}
            for x in mine:
                by_metric.setdefault(x["metric"], []).append(x)
            parts = []
            for metric, xs in by_metric.items():
                worst = max(xs, key=lambda x: x["factor"])
                parts.append(f"{metric} missed on {len(xs)} of {n} scenes (worst {worst['value']:.4g} against "
                             f"{worst['target']:g}, {worst['factor']:.2f}x, {worst['scene']})")
            lines.append(f"- **{preset}** ({named}): " + "; ".join(parts) + f"{within}.")
    return lines


def _edge_lines(data: dict) -> list[str]:
    """What the silhouette and window columns are, in runs that have them (module doc: edges)."""
    if not _has_edges(data["summary"].values()):
        return []
    return ["Silhouette: rel. RMSE of the frame over black against the references' foreground at their edge "
            "pixels (coverage: the RMSE of alpha there), each the excess over the truth's own noise; windows: the "
            "share of the judged 5 x 5 windows inside the object whose mean luminance is off by more than 1.5x."]


def _has_edges(summaries) -> bool:
    return any("window_share_max" in s for s in summaries)


def _edge_cells(s: dict) -> str:
    """A summary row's silhouette and window cells (the median silhouette and coverage errors, the
    windows' median and worst share)."""
    sil = s.get("silhouette_rel_rmse_median")
    sil = "-" if sil is None else f"{sil:.3f} ({s['coverage_rmse_median']:.3f})"
    return f"{sil} | {_pct(s['window_share_median'])} / {_pct(s['window_share_max'])} | "


def markdown(data: dict) -> str:
    m, cfg = data["machine"], data["config"]
    rows = data["rows"]
    sets = data["split"]
    edges = _has_edges(data["summary"].values())
    strata = (f", each pixel over {cfg['pixel_samples']} x {cfg['pixel_samples']} strata" if "pixel_samples" in cfg
              else "")
    lines = [f"# Broad benchmark: {len(rows)} rows", "",
             f"Machine: {m['gl_renderer']} (GL {m['gl_version']}), {m['cores']} cores, {m['date']}. Presets: {data['presets']}.",
             f"References: two per scene, {cfg['spp_small']} spp at 128 x 128 and {cfg['spp_large']} at 256 x 256 and above"
             f"{strata} (cached; {data['reference_s']:.0f} s rendering this run). Command: `garment-render bench --broad"
             f"{' --quick' if cfg['quick'] else ''}{_size_flag(cfg)}`.", *_set_lines(data), *_retimed_lines(data),
             *_excess_lines(rows), *_edge_lines(data), "",
             "Tuning maps: " + ", ".join(k for k, v in sets.items() if v == "tuning") + ".",
             "Held-out maps: " + ", ".join(k for k, v in sets.items() if v == "held-out") + ".", "",
             "## Summary (median / worst over the scenes)", "",
             "| set | size | preset | scenes | rel. RMSE | FLIP | artefact share | "
             + ("silhouette rel. RMSE (coverage) | 5 x 5 windows off 1.5x | " if edges else "")
             + "frame ms | mean ratio (min) | ref. floor | equal error median (min) | worst scene |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if edges else "")]
    for s in data["summary"].values():
        ee = (f"{_times(s['equal_error_median'])} ({_times(s['equal_error_min'])})" if s["equal_error_min"] is not None
              else "-")
        if s["unresolved"]:
            ee += f" ({s['unresolved']} unresolved)"
        lines.append(f"| {s['set']} | {s['size']} | {s['preset']} | {s['scenes']} | {s['rel_rmse_median']:.3f} / "
                     f"{s['rel_rmse_max']:.3f} | {s['flip_median']:.3f} / {s['flip_max']:.3f} | "
                     f"{_pct(s['artefact_share_median'])} / {_pct(s['artefact_share_max'])} | "
                     f"{_edge_cells(s) if edges else ''}"
                     f"{s['frame_ms_median']:.0f} / {s['frame_ms_max']:.0f} | {s['mean_ratio_median']:.3f} "
                     f"({s['mean_ratio_min']:.3f}) | {s['ref_noise_rel_rmse_median']:.3f} | {ee} | {s['worst_scene']} |")
    lines += _target_lines(rows, data["misses"])
    lines += garment_lines(rows)
    lines += knob_lines(rows)
    lines += ["", "## Every preset's row", "",
              "| scene | set | preset | rel. RMSE | FLIP | artefacts | too bright / dark | "
              + ("silhouette (coverage) | windows off 1.5x | " if edges else "")
              + "mean ratio | background | frame ms | ref. floor | equal error |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if edges else "")]
    for r in sorted((r for r in rows if r["preset"] in PRESETS),
                    key=lambda r: (r["set"], r["size"], r["scene"], PRESETS.index(r["preset"]))):
        ee = _times(r["equal_error_speedup"]) if r["equal_error_speedup"] is not None else "unresolved"
        sil = r.get("silhouette_rel_rmse")
        cells = (("-" if sil is None else f"{sil:.3f} ({r['coverage_rmse']:.3f})") + " | "
                 + ("-" if r.get("window_share") is None else _pct(r["window_share"])) + " | ") if edges else ""
        lines.append(f"| {r['scene']} | {r['set']} | {r['preset']} | {r['rel_rmse']:.3f} | {r['flip']:.3f} | "
                     f"{_pct(r['artefact_share'])} | {r['too_bright']} / {r['too_dark']} | {cells}{r['mean_ratio']:.3f} | "
                     f"{r['background_rel_rmse']:.3f} | {r['frame_ms']:.0f} | {r['ref_noise_rel_rmse']:.3f} | {ee} |")
    return "\n".join(lines) + "\n"
