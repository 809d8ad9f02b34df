"""`garment-render speed --one-shot`: the wall time of one `garment-render render` command, as a user
runs it (a new process: imports, the GL context, the map, the meshes, the PEM set, one frame, the
files), in the three states of the user's cache folder (renderer/user_cache.py):

* **first run**: the folder empty, as on a machine that never rendered (the glossiness calibration's
  tables are built too, once per face size, and the mesh files parsed by trimesh);
* **new map**: the tables and the garment kept (its files' parses and convexity, mesh_cache.py), nothing
  of this map (its cube resampled, the light decomposition and the PEMs built);
* **cached**: the map and the garment rendered before (the PEM set, with its decomposition, read back).

The states take turns within each round, so that a slow spell of the machine falls on all of them.
Mesa keeps its compiled shaders in a cache of its own (~/.cache/mesa_shader_cache), warm in every
state here as on any machine that rendered once; the package's modules are compiled to bytecode first,
as `pip install` leaves them (a checkout run with PYTHONDONTWRITEBYTECODE would compile them in every
process, ~0.1 s here).
Scenes: the bundled default (the dress in the studio) and the newton shirt on its form under the
first held-out maps of the broad catalogue (lab/garment_lab/catalogue.py), 256 x 256, balanced, with
its PNG and EXR written. Targets (issue 35): cached <= CACHED_TARGET_S, new map <= NEW_MAP_TARGET_S;
a missed target is a row of the report, with the scenes it is missed on."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import renderer
from renderer.presets import presets_digest
from renderer.user_cache import ENV_VAR

from .catalogue import MAPS, split
from .scenes import shared_assets

CACHED_TARGET_S = 1.5
NEW_MAP_TARGET_S = 2.5
STATES = ("first run", "new map", "cached")
# The cache folder's entries that belong to one map (the rest, per face size and filter, to the machine).
PER_MAP = ("pem-sets", "cubes")
SIZE = 256
HELD_OUT_MAPS = 2


def scenes() -> list[tuple[str, list[str]]]:
    """(name, the render command's scene flags): the bundled default, and the shirt under the first
    held-out maps where the shared assets are."""
    out = [("bundled default (dress, studio)", [])]
    assets = shared_assets()
    sim = assets / "sim"
    if (sim / "newton_shirt_drape_f060.obj").exists():
        held_out = [m for m in MAPS if split()[m] == "held-out"][:HELD_OUT_MAPS]
        for m in held_out:
            out.append((f"newton shirt, {m}", ["--env", str(assets / "hdri" / m), "--up", "z",
                                               "--mesh", str(sim / "newton_shirt_drape_f060.obj"),
                                               "--mesh", str(sim / "newton_shirt_drape_colliders.obj")]))
    return out


def _one(flags: list[str], cache: Path, out: Path) -> float:
    env = {**os.environ, ENV_VAR: str(cache)}
    cmd = [sys.executable, "-m", "renderer.cli", "render", *flags, "--preset", "balanced", "--size", f"{SIZE}x{SIZE}",
           "--out", str(out / "frame.png"), "--exr", str(out / "frame.exr")]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"render failed ({done.returncode}): {done.stderr[-2000:]}")
    return wall


def _compile_package() -> None:
    """Bytecode for every module of the package, as an installed one has it."""
    import compileall

    compileall.compile_dir(str(Path(renderer.__file__).resolve().parent), quiet=1)


def run_one_shot(out_dir: Path | None, rounds: int = 3, log=print) -> dict:
    rows = []
    _compile_package()
    with tempfile.TemporaryDirectory(prefix="one-shot-") as tmp:
        tmp = Path(tmp)
        for name, flags in scenes():
            walls = {s: [] for s in STATES}
            for k in range(rounds):
                cache = tmp / f"cache-{len(rows)}-{k}"
                shutil.rmtree(cache, ignore_errors=True)
                walls["first run"].append(_one(flags, cache, tmp))
                for per_map in PER_MAP:
                    shutil.rmtree(cache / per_map)
                walls["new map"].append(_one(flags, cache, tmp))
                walls["cached"].append(_one(flags, cache, tmp))
                log(f"  {name}: " + ", ".join(f"{s} {walls[s][-1]:.2f} s" for s in STATES))
            rows.append({"scene": name, "wall_s": walls, "median_s": {s: float(np.median(v)) for s, v in walls.items()}})
    from renderer.gpu.context import GLContext

    from .report import machine_info

    gl = GLContext()
    try:
        machine = machine_info(gl)
    finally:
        gl.release()
    result = {"machine": machine, "presets_digest": presets_digest(), "rounds": rounds, "size": SIZE, "preset": "balanced", "rows": rows,
              "targets": targets(rows)}
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "one_shot.json").write_text(json.dumps(result, indent=1))
        (out_dir / "one_shot.md").write_text(markdown(result))
    return result


def targets(rows: list[dict]) -> list[dict]:
    """One row per target: the median over the scenes of each scene's median, met or missed, and the
    scenes over the limit."""
    out = []
    for state, limit in (("cached", CACHED_TARGET_S), ("new map", NEW_MAP_TARGET_S)):
        medians = [r["median_s"][state] for r in rows]
        over = [r["scene"] for r in rows if r["median_s"][state] > limit]
        got = float(np.median(medians))
        out.append({"state": state, "limit_s": limit, "median_s": got, "met": got <= limit, "scenes_over": over})
    return out


def markdown(result: dict) -> str:
    m = result["machine"]
    lines = [f"One `garment-render render` command, {result['size']} x {result['size']}, {result['preset']}, as a new "
             f"process (made by `garment-render speed --one-shot --out DIR`, {result['rounds']} rounds, the states "
             f"taking turns) on {m['gl_renderer']}, {m['cores']} cores ({m['date']}), Mesa's shader cache warm, the "
             "package's bytecode compiled. Wall "
             "seconds, median (min-max).",
             "", "| scene | " + " | ".join(STATES) + " |", "|---|" + "---|" * len(STATES)]
    for r in result["rows"]:
        cells = [f"{r['median_s'][s]:.2f} ({min(r['wall_s'][s]):.2f}-{max(r['wall_s'][s]):.2f})" for s in STATES]
        lines.append(f"| {r['scene']} | " + " | ".join(cells) + " |")
    lines += ["", "| target | limit | median over the scenes | | scenes over the limit |", "|---|---|---|---|---|"]
    for t in result["targets"]:
        lines.append(f"| {t['state']} | {t['limit_s']:.1f} s | {t['median_s']:.2f} s | "
                     f"{'met' if t['met'] else 'MISSED by ' + format(t['median_s'] - t['limit_s'], '.2f') + ' s'} | "
                     f"{', '.join(t['scenes_over']) or 'none'} |")
    return "\n".join(lines) + "\n"
