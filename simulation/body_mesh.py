"""The mannequin as the renderer sees it: one smooth closed surface instead of overlapping capsules,
and the floor as a mesh of its own (the renderer takes it as a receiver of shadows only).

The surface is the zero set of a smooth union of the proxy's capsules, polygonised with naive
surface nets (Gibson, "Constrained elastic SurfaceNets", 1998: one vertex per grid cell the surface
crosses, one quad per grid edge it crosses) and each vertex then moved onto the zero set by Newton
steps. The smooth union is the quadratic smooth minimum of each capsule in turn (Quilez, "smooth
minimum", 2013):

    smin(a, b) = min(a, b) - k h^2 / 4,   h = max(k - |a - b|, 0) / k

which equals min(a, b) wherever the two distances differ by more than k, and is at most k / 4 below
it: the render surface lies on the proxy except in the creases (neck, armpits, waist, crotch),
where it fills them by at most k / 4 per shape met. With k / 4 under the cloth's thickness the cloth,
which keeps the thickness from the proxy, never sinks into the body it is drawn on.
"""

from __future__ import annotations

import numpy as np

from .proxy import BodyProxy


def smooth_distance(body: BodyProxy, points: np.ndarray, blend_m: float, chunk: int = 65536) -> np.ndarray:
    """Smooth-union distance of the capsules (floor excluded) at points (N, 3) metres -> (N,)."""
    points = np.asarray(points, np.float64)
    out = np.empty(len(points))
    r = np.array([c.radius for c in body.capsules])
    for lo in range(0, len(points), chunk):
        p = points[lo:lo + chunk]
        d = np.linalg.norm(p[:, None, :] - body.closest_axis_points(p), axis=-1) - r[None]
        acc = d[:, 0]
        for c in range(1, d.shape[1]):
            h = np.maximum(blend_m - np.abs(acc - d[:, c]), 0.0) / blend_m
            acc = np.minimum(acc, d[:, c]) - 0.25 * blend_m * h * h
        out[lo:lo + chunk] = acc
    return out


def body_mesh(body: BodyProxy, blend_m: float = 0.03, cell_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """The smooth surface of the body's capsules (no floor): positions (V, 3) float32 metres,
    faces (F, 3) int32 counter-clockwise seen from outside. blend_m: the smooth union's k; cell_m:
    the polygonising grid's cell (about one vertex per cell_m^2 of surface)."""
    if not body.capsules:
        raise ValueError("the body has no capsules")
    a = np.array([c.a for c in body.capsules])
    b = np.array([c.b for c in body.capsules])
    r = np.array([c.radius for c in body.capsules])[:, None]
    lo = np.minimum(a, b).min(0) - r.max() - 3 * cell_m
    hi = np.maximum(a, b).max(0) + r.max() + 3 * cell_m
    n = np.ceil((hi - lo) / cell_m).astype(int) + 1
    axes = [lo[i] + cell_m * np.arange(n[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    f = smooth_distance(body, grid.reshape(-1, 3), blend_m).reshape(tuple(n))

    # One vertex per crossed cell: the mean of the crossings on its 12 edges.
    total = np.zeros(tuple(n - 1) + (3,))
    count = np.zeros(tuple(n - 1))
    for axis in range(3):
        f0 = np.take(f, np.arange(n[axis] - 1), axis)
        f1 = np.take(f, np.arange(1, n[axis]), axis)
        g0 = np.take(grid, np.arange(n[axis] - 1), axis)
        g1 = np.take(grid, np.arange(1, n[axis]), axis)
        cross = (f0 < 0) != (f1 < 0)
        u = np.where(cross, f0 / np.where(cross, f0 - f1, 1.0), 0.0)
        point = g0 + u[..., None] * (g1 - g0)
        # An edge along `axis` at node (i, j, k) belongs to the 4 cells at offsets 0 / -1 in the
        # other two axes.
        others = [ax for ax in range(3) if ax != axis]
        for d0 in (0, 1):
            for d1 in (0, 1):
                sl_edge, sl_cell = [slice(None)] * 3, [slice(None)] * 3
                for ax, d in zip(others, (d0, d1)):
                    sl_edge[ax] = slice(d, n[ax] - 1 + d)
                    sl_cell[ax] = slice(0, n[ax] - 1)
                c = cross[tuple(sl_edge)]
                total[tuple(sl_cell)] += np.where(c[..., None], point[tuple(sl_edge)], 0.0)
                count[tuple(sl_cell)] += c
    cells = count > 0
    index = np.full(cells.shape, -1, np.int64)
    index[cells] = np.arange(int(cells.sum()))
    positions = total[cells] / count[cells][:, None]

    # One quad per crossed edge, between the 4 cells around it, wound so that its normal points
    # from the inside (f < 0) to the outside: for an edge along x the cells go round (y, z) as
    # (-, -), (+, -), (+, +), (-, +), counter-clockwise seen from +x (e_y x e_z = e_x), and so on
    # cyclically for y (z, x) and z (x, y).
    quads = []
    for axis in range(3):
        o1, o2 = (axis + 1) % 3, (axis + 2) % 3
        f0 = np.take(f, np.arange(n[axis] - 1), axis)
        f1 = np.take(f, np.arange(1, n[axis]), axis)
        cross = (f0 < 0) != (f1 < 0)
        # Edges with all 4 cells inside the grid: not on the first or last node of o1 and o2.
        interior = np.zeros_like(cross)
        sl = [slice(None)] * 3
        sl[o1], sl[o2] = slice(1, n[o1] - 1), slice(1, n[o2] - 1)
        interior[tuple(sl)] = True
        e = np.argwhere(cross & interior)
        outward = f0[tuple(e.T)] < 0  # inside below, outside above: the normal is +axis
        ring = []
        for d1, d2 in ((-1, -1), (0, -1), (0, 0), (-1, 0)):
            c = e.copy()
            c[:, o1] += d1
            c[:, o2] += d2
            ring.append(index[tuple(c.T)])
        q = np.stack(ring, -1)
        quads.append(np.where(outward[:, None], q, q[:, ::-1]))
    quads = np.concatenate(quads)
    if np.any(quads < 0):
        raise RuntimeError("surface nets: a crossed edge without its four cells (the grid is too tight)")

    positions = _project(body, positions, blend_m, cell_m)
    # Split each quad along its shorter diagonal.
    p = positions
    d02 = np.linalg.norm(p[quads[:, 0]] - p[quads[:, 2]], axis=1)
    d13 = np.linalg.norm(p[quads[:, 1]] - p[quads[:, 3]], axis=1)
    short02 = (d02 <= d13)[:, None]
    t1 = np.where(short02, quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    t2 = np.where(short02, quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    faces = np.concatenate([t1, t2])
    return positions.astype(np.float32), faces.astype(np.int32)


def _project(body: BodyProxy, p: np.ndarray, blend_m: float, cell_m: float, steps: int = 3) -> np.ndarray:
    """Newton steps p <- p - f grad f / |grad f|^2 towards the zero set, the gradient by central
    differences; a step is clamped to half a cell so that no vertex leaves its neighbourhood."""
    eps = 1e-4
    for _ in range(steps):
        fp = smooth_distance(body, p, blend_m)
        grad = np.stack([(smooth_distance(body, p + e, blend_m) - smooth_distance(body, p - e, blend_m)) / (2 * eps)
                         for e in np.eye(3) * eps], -1)
        g2 = np.maximum(np.einsum("ij,ij->i", grad, grad), 1e-12)
        step = (fp / g2)[:, None] * grad
        length = np.linalg.norm(step, axis=1, keepdims=True)
        p = p - step * np.minimum(1.0, 0.5 * cell_m / np.maximum(length, 1e-12))
    return p


def floor_mesh(body: BodyProxy, size_m: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """The floor y = body.floor_y as a square of side size_m centred under the figure: positions
    (4, 3) float32, faces (2, 3) int32, counter-clockwise seen from +Y."""
    if body.floor_y is None:
        raise ValueError("the body has no floor")
    s, y = 0.5 * size_m, body.floor_y
    p = np.array([[-s, y, -s], [s, y, -s], [s, y, s], [-s, y, s]], np.float32)
    return p, np.array([[0, 2, 1], [0, 3, 2]], np.int32)
