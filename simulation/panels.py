"""A sleeveless dress sewn from two panels, drafted flat and placed around the mannequin the way
garment CAD tools do it: a front and a back pattern, each triangulated in its own plane, wrapped
around the body a few centimetres off it, and seams that pair the vertices of matching edges (the
two side seams and the two shoulder seams) for the solver to close (`ClothMesh.seams`).

Pattern space (metres): s across the panel, 0 on its centre line; t up the panel from the hem. A
panel seen from outside the garment has s to the right and t up, so faces counter-clockwise in
(s, t) are counter-clockwise seen from outside. The front's +s goes to the figure's +X, the back's
+s to -X (the back is seen from behind). The figure faces +Z, Y up (`proxy.py`).

The dress's shape around the body is a stack of superellipses (half-width A(y) along X, half-depth B(y)
along Z, centred on the Y axis) from the hem up to the chest, then an arc over each shoulder to the
shoulder seam at z = 0. The pattern is that shape flattened: a row of the pattern at height y is as
wide as a quarter of the section's perimeter on each side of the centre line, and s is arc length
along the section, so rows are placed at their rest length. Up the panel, t is arc length along the
steepest line of the stack (the side seam), so nothing starts stretched; where the stack changes
its width faster than its depth, the centre starts a little slack.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from .cloth import ClothMesh, Springs

FRONT, BACK = 0, 1


@dataclass(frozen=True)
class DressPattern:
    """The dress drafted for `mannequin()`: heights and widths in metres.

    sections: (y, A, B) cross-sections of the placed dress, bottom (the hem) to top (where the bend over
    the shoulders starts); each is the body's cross-section there plus 2-4 cm of ease, except the
    skirt, which flares from the hips (y 0.9) to the hem. squareness: the sections are superellipses
    |x / A|^n + |z / B|^n = 1 of this n (2: ellipses; more: closer to the rounded-box cross-section
    of a torso, which keeps the ease at the chest's corners). seam_y_m: height of the shoulder seams
    (the shoulders' top is at 1.48). hip_y_m: where the skirt's flare ends.
    underarm_y_m: top of the side seams, where the armholes start.
    strap_base_y_m: where the armhole meets the strap. strap_inner_m, strap_outer_m: the straps'
    edges, as arc length from the centre line. *_neck_depth_m: the neckline's depth below the
    shoulder seam along the panel.
    """

    sections: tuple[tuple[float, float, float], ...] = (
        (0.50, 0.34, 0.30),    # hem, a little below the knees: an A-line flare
        (0.90, 0.225, 0.17),   # hips (the body: 0.195 x 0.135)
        (1.08, 0.20, 0.155),   # waist (the body: 0.12 x 0.12): a shift dress, not fitted there
        (1.18, 0.205, 0.155),  # underarm (the body: 0.166 x 0.116)
        (1.26, 0.22, 0.16),    # bust (the body: 0.195 x 0.135)
        (1.36, 0.20, 0.15),    # where the straps bend over the shoulders
    )
    squareness: float = 2.5
    hip_y_m: float = 0.90
    seam_y_m: float = 1.505
    underarm_y_m: float = 1.18
    strap_base_y_m: float = 1.33
    strap_inner_m: float = 0.08
    strap_outer_m: float = 0.15
    front_neck_depth_m: float = 0.25
    back_neck_depth_m: float = 0.12


@dataclass(frozen=True)
class Garment:
    """A garment sewn from panels. cloth: the simulated mesh (front panel's vertices first), its
    seams the concatenation of `seam_pairs`. pattern: (V, 2) float64, each vertex on its flat
    pattern (metres; the rest lengths are its distances). panel: (V,) int8, FRONT or BACK. seam_pairs: name -> (E, 2) int32 vertex pairs, first
    column on the front panel, in order along the seam."""

    cloth: ClothMesh
    pattern: np.ndarray
    panel: np.ndarray
    seam_pairs: dict[str, np.ndarray] = field(default_factory=dict)

    def sewn(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The garment as one mesh for rendering: each seam's two vertices merged into one at their
        midpoint (smooth normals across the seam; the front's UV wins). positions (V, 3) ->
        positions (V', 3) float32, faces (F, 3) int32 (counter-clockwise seen from outside, as both
        panels are), uvs (V', 2) float32."""
        positions = np.asarray(positions, np.float64)
        pairs = self.cloth.seams.pairs if self.cloth.seams is not None else np.zeros((0, 2), np.int32)
        keep = np.ones(len(positions), bool)
        keep[pairs[:, 1]] = False
        merged = positions.copy()
        merged[pairs[:, 0]] = 0.5 * (positions[pairs[:, 0]] + positions[pairs[:, 1]])
        target = np.arange(len(positions))
        target[pairs[:, 1]] = pairs[:, 0]
        new_index = np.cumsum(keep) - 1
        faces = new_index[target[self.cloth.faces]].astype(np.int32)
        return merged[keep].astype(np.float32), faces, self.cloth.uvs[keep].astype(np.float32)


class _Form:
    """The stack of sections: A(y), B(y) (callables on arrays) and the panel's height coordinate
    t(y) (metres)."""

    def __init__(self, pattern: DressPattern):
        self.squareness = pattern.squareness
        y, a, b = (np.array(c, np.float64) for c in zip(*pattern.sections))
        if np.any(np.diff(y) <= 0) or np.any(a <= 0) or np.any(b <= 0):
            raise ValueError("sections must go up in y and have positive half-width and half-depth")
        self.hem_y, self.bend_y = float(y[0]), float(y[-1])
        upper = y >= pattern.hip_y_m - 1e-9
        if not (np.any(np.abs(y - pattern.hip_y_m) < 1e-9) and upper.sum() >= 2 and (~upper).sum() >= 1):
            raise ValueError("hip_y_m must be one of the sections' heights, with sections below and above it")
        # The skirt (hem to hips) is a cone, A and B linear in y: a cone develops onto the plane
        # without distortion. Above the hips PCHIP: smooth, with no overshoot between sections.
        y_hip, a_hip, b_hip = pattern.hip_y_m, a[upper][0], b[upper][0]
        pa, pb = PchipInterpolator(y[upper], a[upper]), PchipInterpolator(y[upper], b[upper])

        def cone(v, lo, hi):
            return lo + (hi - lo) * (v - y[0]) / (y_hip - y[0])

        self.a = lambda v: np.where(v < y_hip, cone(v, a[0], a_hip), pa(np.maximum(v, y_hip)))
        self.b = lambda v: np.where(v < y_hip, cone(v, b[0], b_hip), pb(np.maximum(v, y_hip)))
        self._y = np.linspace(self.hem_y, self.bend_y, 2048)
        slope = np.maximum(np.abs(np.gradient(self.a(self._y), self._y)), np.abs(np.gradient(self.b(self._y), self._y)))
        ds = np.sqrt(1.0 + slope**2)
        self._t = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(self._y))])

        # Geodesic curvature of the rows (`_develop`): kappa = -(dW/dt) / W on the skirt; above the
        # hips the rows keep the hip row's curvature, so they are that arc moved up (a bodice on a
        # body of nearly constant girth is a cylinder: its rows are parallel in the pattern).
        yk = np.linspace(self.hem_y, pattern.hip_y_m, 512)
        tk = np.interp(yk, self._y, self._t)
        w = np.array([_quarter_perimeter(float(self.a(v)), float(self.b(v)), self.squareness) for v in yk])
        self._tk, self._kappa = tk, -np.gradient(w, tk) / w

    def kappa(self, t: float) -> float:
        """Curvature (1/m) of the pattern's row at t (positive: its ends bend up)."""
        return float(np.interp(t, self._tk, self._kappa))

    def t_of_y(self, y: float) -> float:
        return float(np.interp(y, self._y, self._t))

    def y_of_t(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self._t, self._y)


_N_ARC = 4096


def _ring(a: float, b: float, n: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A quarter of the superellipse |x / a|^n + |z / b|^n = 1 from (0, b) to (a, 0), as x, z and
    arc length at _N_ARC + 1 points: x = a sin(theta)^(2/n), z = b cos(theta)^(2/n) (n = 2: an
    ellipse), arc length as the sum of chords (the parametrisation's speed is infinite at the ends
    for n > 2, its integral is not)."""
    theta = np.linspace(0.0, 0.5 * np.pi, _N_ARC + 1)
    x = a * np.sin(theta) ** (2.0 / n)
    z = b * np.cos(theta) ** (2.0 / n)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
    return x, z, arc


def _ring_point(a: float, b: float, n: float, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The point at arc length |s| from (0, b) on the side of sign(s): x (signed), z; (N,) each.
    Beyond the quarter perimeter: the side point (a, 0)."""
    x, z, arc = _ring(a, b, n)
    s = np.asarray(s, np.float64)
    return np.sign(s) * np.interp(np.abs(s), arc, x), np.interp(np.abs(s), arc, z)


def _quarter_perimeter(a: float, b: float, n: float) -> float:
    return float(_ring(a, b, n)[2][-1])


@dataclass(frozen=True)
class _Panel:
    """One panel: curvilinear coordinates st (N, 2) (s along the row, t the row's height on the
    centre line), the flat pattern (N, 2), 3D positions (N, 3), rows of spans of vertex indices
    (each span left to right), and the number of rows with side seams."""

    st: np.ndarray
    flat: np.ndarray
    xyz: np.ndarray
    rows: list[list[np.ndarray]]
    side_rows: int


def _row_spans(t: float, p: DressPattern, form: _Form, t_arm: float, t_strap: float, t_top: float,
               neck_depth: float, spacing: float) -> list[tuple[float, float]]:
    """The intervals of s inside the panel's outline on the row at height t."""
    if t <= t_arm + 1e-9:
        y = float(form.y_of_t(t))
        w = _quarter_perimeter(float(form.a(y)), float(form.b(y)), p.squareness)
        return [(-w, w)]
    y_arm = float(form.y_of_t(t_arm))
    w_arm = _quarter_perimeter(float(form.a(y_arm)), float(form.b(y_arm)), p.squareness)
    # Armhole: a quarter ellipse from the underarm (w_arm, t_arm), leaving it horizontally, to the
    # strap's outer edge (strap_outer, t_strap), arriving vertically.
    if t < t_strap:
        u = (t_strap - t) / (t_strap - t_arm)
        outer = w_arm - (w_arm - p.strap_outer_m) * np.sqrt(max(0.0, 1.0 - u * u))
    else:
        outer = p.strap_outer_m
    # Neckline: a quarter ellipse from the centre line at t_top - depth to the strap's inner edge at
    # the shoulder seam. An opening narrower than half a spacing is not cut yet.
    t_neck = t_top - neck_depth
    inner = 0.0
    if t > t_neck:
        u = (t_top - t) / neck_depth
        inner = p.strap_inner_m * np.sqrt(max(0.0, 1.0 - u * u))
    if inner < 0.25 * spacing:
        return [(-outer, outer)]
    return [(-outer, -inner), (inner, outer)]


def _span_s(a: float, b: float, spacing: float) -> np.ndarray:
    """Vertices of a span: its two ends on the outline and the grid columns k * spacing at least
    half a spacing inside them (so the cells at the outline are 0.5 to 1.5 spacings wide)."""
    k = np.arange(np.ceil((a + 0.5 * spacing) / spacing - 1e-9), np.floor((b - 0.5 * spacing) / spacing + 1e-9) + 1)
    return np.concatenate([[a], k * spacing, [b]])


def _panel(p: DressPattern, form: _Form, side: int, spacing: float) -> _Panel:
    """Draft, grid and place one panel (side FRONT or BACK)."""
    sigma = 1.0 if side == FRONT else -1.0
    t_bend = form.t_of_y(form.bend_y)
    t_arm = round(form.t_of_y(p.underarm_y_m) / spacing) * spacing
    t_strap = form.t_of_y(p.strap_base_y_m)
    rise = p.seam_y_m - form.bend_y
    a_b, b_b = float(form.a(form.bend_y)), float(form.b(form.bend_y))
    # The bend over the shoulder: per column a quarter ellipse from (y_bend, z_b) to (seam_y, 0). Its
    # pattern length is the longest of the straps' columns, so none starts stretched.
    s_strap = np.linspace(p.strap_inner_m, p.strap_outer_m, 16)
    depth = _ring_point(a_b, b_b, p.squareness, s_strap)[1]
    bend_len = max(_quarter_perimeter(d, rise, 2.0) for d in depth)
    n_top = int(np.ceil((t_bend + bend_len) / spacing - 1e-9))
    t_top = n_top * spacing
    if not (0 < t_arm < t_strap < t_bend < t_top):
        raise ValueError("the pattern's heights must go hem < underarm < strap base < bend < shoulder seam")
    neck = p.front_neck_depth_m if side == FRONT else p.back_neck_depth_m

    st, rows = [], []
    n = 0
    for j in range(n_top + 1):
        t = j * spacing
        row = []
        for a, b in _row_spans(t, p, form, t_arm, t_strap, t_top, neck, spacing):
            s = _span_s(a, b, spacing)
            st.append(np.stack([s, np.full_like(s, t)], -1))
            row.append(np.arange(n, n + len(s)))
            n += len(s)
        rows.append(row)
    st = np.concatenate(st)

    s, t = st[:, 0], st[:, 1]
    xyz = np.empty((len(st), 3))
    for j, row in enumerate(rows):
        idx = np.concatenate(row)
        tj = j * spacing
        y = float(form.y_of_t(min(tj, t_bend)))
        x, z = _ring_point(float(form.a(y)), float(form.b(y)), p.squareness, s[idx])
        yy = np.full(len(idx), y)
        if tj > t_bend:
            phi = 0.5 * np.pi * (tj - t_bend) / (t_top - t_bend)
            yy[:] = form.bend_y + rise * np.sin(phi)
            z = z * np.cos(phi)
        xyz[idx] = np.stack([sigma * x, yy, sigma * z], -1)
    kappa = np.array([form.kappa(j * spacing) for j in range(n_top + 1)])
    flat = _develop(st, kappa[np.round(t / spacing).astype(int)])
    return _Panel(st, flat, xyz, rows, side_rows=int(round(t_arm / spacing)) + 1)


def _develop(st: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """The flat pattern (N, 2) of curvilinear coordinates st (N, 2): the row at t is the circular
    arc of curvature kappa through (0, t), tangent to the s axis there, and s is arc length along it:
    (sin(kappa s) / kappa, t + (1 - cos(kappa s)) / kappa). Rows of a cone's development are
    concentric arcs of kappa = -(dW/dt) / W, W the row's half-length: rows that shorten going up
    bend up at the sides, like the hem and waist of a flared skirt's pattern."""
    s, t = st[:, 0], st[:, 1]
    ks = kappa * s
    small = np.abs(ks) < 1e-6
    k = np.where(small, 1.0, kappa)
    x = np.where(small, s * (1.0 - ks**2 / 6.0), np.sin(ks) / k)
    y = t + np.where(small, 0.5 * s * ks, (1.0 - np.cos(ks)) / k)
    return np.stack([x, y], -1)


def _zipper(lower: np.ndarray, upper: np.ndarray, st: np.ndarray, spacing: float) -> list[tuple[int, int, int]]:
    """Triangles between two rows of vertices (each left to right), counter-clockwise in (s, t):
    advance along the row whose next vertex makes the shorter new edge; where both rows have a
    vertex on the same grid columns, a quad split along alternating diagonals (a checkerboard, as in
    `sheet()`, so the cloth has no preferred shear direction)."""
    tris = []
    i = k = 0
    while i < len(lower) - 1 or k < len(upper) - 1:
        if i == len(lower) - 1:
            advance_lower = False
        elif k == len(upper) - 1:
            advance_lower = True
        else:
            a, b, c, d = lower[i], lower[i + 1], upper[k + 1], upper[k]
            if abs(st[a, 0] - st[d, 0]) < 1e-9 and abs(st[b, 0] - st[c, 0]) < 1e-9:
                if (round(st[a, 0] / spacing) + round(st[a, 1] / spacing)) % 2 == 0:
                    tris += [(a, b, c), (a, c, d)]
                else:
                    tris += [(a, b, d), (b, c, d)]
                i, k = i + 1, k + 1
                continue
            advance_lower = np.linalg.norm(st[b] - st[d]) <= np.linalg.norm(st[c] - st[a])
        if advance_lower:
            tris.append((lower[i], lower[i + 1], upper[k]))
            i += 1
        else:
            tris.append((lower[i], upper[k + 1], upper[k]))
            k += 1
    return tris


def _triangulate(panel: _Panel, spacing: float) -> np.ndarray:
    """Faces (F, 3) of a panel: each row zipped to the next, span by span. Where the neck opens, a
    row's one span meets two above it: each takes the part of the span below it."""
    st = panel.st
    faces = []
    for lower_row, upper_row in zip(panel.rows[:-1], panel.rows[1:]):
        for lo in lower_row:
            s_lo = st[lo, 0]
            ups = [u for u in upper_row if st[u[0], 0] <= s_lo[-1] + 1e-9 and st[u[-1], 0] >= s_lo[0] - 1e-9]
            for m, up in enumerate(ups):
                first = 0 if m == 0 else int(np.argmin(np.abs(s_lo - st[up[0], 0])))
                last = len(lo) - 1 if m == len(ups) - 1 else int(np.argmin(np.abs(s_lo - st[up[-1], 0])))
                faces += _zipper(lo[first:last + 1], up, st, spacing)
    faces = np.array(faces, np.int64)
    e1, e2 = st[faces[:, 1]] - st[faces[:, 0]], st[faces[:, 2]] - st[faces[:, 0]]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0), "a pattern triangle is not counter-clockwise"
    return faces


def _springs(faces: np.ndarray, st: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Structural, shear and bend pairs of a triangulated pattern, as `sheet()` lays them out on its
    grid: structural along rows and columns (and along the outline, which must not stretch), shear
    across each quad both ways, bend over two structural edges in a (nearly) straight line."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    d = np.abs(st[edges[:, 0]] - st[edges[:, 1]])
    structural = (d[:, 1] < 1e-9) | (d[:, 0] < 0.5 * spacing) | (count == 1)
    # The other diagonal of each sheared quad: the two vertices facing a diagonal edge.
    opposite: dict[tuple[int, int], list[int]] = {}
    for f in faces.tolist():
        for k in range(3):
            key = tuple(sorted((f[k], f[(k + 1) % 3])))
            opposite.setdefault(key, []).append(f[(k + 2) % 3])
    shear = [tuple(ed) for ed in edges[~structural].tolist()]
    have = {tuple(ed) for ed in edges.tolist()}
    for ed in shear[:]:
        o = opposite[ed]
        if len(o) == 2 and tuple(sorted(o)) not in have:
            shear.append(tuple(sorted(o)))
            have.add(tuple(sorted(o)))
    st_pairs = edges[structural]
    neighbours: dict[int, list[int]] = {}
    for i, j in st_pairs.tolist():
        neighbours.setdefault(i, []).append(j)
        neighbours.setdefault(j, []).append(i)
    bend = set()
    for b, nb in neighbours.items():
        for x in range(len(nb)):
            for y in range(x + 1, len(nb)):
                u, v = st[nb[x]] - st[b], st[nb[y]] - st[b]
                if np.dot(u, v) < -np.cos(np.radians(30)) * np.linalg.norm(u) * np.linalg.norm(v):
                    bend.add(tuple(sorted((nb[x], nb[y]))))
    return st_pairs, np.array(shear, np.int64).reshape(-1, 2), np.array(sorted(bend), np.int64).reshape(-1, 2)


def _tethers(structural: Springs, shear: Springs, anchors: np.ndarray, n: int) -> Springs:
    """Each vertex tethered to its nearest anchor along the pattern's structural and shear edges,
    the rest length that path's length (Dijkstra): never shorter than the cloth between them, so a
    tether only acts once the cloth between has stretched. A vertex no anchor reaches has none."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    pairs = np.concatenate([structural.pairs, shear.pairs])
    rest = np.concatenate([structural.rest_m, shear.rest_m])
    graph = coo_matrix((rest, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    dist, _, source = dijkstra(graph, directed=False, indices=anchors, min_only=True, return_predecessors=True)
    reached = np.isfinite(dist) & (dist > 0)
    vertex = np.flatnonzero(reached)
    return Springs(np.stack([vertex, source[vertex]], -1).astype(np.int32), dist[vertex])


def dress(spacing_m: float = 0.025, pattern: DressPattern = DressPattern()) -> Garment:
    """The sleeveless dress of `pattern`, its panels gridded at `spacing_m` (metres between grid
    columns and rows) and placed around `mannequin()`, with its side and shoulder seams.

    Both panels share their rows up to the underarm and their strap tops, so every seam edge has
    the same number of vertices on both sides and its pairs start together (the side seams meet at
    the sections' sides, the shoulder seams at z = 0). Rest lengths are the pattern's.
    """
    if not 0.005 <= spacing_m <= 0.06:
        raise ValueError(f"spacing_m must be in [0.005, 0.06] m; got {spacing_m}")
    form = _Form(pattern)
    front, back = _panel(pattern, form, FRONT, spacing_m), _panel(pattern, form, BACK, spacing_m)
    off = len(front.st)
    st = np.concatenate([front.st, back.st])
    flat = np.concatenate([front.flat, back.flat])
    xyz = np.concatenate([front.xyz, back.xyz])
    faces = np.concatenate([_triangulate(front, spacing_m), _triangulate(back, spacing_m) + off])
    panel = np.concatenate([np.full(off, FRONT, np.int8), np.full(len(back.st), BACK, np.int8)])

    # Side seams: the front's right end of each row to the back's left end (both at +X), and the
    # front's left to the back's right (-X). Shoulder seams: the front's strap tops to the back's,
    # +s on the front with -s on the back (the back's s is mirrored).
    if front.side_rows != back.side_rows:
        raise ValueError("front and back must share their side seam rows")
    rows = range(front.side_rows)
    seams = {
        "side +x": np.array([(front.rows[j][0][-1], back.rows[j][0][0] + off) for j in rows]),
        "side -x": np.array([(front.rows[j][0][0], back.rows[j][-1][-1] + off) for j in rows]),
    }
    top_f, top_b = front.rows[-1], back.rows[-1]
    if len(top_f) != 2 or len(top_b) != 2 or [len(r) for r in top_f] != [len(r) for r in top_b][::-1]:
        raise ValueError("the shoulder seams need two straps of the same width on both panels")
    seams["shoulder +x"] = np.stack([top_f[1], top_b[0][::-1] + off], -1)
    seams["shoulder -x"] = np.stack([top_f[0], top_b[1][::-1] + off], -1)
    seams = {k: v.astype(np.int32) for k, v in seams.items()}

    structural, shear, bend = _springs(faces, st, spacing_m)

    def springs(pairs: np.ndarray) -> Springs:
        pairs = pairs.astype(np.int32)
        return Springs(pairs, np.linalg.norm(flat[pairs[:, 0]] - flat[pairs[:, 1]], axis=1))

    # UVs: the pattern at one scale, front on the left half, back on the right half of [0, 1]^2.
    width = 2.0 * np.abs(flat[:, 0]).max()
    scale = 1.0 / max(2.0 * width * 1.02, flat[:, 1].max())
    centre_u = np.where(panel == FRONT, 0.25, 0.75)
    uvs = np.stack([centre_u + flat[:, 0] * scale, flat[:, 1] * scale], -1)
    all_seams = np.concatenate(list(seams.values()))
    anchors = np.concatenate([seams["shoulder +x"].reshape(-1), seams["shoulder -x"].reshape(-1)])
    cloth = ClothMesh(positions=xyz, faces=faces.astype(np.int32), uvs=uvs, structural=springs(structural),
                      shear=springs(shear), bend=springs(bend),
                      seams=Springs(all_seams, np.zeros(len(all_seams))),
                      tethers=_tethers(springs(structural), springs(shear), anchors, len(st)))
    e1, e2 = flat[faces[:, 1]] - flat[faces[:, 0]], flat[faces[:, 2]] - flat[faces[:, 0]]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0), "a pattern triangle is not counter-clockwise"
    return Garment(cloth, flat, panel, seams)
