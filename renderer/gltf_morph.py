"""Mesh sequences from glTF / GLB morph-target animation (pygltflib): a mesh's base positions plus its
POSITION targets, weighted over time by an animation channel whose path is "weights".

Each mesh node is placed by its world transform (the node hierarchy's matrices or TRS, read once:
animated node transforms are not read), in glTF's own axes and units (Y up, metres: the renderer's).
The frames are the keyframe times of the mesh's weights samplers; STEP and LINEAR samplers give their
keyframes' weights, CUBICSPLINE ones their values (the tangents lie between keyframes). Sparse
accessors are read. Meshes whose weights are animated are the sequence (merged: a garment's panels);
the others are returned beside it, at their default weights (the body).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MeshError

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
TRIANGLES = 4


@dataclass(frozen=True)
class MorphMesh:
    name: str
    faces: np.ndarray        # (T, 3) int32
    positions: np.ndarray    # (F, V, 3) float32, world space
    animated: bool


def _load(path: Path):
    try:
        import pygltflib
    except ImportError as exc:
        raise MeshError("reading glTF animation needs the pygltflib package (pip install pygltflib)") from exc
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    try:
        gltf = pygltflib.GLTF2().load(str(path))
    except Exception as exc:   # pygltflib raises whatever its JSON or struct parsing met
        raise MeshError(f"{path}: not a glTF file ({exc})") from exc
    if gltf is None:
        raise MeshError(f"{path}: not a glTF file")
    return gltf


def _buffer_bytes(gltf, path: Path, index: int) -> bytes:
    buf = gltf.buffers[index]
    if buf.uri is None:
        blob = gltf.binary_blob()
        if blob is None:
            raise MeshError(f"{path}: buffer {index} has no data (no GLB binary chunk)")
        return blob
    if buf.uri.startswith("data:"):
        import base64

        return base64.b64decode(buf.uri.split(",", 1)[1])
    file = path.parent / buf.uri
    if not file.exists():
        raise MeshError(f"{path}: buffer {index}'s file {buf.uri} is missing")
    return file.read_bytes()


def _accessor(gltf, path: Path, index: int, cache: dict) -> np.ndarray:
    """An accessor's values as float64 (count, width), normalized integers scaled, sparse values in."""
    acc = gltf.accessors[index]
    dtype, width = _COMPONENTS.get(acc.componentType), _WIDTH.get(acc.type)
    if dtype is None or width is None:
        raise MeshError(f"{path}: accessor {index} has an unknown type ({acc.componentType}, {acc.type})")
    out = np.zeros((acc.count, width), np.float64)
    if acc.bufferView is not None:
        view = gltf.bufferViews[acc.bufferView]
        if view.buffer not in cache:
            cache[view.buffer] = _buffer_bytes(gltf, path, view.buffer)
        data = cache[view.buffer]
        item = np.dtype(dtype).itemsize * width
        stride = view.byteStride or item
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        end = start + stride * (acc.count - 1) + item
        if acc.count and end > len(data):
            raise MeshError(f"{path}: accessor {index} reads past its buffer ({end} > {len(data)} bytes)")
        raw = np.frombuffer(data, np.uint8, count=end - start, offset=start) if acc.count else np.zeros(0, np.uint8)
        rows = np.lib.stride_tricks.as_strided(raw, (acc.count, item), (stride, 1)) if acc.count else raw.reshape(0, item)
        out[:] = np.ascontiguousarray(rows).view(dtype).reshape(acc.count, width)
        if acc.normalized and dtype is not np.float32:
            out /= float(np.iinfo(dtype).max)
    if acc.sparse is not None:
        sp = acc.sparse
        idx = _raw(gltf, path, sp.indices.bufferView, sp.indices.byteOffset or 0, _COMPONENTS[sp.indices.componentType],
                   sp.count, 1, cache)[:, 0].astype(np.int64)
        vals = _raw(gltf, path, sp.values.bufferView, sp.values.byteOffset or 0, dtype, sp.count, width, cache)
        if len(idx) and (idx.min() < 0 or idx.max() >= acc.count):
            raise MeshError(f"{path}: accessor {index}'s sparse indices reach outside its {acc.count} values")
        out[idx] = vals
    return out


def _raw(gltf, path, view_index, offset, dtype, count, width, cache) -> np.ndarray:
    view = gltf.bufferViews[view_index]
    if view.buffer not in cache:
        cache[view.buffer] = _buffer_bytes(gltf, path, view.buffer)
    start = (view.byteOffset or 0) + offset
    n = count * width
    return np.frombuffer(cache[view.buffer], dtype, count=n, offset=start).astype(np.float64).reshape(count, width)


def _local_matrix(node) -> np.ndarray:
    if node.matrix is not None:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T   # glTF stores column-major
    m = np.eye(4)
    if node.scale is not None:
        m = np.diag([*node.scale, 1.0]) @ m
    if node.rotation is not None:
        x, y, z, w = node.rotation
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        rot = np.eye(4)
        rot[:3, :3] = r
        m = rot @ m
    if node.translation is not None:
        t = np.eye(4)
        t[:3, 3] = node.translation
        m = t @ m
    return m


def _world_matrices(gltf) -> dict[int, np.ndarray]:
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    out: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in out:
            local = _local_matrix(gltf.nodes[i])
            out[i] = world(parent[i]) @ local if i in parent else local
        return out[i]

    for i in range(len(gltf.nodes)):
        world(i)
    return out


def read_morph_animation(path: str | Path) -> tuple[list[MorphMesh], np.ndarray]:
    """Every mesh node of a glTF file, its positions at each keyframe of its weights; and the times."""
    path = Path(path)
    gltf = _load(path)
    cache: dict = {}
    worlds = _world_matrices(gltf)
    # The weights channels: node -> (times, weights (K, n_targets)).
    channels: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for anim in gltf.animations or []:
        for ch in anim.channels:
            if ch.target.path != "weights" or ch.target.node is None:
                continue
            sampler = anim.samplers[ch.sampler]
            times = _accessor(gltf, path, sampler.input, cache)[:, 0]
            values = _accessor(gltf, path, sampler.output, cache).reshape(-1)
            n_keys = len(times)
            if n_keys == 0:
                raise MeshError(f"{path}: an animation's weights sampler has no keyframes")
            per_key = len(values) // n_keys
            if (sampler.interpolation or "LINEAR") == "CUBICSPLINE":
                values = values.reshape(n_keys, 3, per_key // 3)[:, 1]   # in-tangent, value, out-tangent
            else:
                values = values.reshape(n_keys, per_key)
            channels[ch.target.node] = (times, values)
    all_times = sorted({float(t) for times, _ in channels.values() for t in times})
    times = np.array(all_times or [0.0])
    meshes = []
    for i, node in enumerate(gltf.nodes):
        if node.mesh is None:
            continue
        mesh = gltf.meshes[node.mesh]
        m = worlds[i]
        for p, prim in enumerate(mesh.primitives):
            where = f"{path}: mesh {mesh.name or node.mesh} primitive {p}"
            if (prim.mode if prim.mode is not None else TRIANGLES) != TRIANGLES:
                raise MeshError(f"{where}: mode {prim.mode} is not triangles (4)")
            if prim.attributes.POSITION is None:
                raise MeshError(f"{where}: no POSITION attribute")
            base = _accessor(gltf, path, prim.attributes.POSITION, cache)
            n = len(base)
            faces = (_accessor(gltf, path, prim.indices, cache)[:, 0].astype(np.int64) if prim.indices is not None
                     else np.arange(n))
            if len(faces) % 3 or (len(faces) and (faces.min() < 0 or faces.max() >= n)):
                raise MeshError(f"{where}: its indices are not triangles of its {n} vertices")
            targets = [_accessor(gltf, path, t["POSITION"], cache) if isinstance(t, dict) else
                       _accessor(gltf, path, t.POSITION, cache) for t in (prim.targets or [])]
            defaults = np.asarray(getattr(node, "weights", None) or mesh.weights or [0.0] * len(targets), np.float64)
            if i in channels:
                key_times, weights = channels[i]
                if weights.shape[1] != len(targets):
                    raise MeshError(f"{where}: its animation has {weights.shape[1]} weights per keyframe but the "
                                    f"primitive has {len(targets)} morph targets")
                # Each keyframe time of any channel: this mesh's weights there (linear between its own keys).
                w = np.stack([np.interp(times, key_times, weights[:, k]) for k in range(len(targets))], axis=1)
            else:
                w = np.tile(defaults[:len(targets)], (len(times), 1)) if targets else np.zeros((len(times), 0))
            pos = np.repeat(base[None], len(times), axis=0)
            for k, t in enumerate(targets):
                pos += w[:, k, None, None] * t[None]
            pos = pos @ m[:3, :3].T + m[:3, 3]
            if not np.isfinite(pos).all():
                raise MeshError(f"{where}: NaN or Inf positions")
            meshes.append(MorphMesh(mesh.name or f"mesh{node.mesh}", faces.reshape(-1, 3).astype(np.int32),
                                    pos.astype(np.float32), i in channels and bool(np.ptp(pos, axis=0).max() > 0)))
    if not meshes:
        raise MeshError(f"{path}: the file has no mesh")
    return meshes, times
