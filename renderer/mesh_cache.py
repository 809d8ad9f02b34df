"""Mesh files read before, from the user's cache folder (user_cache.py): `load_mesh` of a file whose
bytes, up axis and scale a command saw before costs a hash and a read of its arrays, not trimesh's
import (half a second: scipy and networkx under it) and parse. OBJ, PLY and STL only: their geometry is
all in the one file (a .gltf's buffers may lie beside it)."""

from __future__ import annotations

import hashlib
from importlib.metadata import version
from pathlib import Path

import numpy as np

from . import user_cache
from .errors import MeshError
from .mesh import Mesh, load_mesh

SELF_CONTAINED = (".obj", ".ply", ".stl")
MESH_CACHE_BYTES = 1 << 30


def load_mesh_cached(path, up: str = "y", scale: float = 1.0, cache: Path | None = None) -> Mesh:
    """`load_mesh(path, up, scale)`, kept in the folder `cache` (MESH_CACHE_BYTES of entries at most,
    keyed by the file's bytes, the up axis, the scale and trimesh's version); without a folder, or for
    another format or a file that is not there, `load_mesh` itself (and its errors)."""
    path = Path(path)
    if cache is None or path.suffix.lower() not in SELF_CONTAINED or not path.is_file():
        return load_mesh(path, up=up, scale=scale)
    data = path.read_bytes()
    digest = hashlib.sha256(data)
    digest.update(f"{path.suffix.lower()}|{up}|{float(scale)!r}|trimesh {version('trimesh')}".encode())

    def parse() -> dict[str, np.ndarray]:
        mesh = load_mesh(path, up=up, scale=scale)
        if path.read_bytes() != data:   # written to while read: keyed by bytes it was not parsed from
            raise MeshError(f"mesh file '{path}' changed while it was read; read it again")
        return {"positions": mesh.positions, "faces": mesh.faces} | ({} if mesh.uvs is None else {"uvs": mesh.uvs})

    arrays = user_cache.cached_arrays(cache, digest.hexdigest()[:32], ("renderer.mesh", __name__), parse,
                                      MESH_CACHE_BYTES)
    return Mesh.from_arrays(arrays["positions"], arrays["faces"], arrays.get("uvs"), name=path.stem)
