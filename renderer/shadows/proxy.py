"""Coarser shadow casters: the same vertices, fewer triangles.

A shadow map on llvmpipe costs about the same per triangle whatever its size (the 48 maps of a
17k-triangle garment take 75 ms at 64^2 and 120 ms at 256^2), so the pass is bound by triangles,
not texels. A proxy made by half-edge collapses (quadric error order, fast_simplification, on the
mesh as first registered) keeps a subset of the original vertices: its triangles index the same
vertex buffer, so it follows the cloth frame after frame with no per-frame work, and only its index
buffer is new. What it costs in accuracy is measured by the benchmark (`caster_detail`).
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


# Above this many triangles a proxy is made in a child process: fast_simplification holds the GIL for
# the whole simplification (1.8 s for 1.3M triangles on this machine), which would stall every other
# thread of a service (its event loop, its GL thread) meanwhile.
ISOLATE_ABOVE = 200_000


def caster_proxy_isolated(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    """`caster_proxy`, in a child process for large meshes so that the caller's other threads run on."""
    if keep >= 1.0 or len(faces) <= ISOLATE_ABOVE:
        return caster_proxy(positions, faces, keep)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_in_child, np.asarray(positions), np.asarray(faces), keep).result()


def _in_child(positions: np.ndarray, faces: np.ndarray, keep: float) -> np.ndarray:
    return caster_proxy(positions, faces, keep)
