"""The benchmark's scenes: a bundled one (always there) and the issue's target scenes on the shared
assets (the newton shirt's last frame on its dress form under four probes of different kinds)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from renderer.envmap import environment_from_array, load_environment, studio_environment
from renderer.mesh import Mesh, load_mesh
from renderer.procedural import procedural_body, procedural_garment
from renderer.shading.material import Material

SHARED_ASSETS = Path(__file__).resolve().parents[2].parent / "shared" / "assets"
# Where the shared assets are when not beside the project (a copy elsewhere on a benchmark machine).
ASSETS_VARIABLE = "GARMENT_RENDER_ASSETS"


def shared_assets() -> Path:
    """The shared assets' folder: $GARMENT_RENDER_ASSETS when set, else ../shared/assets."""
    return Path(os.environ[ASSETS_VARIABLE]) if os.environ.get(ASSETS_VARIABLE) else SHARED_ASSETS

# The four probes of different kinds named by the accuracy target (issue 3, section 7).
TARGET_PROBES = {
    "hard-sun": "rooitou_park_1k.hdr",
    "interior": "empty_warehouse_01_1k.hdr",
    "overcast": "potsdamer_platz_1k.hdr",
    "night": "dikhololo_night_1k.hdr",
}

GARMENT = Material((0.8, 0.2, 0.2), 0.5, 0.8)
BODY = Material((0.6, 0.6, 0.6), 0.1, 0.3)


@dataclass
class BenchScene:
    name: str
    env_name: str
    meshes: list[Mesh]
    materials: list[Material]
    _env_loader: object = None
    _envs: dict | None = None

    def cube(self, face_size: int) -> np.ndarray:
        """The environment as a cube of the requested face size (converted once per size)."""
        self._envs = self._envs or {}
        if face_size not in self._envs:
            self._envs[face_size] = self._env_loader(face_size)
        return self._envs[face_size].cube


def bundled_scene() -> BenchScene:
    studio = studio_environment(1024)
    return BenchScene("studio-dress", "studio (procedural)", [procedural_garment(), procedural_body()],
                      [GARMENT, BODY], lambda f: environment_from_array(studio, "latlong", f, name="studio"))


def shared_scenes(probes: dict[str, str] = TARGET_PROBES) -> list[BenchScene]:
    """The target scenes, or [] when the shared assets are absent (a user's machine)."""
    assets = shared_assets()
    sim = assets / "sim"
    if not (sim / "newton_shirt_drape_f060.obj").exists():
        return []
    shirt = load_mesh(sim / "newton_shirt_drape_f060.obj", up="z")
    form = load_mesh(sim / "newton_shirt_drape_colliders.obj", up="z")
    out = []
    for kind, fname in probes.items():
        path = assets / "hdri" / fname
        out.append(BenchScene(f"newton-shirt/{kind}", fname, [shirt, form], [GARMENT, BODY],
                              lambda f, path=path: load_environment(path, face_size=f, repair=True)))
    return out


# The GPU speed target's scene (issue 3, section 7): a garment of at least 100k triangles.
LARGE_GARMENT_TRIANGLES = 100_000


def large_scene(min_triangles: int = LARGE_GARMENT_TRIANGLES, probe: str = "hard-sun") -> BenchScene | None:
    """The newton shirt's last frame, each triangle split in four (trimesh's midpoint subdivision)
    until the garment has at least `min_triangles`, on its dress form under one target probe; None
    when ../shared/assets is absent."""
    found = shared_scenes({probe: TARGET_PROBES[probe]})
    if not found:
        return None
    scene = found[0]
    shirt, form = scene.meshes
    positions, faces = shirt.positions, shirt.faces
    while len(faces) < min_triangles:
        positions, faces = trimesh.remesh.subdivide(positions, faces)
    garment = Mesh.from_arrays(positions, faces, name=f"{shirt.name} ({len(faces)} triangles)")
    return BenchScene(f"newton-shirt-{len(faces)}/{probe}", scene.env_name, [garment, form], scene.materials,
                      scene._env_loader)
