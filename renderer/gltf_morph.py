"""Mesh sequences from glTF / GLB morph-target animation (pygltflib): a mesh's base positions plus its
POSITION targets, weighted over time by an animation channel whose path is "weights".

Each mesh node is placed by its world transform at each time: the node hierarchy's matrices or TRS,
with the animated translations, rotations and scales (a body walking), in glTF's own axes and units
(Y up, metres: the renderer's). The frames are every keyframe time of the weights and transform
samplers. STEP and LINEAR samplers give their keyframes' values (rotations by spherical
interpolation between keys), CUBICSPLINE ones their values (the tangents shape the curve between
keyframes, which are the frames). Sparse accessors are read. Meshes that move are the sequence
(merged: a garment's panels); the others are returned beside it (the body).
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

    @property
    def path(self) -> str:   # a glTF mesh has its name alone (USD's meshes have a path: sequence._by_role)
        return self.name


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


def _view_bytes(gltf, path: Path, view_index: int, cache: dict) -> tuple[object, bytes]:
    """A buffer view and its buffer's bytes (each buffer read once, `cache`)."""
    view = gltf.bufferViews[view_index]
    if view.buffer not in cache:
        cache[view.buffer] = _buffer_bytes(gltf, path, view.buffer)
    return view, cache[view.buffer]


def _accessor(gltf, path: Path, index: int, cache: dict) -> np.ndarray:
    """An accessor's values as float64 (count, width), normalized integers scaled, sparse values in."""
    acc = gltf.accessors[index]
    dtype, width = _COMPONENTS.get(acc.componentType), _WIDTH.get(acc.type)
    if dtype is None or width is None:
        raise MeshError(f"{path}: accessor {index} has an unknown type ({acc.componentType}, {acc.type})")
    out = np.zeros((acc.count, width), np.float64)
    if acc.bufferView is not None and acc.count:
        view, data = _view_bytes(gltf, path, acc.bufferView, cache)
        item = np.dtype(dtype).itemsize * width
        stride = view.byteStride or item
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        end = start + stride * (acc.count - 1) + item
        if end > len(data):
            raise MeshError(f"{path}: accessor {index} reads past its buffer ({end} > {len(data)} bytes)")
        raw = np.frombuffer(data, np.uint8, count=end - start, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, (acc.count, item), (stride, 1))
        out[:] = np.ascontiguousarray(rows).view(dtype).reshape(acc.count, width)
        if acc.normalized and dtype is not np.float32:
            out /= float(np.iinfo(dtype).max)
    if acc.sparse is not None:
        sp = acc.sparse

        def packed(part, kind, n_comp) -> np.ndarray:   # sparse indices and values are tightly packed
            view, data = _view_bytes(gltf, path, part.bufferView, cache)
            start = (view.byteOffset or 0) + (part.byteOffset or 0)
            return np.frombuffer(data, kind, count=sp.count * n_comp, offset=start).astype(np.float64)

        idx = packed(sp.indices, _COMPONENTS[sp.indices.componentType], 1).astype(np.int64)
        vals = packed(sp.values, dtype, width).reshape(sp.count, width)
        if len(idx) and (idx.min() < 0 or idx.max() >= acc.count):
            raise MeshError(f"{path}: accessor {index}'s sparse indices reach outside its {acc.count} values")
        out[idx] = vals
    return out


def _channel(gltf, path: Path, sampler, cache: dict) -> tuple[np.ndarray, np.ndarray, str]:
    """An animation sampler's keyframe times (K,), values (K, width: 3, 4 or the morph targets) and
    interpolation; a cubic spline's values without their tangents (in-tangent, value, out-tangent)."""
    key_times = _accessor(gltf, path, sampler.input, cache)[:, 0]
    interpolation = sampler.interpolation or "LINEAR"
    if len(key_times) == 0:
        raise MeshError(f"{path}: an animation sampler has no keyframes")
    values = _accessor(gltf, path, sampler.output, cache).reshape(len(key_times), -1)
    if interpolation == "CUBICSPLINE":
        values = values.reshape(len(key_times), 3, -1)[:, 1]
    return key_times, values, interpolation


def _local_matrix(node, trs: dict | None = None) -> np.ndarray:
    """A node's matrix; `trs`: its animated translation, rotation or scale at one time (a node with a
    matrix is not animated: the specification forbids it)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T   # glTF stores column-major
    trs = trs or {}
    scale, rotation, translation = (trs.get("scale", node.scale), trs.get("rotation", node.rotation),
                                    trs.get("translation", node.translation))
    m = np.eye(4)
    if scale is not None:
        m = np.diag([*scale, 1.0]) @ m
    if rotation is not None:
        x, y, z, w = np.asarray(rotation, np.float64) / np.linalg.norm(rotation)
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        rot = np.eye(4)
        rot[:3, :3] = r
        m = rot @ m
    if translation is not None:
        t = np.eye(4)
        t[:3, 3] = translation
        m = t @ m
    return m


def _sample(key_times: np.ndarray, values: np.ndarray, t: float, interpolation: str, rotation: bool) -> np.ndarray:
    """A channel's value at time t: STEP the last key at or before t; LINEAR (and CUBICSPLINE's values)
    between the two keys around t, rotations by spherical interpolation."""
    if t <= key_times[0] or len(key_times) == 1:
        return values[0]
    if t >= key_times[-1]:
        return values[-1]
    j = int(np.searchsorted(key_times, t, side="right")) - 1
    if interpolation == "STEP":
        return values[j]
    u = (t - key_times[j]) / (key_times[j + 1] - key_times[j])
    a, b = values[j], values[j + 1]
    if not rotation:
        return (1 - u) * a + u * b
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    d = float(a @ b)
    if d < 0:   # the shorter way round
        b, d = -b, -d
    if d > 0.9995:
        q = (1 - u) * a + u * b
        return q / np.linalg.norm(q)
    th = np.arccos(d)
    return (np.sin((1 - u) * th) * a + np.sin(u * th) * b) / np.sin(th)


def _world_matrices(gltf, trs_at: dict[int, dict] | None = None) -> dict[int, np.ndarray]:
    """Every node's world matrix; `trs_at`: the animated nodes' TRS at one time."""
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    out: dict[int, np.ndarray] = {}
    trs_at = trs_at or {}

    def world(i: int) -> np.ndarray:
        if i not in out:
            local = _local_matrix(gltf.nodes[i], trs_at.get(i))
            out[i] = world(parent[i]) @ local if i in parent else local
        return out[i]

    for i in range(len(gltf.nodes)):
        world(i)
    return out


def read_morph_animation(path: str | Path) -> tuple[list[MorphMesh], np.ndarray]:
    """Every mesh node of a glTF file, its positions at every keyframe time of the animation; and the times."""
    path = Path(path)
    gltf = _load(path)
    cache: dict = {}
    # Per node, its animated paths: {path: (times, values (K, width), interpolation)}; "weights"
    # moves the morph targets, "translation", "rotation" and "scale" the node.
    channels: dict[int, dict[str, tuple]] = {}
    for anim in gltf.animations or []:
        for ch in anim.channels:
            if ch.target.node is not None and ch.target.path in ("weights", "translation", "rotation", "scale"):
                channels.setdefault(ch.target.node, {})[ch.target.path] = _channel(gltf, path, anim.samplers[ch.sampler],
                                                                                   cache)
    times = np.array(sorted({float(t) for paths in channels.values() for kt, _, _ in paths.values() for t in kt})
                     or [0.0])
    moves = {n: {k: v for k, v in paths.items() if k != "weights"} for n, paths in channels.items()}
    moves = {n: paths for n, paths in moves.items() if paths}
    # Each node's world matrix at each time (the same at every time without transform channels).
    worlds_at = [_world_matrices(gltf, {n: {k: _sample(kt, v, t, interp, k == "rotation")
                                            for k, (kt, v, interp) in paths.items()} for n, paths in moves.items()})
                 for t in (times if moves else times[:1])]
    meshes = []
    for i, node in enumerate(gltf.nodes):
        if node.mesh is None:
            continue
        mesh = gltf.meshes[node.mesh]
        m = np.broadcast_to(np.stack([w[i] for w in worlds_at]), (len(times), 4, 4))   # one per frame
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
            # A target without positions (normals alone) moves nothing.
            targets = [_accessor(gltf, path, t["POSITION"], cache) if t.get("POSITION") is not None
                       else np.zeros_like(base) for t in (prim.targets or [])]
            if "weights" in channels.get(i, {}):
                key_times, weights, interpolation = channels[i]["weights"]
                if weights.shape[1] != len(targets):
                    raise MeshError(f"{where}: its animation has {weights.shape[1]} weights per keyframe but the "
                                    f"primitive has {len(targets)} morph targets")
                # This mesh's weights at every frame (the keyframes of every channel).
                w = np.stack([_sample(key_times, weights, t, interpolation, False) for t in times])
            else:
                defaults = getattr(node, "weights", None) or mesh.weights or [0.0] * len(targets)
                w = np.tile(np.asarray(defaults, np.float64)[:len(targets)], (len(times), 1))
            pos = np.repeat(base[None], len(times), axis=0)
            for k, t in enumerate(targets):
                pos += w[:, k, None, None] * t[None]
            pos = np.einsum("fvj,fij->fvi", pos, m[:, :3, :3]) + m[:, None, :3, 3]
            if not np.isfinite(pos).all():
                raise MeshError(f"{where}: NaN or Inf positions")
            meshes.append(MorphMesh(mesh.name or f"mesh{node.mesh}", faces.reshape(-1, 3).astype(np.int32),
                                    pos.astype(np.float32), bool(np.ptp(pos, axis=0).max() > 0)))
    if not meshes:
        raise MeshError(f"{path}: the file has no mesh")
    return meshes, times
