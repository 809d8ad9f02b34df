"""Triangle meshes: validated once at the boundary, immutable afterwards.

Conventions, pinned here for every pass that consumes a `Mesh`:
  * world space is right-handed, Y-up, metres (the same frame as `renderer/envmap/cube.py`);
  * a face (i0, i1, i2) is counter-clockwise seen from the side its normal points to, so
    cross(p1 - p0, p2 - p0) is the face normal scaled by twice the triangle's area;
  * vertex order is the source's order (files load with trimesh's `process=False, maintain_order=True`),
    so a simulator can stream new frames of positions for the same faces (`Mesh.with_positions`).
"""

from __future__ import annotations

import dataclasses
import operator
import os
import warnings
from collections.abc import Iterable
from enum import Enum
from pathlib import Path

import numpy as np

from .errors import InvalidInputError, MeshError

# GL index and draw counts are 32-bit signed (GLsizei / GLint), so neither may reach 2**31.
MAX_INDEX_COUNT = 2**31 - 1
MAX_VERTEX_COUNT = 2**31 - 1
# Largest vertex coordinate (metres): every product of two coordinates (a squared distance, the
# projection's far * near) then stays within float32's range (2^120 < 2^128), so that no matrix the
# renderer uploads overflows. A garment is metres across; 2^60 m is 10^18.
MAX_COORDINATE = 2.0**60

# A triangle whose height over its longest edge is below this ratio has no usable normal at float32
# precision; it counts as degenerate in `MeshStats` (it is kept and adds ~nothing to vertex normals).
_DEGENERATE_HEIGHT_RATIO = 1e-6

# Normal of a vertex that no triangle with area touches (isolated, degenerate-only, or whose
# face normals cancel exactly): "up" rather than NaN, so shading stays finite.
FALLBACK_NORMAL = (0.0, 1.0, 0.0)

_CONSTRUCT = object()  # only `Mesh.from_arrays` and friends hold this, so every Mesh is validated


class UpAxis(str, Enum):
    """Up axis of a source asset; the renderer's world is Y-up."""

    Y = "y"
    Z = "z"


def z_up_to_y_up(positions: np.ndarray) -> np.ndarray:
    """Rotate Z-up coordinates (..., 3) into the Y-up world: (x, y, z) -> (x, z, -y).

    A proper rotation (-90 degrees about +X, determinant +1), so handedness and face winding are
    kept. Returns float32 of the same shape.
    """
    p = np.asarray(positions)
    if p.shape[-1:] != (3,):
        raise MeshError(f"z_up_to_y_up expects positions of shape (..., 3); got {p.shape}")
    out = np.empty(p.shape, np.float32)
    out[..., 0] = p[..., 0]
    out[..., 1] = p[..., 2]
    out[..., 2] = -p[..., 1]
    return out


@dataclasses.dataclass(frozen=True)
class MeshStats:
    """Counts worth logging or exposing for a mesh; nothing here makes a mesh invalid."""

    n_vertices: int
    n_faces: int
    n_degenerate: int  # zero-area triangles (repeated index, coincident or collinear vertices)
    n_duplicate_vertices: int  # vertices at exactly the same position as an earlier one (seams)
    n_unreferenced: int  # vertices no face uses (they get the fallback normal)
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]]  # (lo, hi), object space


@dataclasses.dataclass(frozen=True, eq=False)
class Mesh:
    """An immutable triangle mesh. Build it with `Mesh.from_arrays` or `load_mesh`.

    positions: float32 (V, 3), read-only, object space (Y-up, metres for anything rendered as-is).
    faces:     int32 (F, 3), read-only, indices into positions, counter-clockwise front faces.
    uvs:       float32 (V, 2) read-only per-vertex texture coordinates, or None.
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    name: str = "mesh"
    _token: object = dataclasses.field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self._token is not _CONSTRUCT:
            raise TypeError("construct a Mesh with Mesh.from_arrays(positions, faces, uvs, name) so it is validated")

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def from_arrays(
        cls,
        positions: np.ndarray,
        faces: np.ndarray,
        uvs: np.ndarray | None = None,
        name: str = "mesh",
    ) -> Mesh:
        """Validate and copy arrays into a Mesh.

        positions: (V, 3) real numbers, any float/int dtype; stored as float32 (values beyond float32
            range become Inf and are rejected). faces: (F, 3) integer indices in [0, V).
        uvs: optional (V, 2) per-vertex texture coordinates. Raises MeshError naming what to fix.
        Degenerate triangles and duplicate vertices are accepted (see `stats`).
        """
        name = str(name)
        p = _positions_array(positions, name, "positions")
        f = _faces_array(faces, p.shape[0], name)
        p = _finite_float32(p, name, "positions")
        uv = None if uvs is None else _uvs_array(uvs, p.shape[0], name)
        return cls(p, f, uv, name, _CONSTRUCT)

    @classmethod
    def positions_from_bytes(cls, buf: bytes | bytearray | memoryview, n_vertices: int) -> np.ndarray:
        """Decode one frame of raw little-endian float32 xyz triples into float32 (V, 3), read-only.

        `buf` must hold exactly 12 * n_vertices bytes; NaN/Inf are rejected like in `from_arrays`.
        """
        n = _vertex_count(n_vertices)
        try:
            nbytes = memoryview(buf).nbytes
        except TypeError as e:
            raise MeshError(f"a frame of positions must be bytes-like; got {type(buf).__name__}") from e
        expected = 12 * n
        if nbytes != expected:
            hint = ""
            if nbytes == 2 * expected:
                hint = " (twice the size: float64 data? send float32)"
            elif nbytes % 12 == 0:
                hint = f" (that is {nbytes // 12} vertices: a frame of a different mesh?)"
            raise MeshError(
                f"a frame of {n} vertices needs {expected} bytes ({n} x 3 little-endian float32); "
                f"got {nbytes} bytes{hint}"
            )
        p = np.frombuffer(buf, dtype="<f4").reshape(n, 3)
        return _finite_float32(p, "frame", "positions")

    def with_positions(self, new_positions: np.ndarray | bytes | bytearray | memoryview) -> Mesh:
        """The same faces and UVs with a new frame of positions.

        new_positions: (V, 3) real array in this mesh's vertex order, or raw little-endian float32
        bytes (see `positions_from_bytes`). Only the positions are validated: the topology already was.
        """
        if isinstance(new_positions, (bytes, bytearray, memoryview)):
            p = Mesh.positions_from_bytes(new_positions, self.n_vertices)
        else:
            p = _positions_array(new_positions, self.name, "new positions", n_expected=self.n_vertices)
            p = _finite_float32(p, self.name, "new positions")
        return Mesh(p, self.faces, self.uvs, self.name, _CONSTRUCT)

    # --- queries ------------------------------------------------------------------------------

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def stats(self) -> MeshStats:
        """Counts of degenerate triangles, duplicate and unreferenced vertices, and the bounds."""
        p = self.positions.astype(np.float64)
        f = self.faces
        a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
        e1, e2, e3 = b - a, c - a, c - b
        twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
        longest_sq = np.maximum(np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1)), (e3 * e3).sum(1))
        # 2 * area = longest * height, so this compares height / longest with the ratio
        # (and counts triangles whose three vertices coincide, where both sides are 0).
        degenerate = twice_area <= _DEGENERATE_HEIGHT_RATIO * longest_sq
        used = np.bincount(f.ravel(), minlength=self.n_vertices) > 0
        n_unique = np.unique(self.positions, axis=0).shape[0]
        lo, hi = self.positions.min(axis=0), self.positions.max(axis=0)
        return MeshStats(
            n_vertices=self.n_vertices,
            n_faces=self.n_faces,
            n_degenerate=int(degenerate.sum()),
            n_duplicate_vertices=self.n_vertices - int(n_unique),
            n_unreferenced=int((~used).sum()),
            bounds=(tuple(float(x) for x in lo), tuple(float(x) for x in hi)),
        )


# --- validation helpers (each raises MeshError with the mesh name and what to do) -------------


def _vertex_count(n_vertices: int) -> int:
    try:
        n = operator.index(n_vertices)
    except TypeError as e:
        raise MeshError(f"n_vertices must be an integer; got {type(n_vertices).__name__}") from e
    if not 0 < n <= MAX_VERTEX_COUNT:
        raise MeshError(f"n_vertices must be in 1..{MAX_VERTEX_COUNT}; got {n}")
    return n


def _real_array(x: object, name: str, what: str, kinds: str) -> np.ndarray:
    try:
        a = np.asarray(x)
    except (ValueError, TypeError) as e:  # ragged nested lists
        raise MeshError(f"mesh '{name}': {what} is not a rectangular array ({e})") from e
    if a.dtype.kind not in kinds:
        wanted = "integer" if kinds == "iu" else "real numeric"
        raise MeshError(f"mesh '{name}': {what} must be a {wanted} array; got dtype {a.dtype}")
    return a


def _positions_array(x: object, name: str, what: str, n_expected: int | None = None) -> np.ndarray:
    a = _real_array(x, name, what, "fiu")
    if a.ndim != 2 or a.shape[1] != 3:
        hint = " (a flat xyz array? use .reshape(-1, 3))" if a.ndim == 1 and a.size % 3 == 0 else ""
        raise MeshError(f"mesh '{name}': {what} must have shape (V, 3); got {a.shape}{hint}")
    n = a.shape[0]
    if n == 0:
        raise MeshError(f"mesh '{name}' is empty: {what} has 0 vertices")
    if n > MAX_VERTEX_COUNT:
        raise MeshError(f"mesh '{name}': {n} vertices exceed the 32-bit index limit {MAX_VERTEX_COUNT}; split the mesh")
    if n_expected is not None and n != n_expected:
        raise MeshError(
            f"mesh '{name}': {what} has {n} vertices but the mesh has {n_expected}; a new frame must keep the "
            "vertex count and order of the faces (load a new mesh when the topology changes)"
        )
    return a


def _finite_float32(a: np.ndarray, name: str, what: str) -> np.ndarray:
    with np.errstate(over="ignore"):  # float64 beyond float32 range becomes Inf, reported below
        p = np.array(a, dtype=np.float32, order="C", copy=True)
    finite = np.isfinite(p)
    if not finite.all():
        bad = np.flatnonzero(~finite.all(axis=1))
        first = int(bad[0])
        raise MeshError(
            f"mesh '{name}': {what} has NaN/Inf in {bad.size} of {p.shape[0]} vertices (first at vertex {first}: "
            f"{tuple(float(v) for v in np.asarray(a[first], np.float64))}); values beyond float32 range count as Inf. "
            "Fix the source frame (a diverged simulation?) before sending it"
        )
    big = np.abs(p) > MAX_COORDINATE
    if big.any():
        first = int(np.flatnonzero(big.any(axis=1))[0])
        raise MeshError(
            f"mesh '{name}': {what} has coordinates beyond +-{MAX_COORDINATE:.3g} in {int(big.any(axis=1).sum())} of "
            f"{p.shape[0]} vertices (first at vertex {first}: {tuple(float(v) for v in p[first])}); positions are "
            "in metres, and beyond that bound the renderer's float32 matrices overflow")
    if p.shape[0] > 1 and not (p != p[0]).any():
        raise MeshError(
            f"mesh '{name}': {what}: all {p.shape[0]} vertices coincide at {tuple(float(v) for v in p[0])}, so "
            "there is no surface to render (a collapsed or zeroed simulation frame?)")
    _check_strays(p, name, what)
    p.setflags(write=False)
    return p


# A vertex this many times farther from the mesh's middle than 99 % of its vertices is a stray (a
# solver's blow-up, a zeroed index): framed, it would shrink the garment to a dot.
STRAY_RATIO = 1000.0
_STRAY_SAMPLE = 4096   # vertices the 99 % reach is taken from (a large mesh's frame stays cheap)


def _check_strays(p: np.ndarray, name: str, what: str) -> None:
    """MeshError naming the first stray vertex (STRAY_RATIO) and how far it lies, else nothing."""
    if p.shape[0] < 16:
        return
    sample = p[:: max(1, p.shape[0] // _STRAY_SAMPLE)].astype(np.float64)
    middle = np.median(sample, axis=0)
    reach = float(np.percentile(np.linalg.norm(sample - middle, axis=1), 99.0))
    lo, hi = p.min(axis=0).astype(np.float64), p.max(axis=0).astype(np.float64)
    if reach <= 0.0 or float(np.linalg.norm(hi - lo)) <= STRAY_RATIO * reach:
        return
    far = np.linalg.norm(p.astype(np.float64) - middle, axis=1) > STRAY_RATIO * reach
    if not far.any():
        return
    first = int(np.flatnonzero(far)[0])
    raise MeshError(
        f"mesh '{name}': {what}: {int(far.sum())} of {p.shape[0]} vertices lie more than {STRAY_RATIO:g} times "
        f"farther from the mesh's middle than 99 % of the others (first: vertex {first} at "
        f"{tuple(round(float(v), 3) for v in p[first])}, {float(np.linalg.norm(p[first] - middle)):.4g} from the "
        f"middle, the rest within {reach:.3g}): stray vertices from the simulation? fix or drop them")


def _faces_array(x: object, n_vertices: int, name: str) -> np.ndarray:
    a = _real_array(x, name, "faces", "iu")
    if a.ndim != 2 or a.shape[1] != 3:
        hint = ""
        if a.ndim == 2 and a.shape[1] > 3:
            hint = " (quads or polygons? triangulate first)"
        elif a.ndim == 1 and a.size % 3 == 0:
            hint = " (a flat index array? use .reshape(-1, 3))"
        raise MeshError(f"mesh '{name}': faces must have shape (F, 3) of vertex indices; got {a.shape}{hint}")
    if a.shape[0] == 0:
        raise MeshError(f"mesh '{name}' is empty: 0 faces (point clouds cannot be rendered)")
    # Checked on the shape alone, before any pass over the data (the array may be a broadcast view).
    if a.size > MAX_INDEX_COUNT:
        raise MeshError(
            f"mesh '{name}': {a.shape[0]} faces = {a.size} indices, more than the {MAX_INDEX_COUNT} one draw "
            "call can address with 32-bit counts; split the mesh"
        )
    lo, hi = int(a.min()), int(a.max())
    if lo < 0:
        rows = np.flatnonzero((a < 0).any(axis=1))
        raise MeshError(
            f"mesh '{name}': {rows.size} faces have negative vertex indices (first: face {rows[0]} = "
            f"{a[rows[0]].tolist()}); indices are 0-based into the {n_vertices} vertices"
        )
    if hi >= n_vertices:
        rows = np.flatnonzero((a >= n_vertices).any(axis=1))
        hint = " (1-based indices, as in OBJ? subtract 1)" if hi == n_vertices else ""
        raise MeshError(
            f"mesh '{name}': {rows.size} faces index past the {n_vertices} vertices (valid 0..{n_vertices - 1}; "
            f"largest index {hi}; first: face {rows[0]} = {a[rows[0]].tolist()}){hint}"
        )
    f = a.astype(np.int32, order="C", copy=True)  # safe: every value is in [0, n_vertices)
    f.setflags(write=False)
    return f


def _uvs_array(x: object, n_vertices: int, name: str) -> np.ndarray:
    a = _real_array(x, name, "uvs", "fiu")
    if a.shape != (n_vertices, 2):
        raise MeshError(
            f"mesh '{name}': uvs must be per-vertex with shape ({n_vertices}, 2); got {a.shape} "
            "(per-corner UVs need the vertices split at UV seams first)"
        )
    uv = np.array(a, dtype=np.float32, order="C", copy=True)
    finite = np.isfinite(uv).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise MeshError(f"mesh '{name}': uvs have NaN/Inf at {bad.size} vertices (first at vertex {bad[0]})")
    uv.setflags(write=False)
    return uv


# --- geometry ---------------------------------------------------------------------------------


def vertex_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, float32 (V, 3), in the space of `positions`.

    positions: (V, 3) float; faces: (F, 3) int with indices in [0, V) (a `Mesh` guarantees both).
    Each vertex sums cross(p1 - p0, p2 - p0) of its faces, whose length is twice the face area: the
    area weighting comes free. Vertices whose sum vanishes (isolated, only degenerate faces, or
    opposite faces cancelling) get FALLBACK_NORMAL instead of NaN.
    """
    p = np.asarray(positions)
    f = np.asarray(faces)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"vertex_normals: positions must have shape (V, 3); got {p.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        raise MeshError(f"vertex_normals: faces must be integer (F, 3); got {f.dtype} {f.shape}")
    n_vertices = p.shape[0]
    # float32 like the Mesh itself: edges are differences of nearby float32 values, so the cross
    # products lose nothing that matters, and half the memory traffic makes this ~1.5x faster.
    p = p.astype(np.float32, copy=False)
    corner_major = np.ascontiguousarray(f.T, dtype=np.intp)  # (3, F): corner k of every face
    # np.take per coordinate is ~3x faster than fancy-indexing rows of p.
    x, y, z = (np.take(p[:, c], corner_major) for c in range(3))
    ax, ay, az = x[1] - x[0], y[1] - y[0], z[1] - z[0]
    bx, by, bz = x[2] - x[0], y[2] - y[0], z[2] - z[0]
    face_n = (ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx)
    twice_area = np.sqrt(face_n[0] ** 2 + face_n[1] ** 2 + face_n[2] ** 2)
    # bincount scatters into shared vertices several times faster than np.add.at; the weights are
    # tiled to match the corner-major order of the indices.
    corners = corner_major.ravel()
    sx, sy, sz, area_sum = (
        np.bincount(corners, weights=np.tile(w, 3), minlength=n_vertices) for w in (*face_n, twice_area)
    )
    length = np.sqrt(sx * sx + sy * sy + sz * sz)
    # Relative test: a sum that nearly cancels is rounding noise with no meaningful direction.
    ok = np.isfinite(length) & (length > 1e-6 * area_sum) & (length > 0.0)
    inv = np.zeros(n_vertices)
    np.divide(1.0, length, out=inv, where=ok)
    out = np.empty((n_vertices, 3), np.float32)
    out[:, 0], out[:, 1], out[:, 2] = sx * inv, sy * inv, sz * inv
    out[~ok] = FALLBACK_NORMAL
    return out


def _as_mesh_list(meshes: Mesh | Iterable[Mesh]) -> list[Mesh]:
    items = [meshes] if isinstance(meshes, Mesh) else list(meshes)
    if not items:
        raise InvalidInputError("no meshes given: bounds need at least one mesh")
    for m in items:
        if not isinstance(m, Mesh):
            raise InvalidInputError(f"expected Mesh objects; got {type(m).__name__}")
    return items


def concatenate(parts) -> tuple[np.ndarray, np.ndarray]:
    """Several meshes' (positions, faces) as one: the positions joined along their vertex axis (the
    last but one: (V, 3), or (F, V, 3) for sequences), each part's faces offset by the vertices
    before it."""
    parts = list(parts)
    offsets = np.cumsum([0] + [np.shape(p)[-2] for p, _ in parts[:-1]])
    return (np.concatenate([p for p, _ in parts], axis=-2),
            np.concatenate([np.asarray(f) + o for (_, f), o in zip(parts, offsets)]))


def box(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) of (V, 3) positions (V >= 1), two float64 (3,). Reduced per column
    of a transposed copy: `positions.min(axis=0)` walks rows of three and took 5 ms for 100k
    vertices here, 20-40x longer (a real share of a frame on a GPU)."""
    columns = np.ascontiguousarray(np.asarray(positions).reshape(-1, 3).T)
    return columns.min(axis=1).astype(np.float64), columns.max(axis=1).astype(np.float64)


def box_corners(lo, hi) -> np.ndarray:
    """The eight corners (8, 3) float64 of box (lo, hi); corner k takes hi on x if bit 2 of k is set,
    on y bit 1, on z bit 0 (corners k and k ^ 1, k ^ 2, k ^ 4 share an edge)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    k = np.arange(8)[:, None]
    return np.where((k >> np.array([2, 1, 0])) & 1, hi, lo)


def bounds(meshes: Mesh | Iterable[Mesh]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) around all vertices of one or several meshes: two float64 (3,)."""
    boxes = [box(m.positions) for m in _as_mesh_list(meshes)]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def bounding_sphere(meshes: Mesh | Iterable[Mesh]) -> tuple[np.ndarray, float]:
    """Sphere (centre float64 (3,), radius > 0) containing every vertex; centred on the bounding box.

    Not the minimal sphere, but at most sqrt(3)/2 of the box diagonal and cheap. A single point gets
    radius 1e-6 * max(1, |centre|), so camera fitting never divides by zero.
    """
    items = _as_mesh_list(meshes)
    lo, hi = bounds(items)
    centre = 0.5 * (lo + hi)
    radius = max(float(np.sqrt(((m.positions - centre) ** 2).sum(axis=1).max())) for m in items)
    floor = 1e-6 * max(1.0, float(np.linalg.norm(centre)))
    return centre, max(radius, floor)


# --- files ------------------------------------------------------------------------------------

_FORMATS = (".obj", ".ply", ".glb", ".gltf", ".stl")


def load_mesh(path: str | os.PathLike, up: UpAxis | str = "y", scale: float = 1.0) -> Mesh:
    """Read OBJ, PLY, GLB/glTF or STL into one Y-up Mesh, keeping the file's vertex order.

    up: the file's up axis; "z" is rotated into Y-up with `z_up_to_y_up`. scale: multiplies positions
    (0.01 for centimetres). Several geometries are concatenated (scene transforms applied). UVs are
    kept when every part has per-vertex UVs; an OBJ with UV seams gets one UV per position (trimesh
    picks the most common one), because splitting vertices would break the vertex order.
    """
    path = Path(path)
    axis = _up_axis(up)
    if not (isinstance(scale, (int, float, np.floating, np.integer)) and np.isfinite(scale) and scale > 0):
        # Negative scale would mirror the mesh and flip every face's winding.
        raise InvalidInputError(f"scale must be a finite number > 0; got {scale!r}")
    if path.suffix.lower() not in _FORMATS:
        raise MeshError(f"cannot read mesh file '{path}': unsupported extension; use one of {', '.join(_FORMATS)}")
    if not path.is_file():
        raise MeshError(f"cannot read mesh file '{path}': no such file")
    positions, faces, uvs = _read_with_trimesh(path)
    positions = positions * float(scale)
    if axis is UpAxis.Z:
        positions = z_up_to_y_up(positions)
    try:
        return Mesh.from_arrays(positions, faces, uvs, name=path.stem)
    except MeshError as e:
        raise MeshError(f"mesh file '{path}': {e}") from e


def _up_axis(up: UpAxis | str) -> UpAxis:
    try:
        return UpAxis(up.lower() if isinstance(up, str) else up)
    except ValueError:
        raise InvalidInputError(f"up must be one of {[a.value for a in UpAxis]}; got {up!r}") from None


def triangle_parts(scene):
    """(trimesh.Trimesh, world transform (4, 4)) of a trimesh scene's triangle geometries, in the order
    `load_mesh` stacks them (point clouds and curves are not renderable surfaces)."""
    import trimesh

    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0:
            yield geom, transform


def _read_with_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import trimesh  # only the file loader needs it

    try:
        with warnings.catch_warnings():
            # trimesh's OBJ loader with maintain_order takes a nanmedian over unreferenced vertices
            # of multi-material files: harmless RuntimeWarnings that would flood the log.
            warnings.simplefilter("ignore", RuntimeWarning)
            scene = trimesh.load_scene(path, process=False, maintain_order=True)
    except Exception as e:  # trimesh raises anything from ValueError to struct.error on a bad file
        raise MeshError(f"cannot read mesh file '{path}': {type(e).__name__}: {e}") from e

    parts = []  # (positions float64 (n, 3), faces (m, 3), uvs or None, is_identity_transform)
    for geom, transform in triangle_parts(scene):
        v = np.asarray(geom.vertices, np.float64)
        f = np.asarray(geom.faces, np.int64)
        t = np.asarray(transform, np.float64)
        identity = np.allclose(t, np.eye(4))
        if not identity:
            v = v @ t[:3, :3].T + t[:3, 3]
            if np.linalg.det(t[:3, :3]) < 0:
                f = f[:, ::-1]  # a mirroring node transform would turn faces inside out
        uv = getattr(geom.visual, "uv", None)
        uv = np.asarray(uv, np.float64) if uv is not None and len(uv) == len(v) else None
        parts.append((v, f, uv, identity))
    if not parts:
        raise MeshError(f"cannot read mesh file '{path}': it contains no triangles")
    if len(parts) == 1:
        v, f, uv, _ = parts[0]
        return v, f, uv

    if path.suffix.lower() == ".obj" and all(p[3] for p in parts):
        merged = _merge_obj_chunks(parts)
        if merged is not None:
            return merged
    # Independent geometries (GLB nodes, ...): stack them, offsetting each part's indices.
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    positions = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[1] + o for p, o in zip(parts, offsets)])
    uvs = np.concatenate([p[2] for p in parts]) if all(p[2] is not None for p in parts) else None
    return positions, faces, uvs


def _merge_obj_chunks(parts: list) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """Re-join an OBJ that trimesh split at `usemtl` lines into the file's single vertex list.

    With maintain_order, trimesh gives every chunk a prefix of the file's 'v' list and leaves the
    face indices global, so the longest prefix plus all faces is the file as written. Returns None
    when the chunks are not prefixes of one list (then they are stacked as independent parts).
    """
    longest = max(parts, key=lambda p: len(p[0]))[0]
    if not all(np.array_equal(p[0], longest[: len(p[0])]) for p in parts):
        return None
    faces = np.concatenate([p[1] for p in parts])
    uvs = None
    if all(p[2] is not None for p in parts):
        uvs = np.full((len(longest), 2), np.nan)
        for _, f, uv, _ in parts:
            used = np.unique(f)
            uvs[used] = uv[used]
        if np.isnan(uvs[np.unique(faces)]).any():
            uvs = None
        else:
            uvs = np.nan_to_num(uvs)  # unreferenced vertices: any UV will do
    return longest, faces, uvs
