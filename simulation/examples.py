"""The files the README's examples name, made from what the project bundles (no ../shared needed):

    python -m simulation.examples [--out DIR] [--frames N]

    studio.exr   the bundled procedural studio, a 1024 x 512 lat-long map (linear Rec. 709)
    shirt.obj    the bundled garment (the draped dress) in centimetres, Y up: `--mesh-scale 0.01`
    body.obj     the mannequin it hangs on, in centimetres, Y up
    drape.npz    the dress's cloth simulation, frame by frame, in the layout of ../shared's drape:
                 positions float32 (frames, V, 3) in metres with Z up, triangles int32 (F, 3)

The simulation is `simulation.dress`'s (deterministic: the same arguments give the same files): the
sewn dress falling onto the mannequin from where its panels are placed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

from .dress import DRESS_SETTINGS, SETTLE_FRAMES
from .panels import DressPattern, dress
from .proxy import mannequin
from .solver import ClothSim

FRAMES = 24


def drape_frames(frames: int = FRAMES, spacing_m: float = 0.025) -> tuple[np.ndarray, np.ndarray]:
    """The dress's render mesh at each of `frames` frames of its simulation: positions float32
    (frames, V, 3) metres Y-up, faces int32 (F, 3)."""
    body = mannequin()
    garment = dress(spacing_m, DressPattern())
    sim = ClothSim(garment.cloth, body, DRESS_SETTINGS)
    out, faces = [], None
    for k in range(frames):
        sim.step_frame()
        if k < SETTLE_FRAMES:
            sim.v[:] = 0.0
        positions, faces, _ = garment.sewn(sim.x)
        out.append(np.asarray(positions, np.float32))
    return np.stack(out), np.asarray(faces, np.int32)


def y_up_to_z_up(p: np.ndarray) -> np.ndarray:
    """(x, y, z) Y-up to Z-up: (x, -z, y), a right-handed turn about X."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def write_examples(out: Path, frames: int = FRAMES) -> list[Path]:
    """Write the README's example files into `out` (made if missing); returns their paths."""
    from renderer.envmap import write_exr
    from renderer.envmap.procedural import studio_environment
    from renderer.procedural import default_scene

    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in ("studio.exr", "shirt.obj", "body.obj", "drape.npz")]
    write_exr(paths[0], studio_environment(1024))
    (garment, body, _floor), _ = default_scene()
    for mesh, path in ((garment, paths[1]), (body, paths[2])):
        trimesh.Trimesh(mesh.positions * 100.0, mesh.faces, process=False).export(path)
    positions, triangles = drape_frames(frames)
    np.savez(paths[3], positions=y_up_to_z_up(positions).astype(np.float32), triangles=triangles)
    return paths


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m simulation.examples", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("."), help="the folder to write them into (default: here)")
    p.add_argument("--frames", type=int, default=FRAMES, help="frames of the simulation in drape.npz")
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error("--frames must be at least 1")
    for path in write_examples(args.out, args.frames):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
