"""`garment-render speed --large --equal-error`: the GPU target's "at equal error" half (issue 3,
section 7): how many samples the Monte Carlo reference needs to be as close to the truth as each
preset's frame on the large scene, and how long it takes them.

The truth is the mean of `workers` independent reference renders (processes, one per core, each
`truth_spp` samples per technique). Its noise is stated two ways: the floor as the bench states it,
one half of the renders' mean against the other's (what a perfect renderer would score against
one half), and the truth's own error, about half of that (the mean of all has a quarter of the
variance of the difference of two halves). A setting whose error is within twice the truth's own is
reported unresolved: the ladder cannot tell its samples from the truth's noise. The ladder renders
the reference at each sample count in a process of its own (numpy and BLAS held to one thread), all
at once after the truth; each one's time is its own process's wall clock (the reference runs on one
core: its times are what one core takes, and a reference split across every core would be up to
`workers` times faster, which the report states beside the ratio). The ladder stops at a quarter of
the truth's samples, past which its error would be mostly the truth's.
"""

from __future__ import annotations

import os
import time

import numpy as np

from renderer.camera import frame_meshes
from renderer.errors import InvalidInputError
from renderer.reference import mean_flip, relative_rmse, render_reference

from .processes import one_thread_pool
from .scenes import large_scene

TRUTH_FACE_SIZE = 256   # the bench's reference cube: twice balanced's PEM faces


def _reference_job(min_triangles: int, size: int, spp: int, seed: int) -> tuple[np.ndarray, float]:
    """One reference render of the large scene in a worker process: (image, wall seconds)."""
    bs = large_scene(min_triangles)
    camera = frame_meshes(bs.meshes, 1.0)
    cube = bs.cube(TRUTH_FACE_SIZE)
    t0 = time.perf_counter()
    ref = render_reference(bs.meshes, bs.materials, cube, camera, size, size, spp, seed=seed)
    return np.array(ref.image), time.perf_counter() - t0


def run_equal_error(frames: dict[str, dict], size: int, min_triangles: int, truth_spp: int = 128,
                    workers: int | None = None, ladder: tuple = (1, 2, 4, 8, 16, 32, 64, 128),
                    log=print) -> dict:
    """`frames`: {setting: {"image": (H, W, 4), "median_ms": wall, "gpu_ms": GPU or None}}, each
    setting's last frame of `run_speed(..., large=True, equal_error=...)` on the same scene and camera."""
    workers = max(2, workers or len(os.sched_getaffinity(0)))
    kept = tuple(s for s in ladder if 4 * s <= truth_spp * workers)
    if not kept:
        raise InvalidInputError(f"a truth of {workers} x {truth_spp} spp is too coarse for a ladder from {min(ladder)} "
                                f"spp (it needs 4x the ladder's samples; raise --truth-spp)")
    if kept != tuple(ladder):
        log(f"  the ladder stops at {max(kept)} spp: a quarter of the truth's {workers} x {truth_spp}")
    ladder = kept
    with one_thread_pool(workers) as pool:   # one core each
        return _run(frames, size, truth_spp, workers, ladder, log, pool, min_triangles)


def _run(frames, size, truth_spp, workers, ladder, log, pool, min_triangles) -> dict:
    """The truth, the ladder and each setting's equal error, with the reference renders in `pool`."""
    t0 = time.perf_counter()
    jobs = [pool.submit(_reference_job, min_triangles, size, truth_spp, 1000 + k) for k in range(workers)]
    renders = [j.result()[0] for j in jobs]
    truth_s = time.perf_counter() - t0
    half = len(renders) // 2
    a, b = np.mean(renders[:half], axis=0), np.mean(renders[half:], axis=0)
    truth = np.mean(renders, axis=0)
    mask = truth[..., 3] > 0.5
    floor_rmse, floor_flip = relative_rmse(a, b, mask), mean_flip(a, b, mask)
    truth_rmse = 0.5 * floor_rmse
    log(f"  truth: {workers} x {truth_spp} spp in {truth_s:.0f} s; noise floor (half against half, "
        f"{half * truth_spp} spp each) rel. RMSE {floor_rmse:.4f}, FLIP {floor_flip:.4f}; the truth's own "
        f"rel. RMSE about {truth_rmse:.4f}")
    del renders
    steps = {spp: pool.submit(_reference_job, min_triangles, size, spp, 100 + spp) for spp in ladder}
    rungs = []
    for spp, job in steps.items():
        image, wall = job.result()
        rungs.append({"spp": spp, "ms": wall * 1e3, "rel_rmse": relative_rmse(image, truth, mask)})
    log("  reference ladder (one process each, run side by side): "
        + ", ".join(f"{r['spp']} spp {r['ms'] / 1e3:.1f} s err {r['rel_rmse']:.3f}" for r in rungs))
    presets = {}
    for name, f in frames.items():
        err, flip = relative_rmse(f["image"], truth, mask), mean_flip(f["image"], truth, mask)
        resolved = err > 2.0 * truth_rmse
        rung = next((r for r in rungs if r["rel_rmse"] <= err), None) if resolved else None
        row = {"rel_rmse": err, "flip": flip, "frame_ms": f["median_ms"], "gpu_ms": f["gpu_ms"], "resolved": resolved,
               "ref_spp": rung["spp"] if rung else None, "ref_ms": rung["ms"] if rung else None,
               "speedup": rung["ms"] / f["median_ms"] if rung else None,
               "speedup_all_cores": rung["ms"] / workers / f["median_ms"] if rung else None}
        presets[name] = row
        log(f"  {name}: rel. RMSE {err:.4f}, FLIP {flip:.4f}; "
            + (f"the reference needs {rung['spp']} spp ({rung['ms'] / 1e3:.1f} s on one core): "
               f"{row['speedup']:.0f}x the frame's {f['median_ms']:.1f} ms ({row['speedup_all_cores']:.0f}x "
               f"against {workers} cores)" if rung else "the ladder never gets this close" if resolved
               else "unresolved: within twice the truth's own error"))
    return {"size": size, "workers": workers, "truth_spp": truth_spp * workers, "truth_s": truth_s,
            "noise_floor_rel_rmse": floor_rmse, "truth_rel_rmse": truth_rmse, "noise_floor_flip": floor_flip, "ladder": rungs, "presets": presets}
