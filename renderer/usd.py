"""Mesh sequences from USD stages (usd-core): time-sampled `points` of `UsdGeomMesh` prims, as
Warp's and newton's USD writers and CLO / Marvelous Designer exports write them.

A stage may hold several meshes: the garment's panels and the body it is draped on. Each mesh's
points are read at every time code any animated mesh has (a mesh without samples holds still), with
its prim's world transform at that time applied (the transforms may be animated too), then turned
into the renderer's axes: Y up (a Z-up stage is turned as `mesh.z_up_to_y_up` turns OBJ files) and
metres (the stage's metersPerUnit). Polygons are cut into triangles as fans (USD's faces are convex
in practice: its own renderers cut them the same way). Meshes whose points move are the sequence;
meshes that hold still are returned beside it (the body under a garment).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MeshError
from .mesh import z_up_to_y_up

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


@dataclass(frozen=True)
class UsdMesh:
    """One mesh prim: its path, triangles (T, 3) int32 and points per time code (F, V, 3) float32 in
    the renderer's axes and metres; `animated`: its points (or its transform) change over time."""

    path: str
    faces: np.ndarray
    positions: np.ndarray
    animated: bool

    @property
    def name(self) -> str:
        return self.path.rsplit("/", 1)[-1]


@dataclass(frozen=True)
class UsdStageData:
    meshes: list[UsdMesh]
    times: np.ndarray          # the time codes read, in seconds (timeCodesPerSecond)
    up_axis: str               # the stage's, "Y" or "Z"
    meters_per_unit: float


def _pxr():
    try:
        from pxr import Usd, UsdGeom
    except ImportError as exc:   # a user's install without the package
        raise MeshError("reading USD needs the usd-core package (pip install usd-core)") from exc
    return Usd, UsdGeom


def _triangulate(counts: np.ndarray, indices: np.ndarray, n_points: int, where: str) -> np.ndarray:
    """Fans over each polygon of faceVertexCounts / faceVertexIndices."""
    if (counts < 3).any():
        raise MeshError(f"{where}: a face has fewer than 3 vertices (faceVertexCounts)")
    if int(counts.sum()) != len(indices):
        raise MeshError(f"{where}: faceVertexCounts sum to {int(counts.sum())} but there are {len(indices)} "
                        "faceVertexIndices")
    if len(indices) and (indices.min() < 0 or indices.max() >= n_points):
        raise MeshError(f"{where}: faceVertexIndices reach outside the {n_points} points")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per_face = counts - 2                          # triangles per polygon
    face = np.repeat(np.arange(len(counts)), per_face)
    k = np.arange(int(per_face.sum())) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    first = starts[face]
    return np.stack([indices[first], indices[first + k + 1], indices[first + k + 2]], axis=1).astype(np.int32)


def read_usd(path: str | Path) -> UsdStageData:
    """Every mesh of a USD stage at every time code its meshes are sampled at."""
    Usd, UsdGeom = _pxr()
    path = Path(path)
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:   # pxr raises its own Tf.ErrorException on a malformed layer
        raise MeshError(f"{path}: not a USD stage ({str(exc).strip().splitlines()[-1] if str(exc) else exc})") from exc
    if stage is None:
        raise MeshError(f"{path}: not a USD stage")
    prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)
             and UsdGeom.Imageable(p).ComputePurpose() in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)]
    if not prims:
        raise MeshError(f"{path}: the stage has no mesh (UsdGeomMesh)")
    up = str(UsdGeom.GetStageUpAxis(stage)).upper()
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not np.isfinite(mpu) or mpu <= 0:
        raise MeshError(f"{path}: metersPerUnit must be a positive number, got {mpu}")
    # The time codes: every sample of any mesh's points or of any transform above a mesh.
    codes: set[float] = set()
    for p in prims:
        codes.update(UsdGeom.Mesh(p).GetPointsAttr().GetTimeSamples())
        q = p
        while q and not q.IsPseudoRoot():
            if q.IsA(UsdGeom.Xformable):
                for op in UsdGeom.Xformable(q).GetOrderedXformOps():
                    codes.update(op.GetAttr().GetTimeSamples())
            q = q.GetParent()
    times = sorted(codes) or [Usd.TimeCode.Default()]
    meshes = []
    for p in prims:
        geom = UsdGeom.Mesh(p)
        where = f"{path}:{p.GetPath()}"
        counts = np.asarray(geom.GetFaceVertexCountsAttr().Get() or [], np.int64)
        indices = np.asarray(geom.GetFaceVertexIndicesAttr().Get() or [], np.int64)
        frames = []
        for t in times:
            pts = geom.GetPointsAttr().Get(t)
            if pts is None or len(pts) == 0:
                raise MeshError(f"{where}: no points at time {t}")
            pts = np.asarray(pts, np.float64)
            m = np.asarray(geom.ComputeLocalToWorldTransform(t), np.float64)   # row vectors: p' = p M
            frames.append(pts @ m[:3, :3] + m[3, :3])
        n = {len(f) for f in frames}
        if len(n) != 1:
            raise MeshError(f"{where}: the point count changes over time ({sorted(n)}): a sequence needs one topology")
        pos = np.stack(frames)
        if not np.isfinite(pos).all():
            raise MeshError(f"{where}: NaN or Inf points")
        if up == "Z":
            pos = np.stack([z_up_to_y_up(f) for f in pos])
        pos = (pos * mpu).astype(np.float32)
        faces = _triangulate(counts, indices, pos.shape[1], where)
        if len(faces) == 0:
            raise MeshError(f"{where}: the mesh has no faces")
        meshes.append(UsdMesh(str(p.GetPath()), faces, pos, bool(np.ptp(pos, axis=0).max() > 0)))
    tps = float(stage.GetTimeCodesPerSecond()) or 24.0
    seconds = np.array([0.0 if isinstance(t, Usd.TimeCode) else t / tps for t in times])
    return UsdStageData(meshes, seconds, up, mpu)
