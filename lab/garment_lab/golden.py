"""Stored frames of the knob sweep's scenes at every preset: a change meant to keep the images (a
refactor of the passes, a shader split) is checked against them by tests/test_golden.py.

    python -m garment_lab.golden --store     # after a change meant to alter the images, say which

The frames are small (GOLDEN_SIZE per side, float16) so that the file stays a few hundred kB; the
check is a rel. RMSE over each frame's covered pixels, loose enough for another GPU's rounding and
tight enough that any change of the method shows.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

GOLDEN_SIZE = 48
GOLDEN_FILE = Path(__file__).resolve().parents[2] / "tests" / "data" / "golden-frames.npz"


def golden_frames(renderer=None, presets: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """scene/preset -> the frame (GOLDEN_SIZE^2, RGBA float32) of the bundled scene and, when the
    shared assets are there, the four newton-shirt scenes, at every preset (or those of `presets`);
    on `renderer` (None: one of its own)."""
    from contextlib import nullcontext

    from renderer.camera import frame_meshes
    from renderer.presets import PRESET_NAMES, preset, preset_frame, preset_pems
    from renderer.renderer import Renderer

    from .scenes import bundled_scene, shared_scenes

    scenes = [bundled_scene()] + shared_scenes()   # shared_scenes: none without the shared assets
    out = {}
    with nullcontext(renderer) if renderer is not None else Renderer() as r:
        for bs in scenes:
            scene = r.create_scene(bs.meshes, bs.materials)
            camera = frame_meshes(bs.meshes, 1.0)
            try:
                for name in presets or PRESET_NAMES:
                    pems = r.build_pems(bs.cube(int(preset(name)["face_size"])), preset_pems(name, bs.materials))
                    try:
                        frame = r.render(scene, pems, preset_frame(name, GOLDEN_SIZE, GOLDEN_SIZE), camera)
                    finally:
                        pems.release()
                    out[f"{bs.name}/{name}"] = np.array(frame.image)
            finally:
                scene.release()
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m garment_lab.golden", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--store", action="store_true", help=f"write {GOLDEN_FILE}")
    args = p.parse_args(argv)
    frames = golden_frames()
    if args.store:
        GOLDEN_FILE.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(GOLDEN_FILE, **{k: v.astype(np.float16) for k, v in frames.items()})
        print(f"stored {len(frames)} frames in {GOLDEN_FILE}")
    else:
        print(f"rendered {len(frames)} frames (--store writes them)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
