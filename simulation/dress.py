"""Drape the sewn dress (`panels.dress`) on the mannequin: a fixed number of frames under gravity,
deterministic (no randomness; the same arguments give the same positions, bit for bit).

    python -m simulation.dress --out dress.npz [--png dress.png]
    python -m simulation.dress --store       # the bundled default scene (renderer/data/default_scene.npz)

writes the draped dress as one mesh, each seam's two vertices merged (positions float32 (V, 3)
metres Y-up, faces int32 (F, 3) counter-clockwise seen from outside, uvs float32 (V, 2)), and,
with --png, a still of it on the mannequin from the front and three-quarter views. --store writes
the dress with the mannequin's render mesh and the floor as the renderer's bundled default scene
(`renderer.procedural.default_scene`): run it after a change to the dress, the cloth or the body.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .panels import DressPattern, Garment, dress
from .proxy import BodyProxy, mannequin
from .solver import ClothSettings, ClothSim, FrameStats

# The dress's cloth: the solver's defaults. Damping and drag are what bring it to rest in the frames
# `drape` runs; structural springs and seams are inextensible.
DRESS_SETTINGS = ClothSettings()
# Frames at the start of a drape whose velocities are zeroed (see `drape`).
SETTLE_FRAMES = 5


@dataclass(frozen=True)
class Drape:
    """A draped garment: its final positions (V, 3) float64 metres, every frame's stats, the
    wall-clock seconds the simulation took."""

    garment: Garment
    body: BodyProxy
    settings: ClothSettings
    positions: np.ndarray
    stats: tuple[FrameStats, ...]
    seconds: float

    @property
    def max_stretch(self) -> float:
        """The largest relative stretch of a structural spring over all frames."""
        return max(s.max_stretch for s in self.stats)

    @property
    def max_penetration_m(self) -> float:
        """The deepest any vertex went into the proxy or floor at the end of any frame (m)."""
        return max(s.max_penetration_m for s in self.stats)

    def sewn(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The draped dress as one render mesh (`Garment.sewn`): positions, faces, uvs."""
        return self.garment.sewn(self.positions)


def drape(spacing_m: float = 0.025, frames: int = 90, settle_frames: int = SETTLE_FRAMES,
          settings: ClothSettings = DRESS_SETTINGS, pattern: DressPattern | None = None,
          body: BodyProxy | None = None) -> Drape:
    """Sew the dress and let it hang on `body` (default `mannequin()`) for `frames` frames of
    settings.frame_dt_s. The first `settle_frames` end with the velocities zeroed: the placed
    panels are near their rest lengths but not at them, and what the springs correct there is a
    settling of the cloth, not motion it should keep."""
    if frames < 1 or settle_frames < 0:
        raise ValueError("frames must be >= 1 and settle_frames >= 0")
    body = mannequin() if body is None else body
    garment = dress(spacing_m, pattern or DressPattern())
    sim = ClothSim(garment.cloth, body, settings)
    t0 = time.perf_counter()
    stats = []
    for k in range(frames):
        stats.append(sim.step_frame())
        if k < settle_frames:
            sim.v[:] = 0.0
    return Drape(garment, body, settings, sim.x.copy(), tuple(stats), time.perf_counter() - t0)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m simulation.dress", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, help="the draped dress (.npz: positions, faces, uvs)")
    p.add_argument("--store", action="store_true",
                   help="write the bundled default scene: the dress, the mannequin and the floor")
    p.add_argument("--png", type=Path, help="also a still of the dress on the mannequin (needs OpenGL 4.5)")
    p.add_argument("--spacing", type=float, default=0.025, help="the panels' grid spacing, metres")
    p.add_argument("--frames", type=int, default=90, help="frames to simulate")
    p.add_argument("--size", type=int, default=512, help="the still's height in pixels (two views side by side)")
    return p.parse_args(argv)


def default_scene_arrays(d: Drape) -> dict[str, np.ndarray]:
    """The arrays of the bundled default scene (renderer.procedural.default_scene): the draped
    dress (garment_*), the mannequin's render mesh (body_*) and the floor (floor_*), float32
    positions in metres Y-up and int32 faces."""
    from .body_mesh import body_mesh, floor_mesh

    positions, faces, uvs = d.sewn()
    body_p, body_f = body_mesh(d.body)
    floor_p, floor_f = floor_mesh(d.body)
    return {"garment_positions": positions, "garment_faces": faces, "garment_uvs": uvs,
            "body_positions": np.asarray(body_p, np.float32), "body_faces": np.asarray(body_f, np.int32),
            "floor_positions": np.asarray(floor_p, np.float32), "floor_faces": np.asarray(floor_f, np.int32)}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.out is None and not args.store:
        raise SystemExit("error: give --out PATH.npz, --store, or both")
    d = drape(args.spacing, args.frames)
    positions, faces, uvs = d.sewn()
    if args.store:
        from renderer.procedural import DEFAULT_SCENE_FILE

        np.savez_compressed(DEFAULT_SCENE_FILE, **default_scene_arrays(d))
        print(f"dress: stored the default scene in {DEFAULT_SCENE_FILE}")
    if args.out is None:
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(args.out, positions=positions, faces=faces, uvs=uvs)
    last = d.stats[-1]
    print(f"dress: {d.garment.cloth.n_vertices} vertices ({len(positions)} sewn), {len(faces)} triangles; "
          f"{len(d.stats)} frames in {d.seconds:.2f} s; max stretch {d.max_stretch:.3f}, "
          f"max penetration {d.max_penetration_m * 1e3:.1f} mm, widest seam gap {last.max_seam_gap_m * 1e3:.2f} mm, "
          f"final kinetic energy {last.kinetic_j:.2e} J -> {args.out}")
    if args.png:
        from .body_mesh import body_mesh, floor_mesh
        from .feed import FRONT, THREE_QUARTER
        from .preview import render_preview

        render_preview(args.png, (positions, faces, uvs), body_mesh(d.body), floor_mesh(d.body),
                       views=[(v.eye, v.target) for v in (FRONT, THREE_QUARTER)], height=args.size)
        print(f"dress: still -> {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
