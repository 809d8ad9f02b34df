"""Coarser shadow casters: the same vertices, fewer triangles.

A shadow map on llvmpipe costs about the same per triangle whatever its size (the 48 maps of a
17k-triangle garment take 75 ms at 64^2 and 120 ms at 256^2), so the pass is bound by triangles,
not texels. A proxy made by half-edge collapses (quadric error order, fast_simplification, on the
mesh as first registered) keeps a subset of the original vertices: its triangles index the same
vertex buffer, so it follows the cloth frame after frame with no per-frame work, and only its index
buffer is new. What it costs in accuracy is measured by the benchmark (`caster_detail`).

The shadow pass draws front faces only (`shadow_faces`): a map keeps each texel's nearest surface,
and from outside a closed surface that is one facing the light, so the far side's triangles were
rasterized for nothing (about a third of the pass on llvmpipe). Cloth is two-sided and its winding is
the source's, so the triangles are split into pieces that are wound one way throughout (neighbours
joined by an edge they run along in opposite directions), each piece is turned to face outwards by
its signed volume, and a piece whose way out is not clear (a flat sheet) is drawn both ways.
"""

from __future__ import annotations

import threading

import numpy as np

from ..errors import InvalidInputError

# fast_simplification keeps the mesh being simplified in global state across its load / simplify /
# read-back calls: one simplification at a time per process.
_LOCK = threading.Lock()


def caster_proxy(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    """Triangles (M, 3) int32 over the same vertices, about `keep` times as many as `faces`
    (0 < keep <= 1; 1 returns `faces`). Triangles that collapse to a line or point are dropped, and so
    are duplicates."""
    if not (0.0 < keep <= 1.0):
        raise InvalidInputError(f"caster_detail is the share of triangles kept, in (0, 1], got {keep}")
    faces = np.ascontiguousarray(faces, np.int32)
    target = int(round(keep * len(faces)))
    if keep >= 1.0 or len(faces) < 16 or target >= len(faces):
        return faces
    import fast_simplification

    # Fresh writable copies: the extension rejects read-only arrays (a Mesh's are).
    with _LOCK:
        _, _, collapses = fast_simplification.simplify(np.array(positions, np.float64), np.array(faces, np.int32),
                                                       target_count=max(target, 4), return_collapses=True)
    survivor = np.arange(len(positions), dtype=np.int64)
    # collapses[k] = (a, b): vertex b merged into a. Later collapses can merge a survivor again, so
    # follow the chains to their end (pointer jumping: log2 of the longest chain rounds).
    if len(collapses):
        survivor[collapses[:, 1]] = collapses[:, 0]
        for _ in range(64):   # 2^64 collapses deep: more than any mesh has
            nxt = survivor[survivor]
            if np.array_equal(nxt, survivor):
                break
            survivor = nxt
        else:
            raise InvalidInputError("caster proxy: the simplification's collapse history has a cycle")
    f = survivor[faces]
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[ok]
    # Drop duplicates whatever their winding (two sheets collapsed onto one another).
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return np.ascontiguousarray(f[np.sort(first)], np.int32)


# An open piece faces out when its volume, closed by cones from its centroid to its openings, is at
# least this share of a sphere's for its area and radius (V = A r / 3): a garment around a body reads
# 0.4-0.6, the GarmentCode body 0.22 (closed: its sign alone decides), a flat sheet 0.
OPEN_OUTWARD = 0.25


def light_facing(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """`faces` wound so that culling back faces keeps every texel's nearest surface: each piece
    (triangles joined by edges they wind the same way) facing outwards, a piece whose outside is not
    clear twice, once each way. Made on the mesh as registered."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.ascontiguousarray(faces, np.int32)
    n = len(faces)
    if n == 0:
        return faces
    # Each triangle's three edges; two triangles are one piece where they share an edge (and no third
    # does) in opposite directions, as a consistently wound surface does.
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).astype(np.int64)
    forward = directed[:, 0] < directed[:, 1]
    key = np.sort(directed, axis=1)
    _, edge, uses = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    edge = edge.ravel()
    order = np.argsort(edge, kind="stable")
    shared = uses[edge[order]] == 2
    first, second = order[shared][0::2], order[shared][1::2]
    joined = forward[first] != forward[second]
    a, b = first[joined] // 3, second[joined] // 3
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    count, piece = connected_components(graph, directed=False)
    # A piece is closed when every edge of its triangles joins two of them.
    edges_joined = np.bincount(np.concatenate([a, b]), minlength=n)
    open_piece = np.bincount(piece, weights=(edges_joined < 3), minlength=count) > 0
    # Signed volume of each piece closed by cones from its centroid to its openings, against a
    # sphere's for its area and mean radius.
    p = np.asarray(positions, np.float64)[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    total = np.bincount(piece, area, count)
    centre = p.mean(axis=1)
    centroid = np.stack([np.bincount(piece, area * centre[:, k], count) for k in range(3)], axis=1)
    centroid /= np.maximum(total, 1e-300)[:, None]
    rel = p - centroid[piece][:, None, :]
    volume = np.bincount(piece, np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2])) / 6.0, count)
    radius = np.bincount(piece, area * np.linalg.norm(rel.mean(axis=1), axis=1), count) / np.maximum(total, 1e-300)
    share = volume / np.maximum(total * radius / 3.0, 1e-300)
    decided = np.where(open_piece, np.abs(share) >= OPEN_OUTWARD, share != 0.0)
    sign = np.where(decided, np.sign(share), 0.0)[piece]
    out = np.concatenate([faces[sign > 0], faces[sign < 0][:, ::-1], faces[sign == 0], faces[sign == 0][:, ::-1]])
    return np.ascontiguousarray(out, np.int32)


def shadow_faces(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    """The shadow pass's triangles at a share `keep` of the mesh's: the proxy, light facing."""
    return light_facing(positions, caster_proxy(positions, faces, keep))


# Above this many triangles the shadow pass's triangles are made in a child process: fast_simplification
# holds the GIL for the whole simplification (1.8 s for 1.3M triangles on this machine), which would
# stall every other thread of a service (its event loop, its GL thread) meanwhile.
ISOLATE_ABOVE = 200_000


def shadow_faces_isolated(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    """`shadow_faces`, in a child process for large meshes so that the caller's other threads run on."""
    if len(faces) <= ISOLATE_ABOVE:
        return shadow_faces(positions, faces, keep)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_in_child, np.asarray(positions), np.asarray(faces), keep).result()


def _in_child(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    return shadow_faces(positions, faces, keep)
