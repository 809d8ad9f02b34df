"""Mesh sequences as cloth tools export them: fixed topology, positions per frame.

Formats: PC2 point caches (Blender, 3ds Max; little-endian), MDD point caches (LightWave, Blender;
big-endian), a folder of OBJ files (one per frame, same vertex order), NumPy `.npz` files with
`positions` (F, V, 3) and `triangles`/`faces` (as the shared newton simulation is stored), and USD
stages with time-sampled mesh points (renderer/usd.py) and glTF / GLB files with morph-target
animation (renderer/gltf_morph.py): in both, the moving meshes are the sequence, the still ones the body
beside it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MeshError
from .mesh import Mesh, concatenate, load_mesh


@dataclass(frozen=True)
class Sequence:
    """positions: float32 (F, V, 3) in the file's axes and units; faces: int32 (T, 3) or None when the
    format carries no topology (point caches: give --topology)."""

    positions: np.ndarray
    faces: np.ndarray | None
    name: str
    frame_times: np.ndarray | None = None
    converted: bool = False  # already in the renderer's Y-up axes and scale (OBJ folders, USD stages)
    # Meshes the file holds beside the sequence that do not move (a USD stage's body), in the
    # renderer's axes.
    extras: tuple[Mesh, ...] = ()
    # Each extra's positions per frame (F, V, 3), None where it holds still (a body that moves too).
    extra_frames: tuple[np.ndarray | None, ...] = ()

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])


def _check(positions: np.ndarray, name: str) -> np.ndarray:
    if positions.ndim != 3 or positions.shape[2] != 3 or positions.shape[0] == 0 or positions.shape[1] == 0:
        raise MeshError(f"{name}: expected positions of shape (frames, vertices, 3), got {positions.shape}")
    bad = ~np.isfinite(positions).all(axis=(1, 2))
    if bad.any():
        raise MeshError(f"{name}: {int(bad.sum())} frame(s) contain NaN or Inf positions, first frame {int(np.argmax(bad))}")
    return positions


def read_pc2(path: str | Path) -> Sequence:
    """PC2: 'POINTCACHE2\\0', int32 version, int32 points, float32 start frame, float32 sample rate,
    int32 samples, then samples x points x 3 float32, all little-endian."""
    path = Path(path)
    data = path.read_bytes()
    if len(data) < 32 or data[:12] != b"POINTCACHE2\0":
        raise MeshError(f"{path}: not a PC2 point cache (missing 'POINTCACHE2' header)")
    _version, n_points, start, rate, n_samples = struct.unpack("<iiffi", data[12:32])
    expected = 32 + n_samples * n_points * 12
    if n_points <= 0 or n_samples <= 0 or len(data) < expected:
        raise MeshError(f"{path}: PC2 header says {n_samples} frames of {n_points} points ({expected} bytes), "
                        f"the file has {len(data)} bytes")
    pos = np.frombuffer(data, "<f4", n_samples * n_points * 3, 32).reshape(n_samples, n_points, 3)
    times = start + rate * np.arange(n_samples, dtype=np.float64)
    return Sequence(_check(pos.astype(np.float32), str(path)), None, path.stem, times)


def write_pc2(path: str | Path, positions: np.ndarray, start: float = 0.0, rate: float = 1.0) -> None:
    positions = np.ascontiguousarray(positions, "<f4")
    header = b"POINTCACHE2\0" + struct.pack("<iiffi", 1, positions.shape[1], start, rate, positions.shape[0])
    Path(path).write_bytes(header + positions.tobytes())


def read_mdd(path: str | Path) -> Sequence:
    """MDD: int32 frames, int32 points, float32 times[frames], then frames x points x 3 float32,
    all big-endian."""
    path = Path(path)
    data = path.read_bytes()
    if len(data) < 8:
        raise MeshError(f"{path}: too short for an MDD point cache")
    n_frames, n_points = struct.unpack(">ii", data[:8])
    expected = 8 + 4 * n_frames + n_frames * n_points * 12
    if n_frames <= 0 or n_points <= 0 or len(data) < expected:
        raise MeshError(f"{path}: MDD header says {n_frames} frames of {n_points} points ({expected} bytes), "
                        f"the file has {len(data)} bytes")
    times = np.frombuffer(data, ">f4", n_frames, 8).astype(np.float64)
    pos = np.frombuffer(data, ">f4", n_frames * n_points * 3, 8 + 4 * n_frames).reshape(n_frames, n_points, 3)
    return Sequence(_check(pos.astype(np.float32), str(path)), None, path.stem, times)


def write_mdd(path: str | Path, positions: np.ndarray, fps: float = 30.0) -> None:
    positions = np.ascontiguousarray(positions, ">f4")
    f, v = positions.shape[:2]
    times = (np.arange(f) / fps).astype(">f4")
    Path(path).write_bytes(struct.pack(">ii", f, v) + times.tobytes() + positions.tobytes())


def read_npz(path: str | Path) -> Sequence:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            pos = np.asarray(z["positions"], np.float32)
            key = "triangles" if "triangles" in z.files else "faces" if "faces" in z.files else None
            faces = np.asarray(z[key], np.int32) if key else None
            times = np.asarray(z["frame_times_s"], np.float64) if "frame_times_s" in z.files else None
    except (OSError, KeyError, ValueError) as exc:
        raise MeshError(f"{path}: not a sequence .npz with a 'positions' array ({exc})") from exc
    return Sequence(_check(pos, str(path)), faces, path.stem, times)


def read_obj_folder(path: str | Path, up: str = "y", scale: float = 1.0) -> Sequence:
    files = sorted(Path(path).glob("*.obj"))
    if not files:
        raise MeshError(f"{path}: no .obj files in the folder")
    meshes = [load_mesh(f, up=up, scale=scale) for f in files]
    first = meshes[0]
    for f, m in zip(files, meshes):
        if m.positions.shape != first.positions.shape or not np.array_equal(m.faces, first.faces):
            raise MeshError(f"{f}: topology differs from {files[0].name} (a sequence needs the same vertices and faces)")
    return Sequence(np.stack([m.positions for m in meshes]), np.asarray(first.faces), Path(path).name,
                    converted=True)


def _by_role(meshes: list, source: str, scale: float, garment: str | None, what: str) -> tuple:
    """A file's meshes (each with .path, .name, .faces, .positions (F, V, 3) and .animated) split into
    the garment (merged) and the rest. `garment`: a glob over the paths or names naming the garment's
    meshes; without one, the moving meshes are the garment and the still ones the rest. Returns
    (positions, faces, extras (Meshes at the first frame), extra_frames (each extra's positions per
    frame, None where it holds still))."""
    import fnmatch

    if garment is not None:
        chosen = [m for m in meshes if fnmatch.fnmatchcase(m.path, garment) or fnmatch.fnmatchcase(m.name, garment)]
        if not chosen:
            raise MeshError(f"{source}: no mesh matches --garment {garment!r}; its meshes are "
                            + ", ".join(m.path for m in meshes))
    else:
        chosen = [m for m in meshes if m.animated]
        if not chosen:
            raise MeshError(f"{source}: no mesh of the file moves ({what}): nothing to play; render it with "
                            "`garment-render render --mesh`")
    rest = [m for m in meshes if all(m is not c for c in chosen)]
    k = np.float32(scale)
    positions, faces = concatenate((m.positions * k, m.faces) for m in chosen)
    extras = tuple(Mesh.from_arrays(m.positions[0] * k, m.faces, name=m.name) for m in rest)
    extra_frames = tuple(m.positions * k if m.animated else None for m in rest)
    return positions, faces.astype(np.int32), extras, extra_frames


def read_usd_sequence(path: str | Path, scale: float = 1.0, garment: str | None = None) -> Sequence:
    """A USD stage's garment as one sequence (several meshes are merged, a garment's panels), in the
    renderer's axes and metres from the stage's own metadata, times `scale`; its other meshes as
    `extras` (moving ones with their frames). `garment`: a glob over prim paths or names (default:
    the meshes that move)."""
    from .usd import read_usd

    data = read_usd(path)
    positions, faces, extras, frames = _by_role(data.meshes, str(path), scale, garment,
                                                "its points have no time samples")
    return Sequence(_check(positions, str(path)), faces, Path(path).stem, data.times, converted=True,
                    extras=extras, extra_frames=frames)


def read_gltf_sequence(path: str | Path, scale: float = 1.0, garment: str | None = None) -> Sequence:
    """A glTF / GLB file's morph-target animation as one sequence (renderer/gltf_morph.py), in glTF's
    Y-up metres times `scale`; `garment` and the other meshes as for a USD stage."""
    from .gltf_morph import read_morph_animation

    meshes, times = read_morph_animation(path)
    positions, faces, extras, frames = _by_role(meshes, str(path), scale, garment,
                                                "no morph-target animation nor moving node")
    return Sequence(_check(positions, str(path)), faces, Path(path).stem, times, converted=True, extras=extras,
                    extra_frames=frames)


def load_sequence(path: str | Path, up: str = "y", scale: float = 1.0, garment: str | None = None) -> Sequence:
    """Any supported sequence. Point caches are returned in their file's axes and units; OBJ folders
    already converted by `up` and `scale` (as load_mesh does); USD stages by their own metadata (up
    axis, metres per unit), then `scale`. `garment`: which of a USD stage's or glTF file's meshes are
    the garment (a glob over their paths or names; default: those that move)."""
    from .usd import USD_SUFFIXES

    path = Path(path)
    if path.is_dir():
        return read_obj_folder(path, up, scale)
    suffix = path.suffix.lower()
    readers = {".pc2": read_pc2, ".mdd": read_mdd, ".npz": read_npz}
    if suffix in USD_SUFFIXES:
        return read_usd_sequence(path, scale, garment)
    if suffix in (".glb", ".gltf"):
        return read_gltf_sequence(path, scale, garment)
    if suffix not in readers:
        raise MeshError(f"{path}: unknown sequence format {suffix!r}; use a folder of .obj files, .pc2, .mdd, .npz "
                        f"a USD stage ({', '.join(USD_SUFFIXES)}) or a glTF file with morph-target animation (.glb, .gltf)")
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    return readers[suffix](path)


def to_meshes(seq: Sequence, topology: Mesh | None, up: str = "y", scale: float = 1.0) -> tuple[Mesh, np.ndarray]:
    """The first frame as a validated Mesh and all frames' positions converted to the renderer's
    Y-up axes and the given scale: (mesh, positions float32 (F, V, 3))."""
    from .mesh import z_up_to_y_up

    pos = seq.positions
    if seq.faces is None and topology is None:
        raise MeshError(f"{seq.name}: a point cache has no faces; give the topology mesh (--topology)")
    faces = seq.faces if seq.faces is not None else topology.faces
    if topology is not None and topology.positions.shape[0] != pos.shape[1]:
        raise MeshError(f"{seq.name}: {pos.shape[1]} points per frame but the topology mesh has "
                        f"{topology.positions.shape[0]} vertices")
    if not seq.converted:
        if up == "z":
            pos = np.stack([z_up_to_y_up(p) for p in pos])
        pos = (pos * np.float32(scale)).astype(np.float32)
    mesh = Mesh.from_arrays(pos[0], faces, uvs=topology.uvs if topology is not None else None, name=seq.name)
    return mesh, pos
