"""A mass-spring cloth integrated with XPBD (extended position-based dynamics) in numpy.

Each substep of length h (Macklin, Storey, Lu et al., "Small Steps in Physics Simulation", SCA 2019):

    v <- v * exp(-damping h) + g h               gravity and air damping
    p <- x + v h                                 predicted positions
    for each spring colour, in turn:             Gauss-Seidel over colours, Jacobi within one
        C = |p_i - p_j| - L                      the spring's stretch (metres)
        dl = (-C - a~ l) / (w_i + w_j + a~)      XPBD multiplier step, a~ = compliance / h^2
        p_i += w_i dl n, p_j -= w_j dl n         n = (p_i - p_j) / |p_i - p_j|
    p <- push_out(p)                             body proxy and floor, then friction
    v <- (p - x) / h, x <- p

(Macklin, Mueller, Chentanez, "XPBD", MIG 2016, Eqs. 17-18; with one iteration per substep the
multipliers l start at 0, so dl = -C / (w_i + w_j + a~).) A compliance of 0 is an inextensible
spring; the compliance is in metres per newton and does not depend on the substep count.

A seam (two vertices that sewing joins, `ClothMesh.seams`) is a spring of rest length L = 0: the
same step pulls its two ends together, n being the direction from one to the other.

Tethers (long range attachments, Kim, Chentanez, Mueller, "Long Range Attachments", SCA 2012):
a vertex that hangs from an anchor (a dress from its shoulder seams) may not be farther from it than
its geodesic distance on the pattern; where it is, it alone moves back onto that sphere, once per
substep after the springs. Hanging from a long chain of inextensible springs, the vertices far down
would otherwise see the chain stretch by what a few Gauss-Seidel passes leave unsolved.

The springs of one colour share no vertex (a greedy edge colouring, done once), so one colour is
solved exactly like sequential Gauss-Seidel but with one vectorised update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cloth import ClothMesh, Springs
from .proxy import BodyProxy

GRAVITY_M_S2 = np.array([0.0, -9.81, 0.0])


@dataclass(frozen=True)
class ClothSettings:
    """Material and integration settings.

    density_kg_m2: cloth mass per area. Compliances (m/N) per spring kind: 0 is inextensible; a
    seam (rest length 0) with compliance 0 closes in one substep, a soft one pulls its two edges
    together over several frames.
    damping_per_s: air damping of all velocities. drag_per_s: damping of the velocity along the
    cloth's normal (air resistance: a falling sheet of 0.2 kg/m^2 reaches about 1.6 m/s, and
    g / 1.6 m/s ~ 6 /s). friction: share of the tangential motion removed at a contact per substep.
    thickness_m: the distance the cloth keeps from the body proxy and floor. edge_collisions: also
    collide the midpoints of structural springs. frame_dt_s, substeps: a frame's time step and its
    substeps. iterations: passes over the structural springs and seams per substep (shear and
    bend: one).
    """

    density_kg_m2: float = 0.2
    structural_compliance: float = 0.0
    shear_compliance: float = 1e-4
    bend_compliance: float = 5e-3
    seam_compliance: float = 0.0
    damping_per_s: float = 0.3
    drag_per_s: float = 6.0
    friction: float = 0.4
    thickness_m: float = 0.012
    edge_collisions: bool = True
    frame_dt_s: float = 1.0 / 30.0
    substeps: int = 16
    iterations: int = 2


def colour_springs(pairs: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """A greedy edge colouring: lists of spring indices, no two springs of one list share a vertex."""
    used: list[set[int]] = [set() for _ in range(n_vertices)]
    colour = np.empty(len(pairs), np.int64)
    for k, (i, j) in enumerate(pairs.tolist()):
        taken = used[i] | used[j]
        c = 0
        while c in taken:
            c += 1
        colour[k] = c
        used[i].add(c)
        used[j].add(c)
    order = np.argsort(colour, kind="stable")
    bounds = np.searchsorted(colour[order], np.arange(colour.max() + 2)) if len(pairs) else [0]
    return [order[bounds[c]:bounds[c + 1]] for c in range(len(bounds) - 1)]


@dataclass
class _Group:
    """One colour of one kind: vertex indices, rest lengths, and the share of a spring's correction
    each end takes, w_i / (w_i + w_j + a~) and w_j / (...), for the substep length h."""

    i: np.ndarray
    j: np.ndarray
    rest_m: np.ndarray
    share_i: np.ndarray
    share_j: np.ndarray


@dataclass(frozen=True)
class FrameStats:
    """What one frame did: simulated time, energies (J), the largest and mean relative stretch of the
    structural springs, the deepest penetration of the body proxy and floor (m, >= 0), contacts, and
    the widest gap of a seam (m; 0 without seams)."""

    time_s: float
    kinetic_j: float
    potential_j: float
    max_stretch: float
    mean_stretch: float
    max_penetration_m: float
    contacts: int
    step_ms: float
    max_seam_gap_m: float = 0.0

    @property
    def energy_j(self) -> float:
        return self.kinetic_j + self.potential_j


class ClothSim:
    """The state of one cloth: positions x (V, 3) and velocities v (V, 3), float64, metres and m/s."""

    def __init__(self, cloth: ClothMesh, body: BodyProxy, settings: ClothSettings = ClothSettings()):
        self.cloth, self.body, self.settings = cloth, body, settings
        self.x = np.array(cloth.positions, np.float64)
        self.v = np.zeros_like(self.x)
        self.time_s = 0.0
        area = _mesh_area(self.x, cloth.faces)
        self.mass_kg = np.full(len(self.x), settings.density_kg_m2 * area / len(self.x))
        self.inv_mass = 1.0 / self.mass_kg
        h = settings.frame_dt_s / settings.substeps
        self._groups: list[_Group] = []
        for springs, compliance in ((cloth.structural, settings.structural_compliance),
                                    (cloth.shear, settings.shear_compliance),
                                    (cloth.bend, settings.bend_compliance)):
            self._groups += self._colour_groups(springs, compliance / (h * h))
            if springs is cloth.structural:
                self._structural = list(self._groups)
        if cloth.seams is not None and len(cloth.seams.pairs):
            # Seams carry the weight of what hangs below them (a dress hangs from its shoulder seams):
            # they take the structural springs' extra passes too.
            seams = self._colour_groups(cloth.seams, settings.seam_compliance / (h * h))
            self._groups += seams
            self._structural += seams
        self._contact = np.zeros(len(self.x), bool)

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float32 metres, Y-up: what a frame sends to the renderer."""
        return self.x.astype(np.float32)

    def step_frame(self) -> FrameStats:
        """Advance one frame (settings.substeps substeps)."""
        import time

        t0 = time.perf_counter()
        s = self.settings
        h = s.frame_dt_s / s.substeps
        decay = np.exp(-s.damping_per_s * h)
        drag = 1.0 - np.exp(-s.drag_per_s * h)
        normal = _vertex_normals(self.x, self.cloth.faces)  # once per frame: the sheet turns slowly
        for _ in range(s.substeps):
            self.v *= decay
            self.v -= drag * np.einsum("ij,ij->i", self.v, normal)[:, None] * normal
            self.v += GRAVITY_M_S2 * h
            p = self.x + self.v * h
            for g in self._groups:
                self._solve(p, g)
            for _ in range(s.iterations - 1):  # extra passes hold the weight of the cloth at the contacts
                for g in self._structural:
                    self._solve(p, g)
            if self.cloth.tethers is not None:
                self._tether(p, self.cloth.tethers)
            if s.edge_collisions:
                self._push_out_edges(p)
            p, contact, normal = self.body.push_out(p, s.thickness_m)
            if contact.any() and s.friction > 0:
                # Friction: remove a share of the substep's motion along the surface at contacts.
                d = p[contact] - self.x[contact]
                n = normal[contact]
                tangential = d - np.einsum("ij,ij->i", d, n)[:, None] * n
                p[contact] -= s.friction * tangential
            self._contact = contact
            self.v = (p - self.x) / h
            self.x = p
        self.time_s += s.frame_dt_s
        return self.stats((time.perf_counter() - t0) * 1e3)

    def _push_out_edges(self, p: np.ndarray) -> None:
        """Edge collisions, approximately: a structural spring whose midpoint is inside the body moves
        both its ends by the midpoint's push. Vertices alone would let a thin capsule (an arm) slice
        between two neighbours, which then slide down on either side with the spring through it."""
        pairs = self.cloth.structural.pairs
        # Only springs with an end that touched the body in the previous substep can be cutting into it.
        pairs = pairs[self._contact[pairs[:, 0]] | self._contact[pairs[:, 1]]]
        if not len(pairs):
            return
        mid = 0.5 * (p[pairs[:, 0]] + p[pairs[:, 1]])
        # Margin 0, not the thickness: the midpoint of a chord over a curved surface sits closer to it
        # than its ends, and pushing it to the full thickness would lift resting cloth every substep.
        moved, contact, _ = self.body.push_out(mid, 0.0)
        if not contact.any():
            return
        push = moved[contact] - mid[contact]
        ends = pairs[contact]
        total = np.zeros_like(p)
        count = np.zeros(len(p))
        for e in (0, 1):
            np.add.at(total, ends[:, e], push)
            np.add.at(count, ends[:, e], 1.0)
        hit = count > 0
        p[hit] += total[hit] / count[hit, None]

    @staticmethod
    def _tether(p: np.ndarray, tethers: Springs) -> None:
        i, a = tethers.pairs[:, 0], tethers.pairs[:, 1]
        d = p[i] - p[a]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        over = length > tethers.rest_m
        scale = (length[over] - tethers.rest_m[over]) / length[over]
        p[i[over]] -= scale[:, None] * d[over]

    def _colour_groups(self, springs: Springs, alpha_tilde: float) -> list[_Group]:
        out = []
        for c in colour_springs(springs.pairs, len(self.x)):
            i, j = springs.pairs[c, 0], springs.pairs[c, 1]
            wi, wj = self.inv_mass[i], self.inv_mass[j]
            denom = wi + wj + alpha_tilde
            out.append(_Group(i, j, springs.rest_m[c], wi / denom, wj / denom))
        return out

    @staticmethod
    def _solve(p: np.ndarray, g: _Group) -> None:
        # -dl * n = (|d| - L) / (w_i + w_j + a~) * d / |d|: one scale per spring times d.
        d = p[g.i] - p[g.j]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        scale = (length - g.rest_m) / np.maximum(length, 1e-12)
        d *= scale[:, None]
        p[g.i] -= g.share_i[:, None] * d
        p[g.j] += g.share_j[:, None] * d

    def stats(self, step_ms: float = 0.0) -> FrameStats:
        st = self.cloth.structural
        length = np.linalg.norm(self.x[st.pairs[:, 0]] - self.x[st.pairs[:, 1]], axis=1)
        stretch = length / st.rest_m - 1.0
        floor = self.body.floor_y if self.body.floor_y is not None else 0.0
        sd = self.body.signed_distance(self.x)
        seams = self.cloth.seams
        gap = 0.0
        if seams is not None and len(seams.pairs):
            gap = float(np.linalg.norm(self.x[seams.pairs[:, 0]] - self.x[seams.pairs[:, 1]], axis=1).max())
        return FrameStats(
            time_s=self.time_s,
            kinetic_j=float(0.5 * np.sum(self.mass_kg * np.einsum("ij,ij->i", self.v, self.v))),
            potential_j=float(np.sum(self.mass_kg * -GRAVITY_M_S2[1] * (self.x[:, 1] - floor))),
            max_stretch=float(stretch.max()), mean_stretch=float(np.abs(stretch).mean()),
            max_penetration_m=float(max(0.0, -sd.min())), contacts=int(self._contact.sum()), step_ms=step_ms,
            max_seam_gap_m=gap)


def _mesh_area(x: np.ndarray, faces: np.ndarray) -> float:
    e1, e2 = x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]]
    return float(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1).sum())


def _vertex_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3); zero for a vertex of degenerate faces only."""
    fn = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    n = np.zeros_like(x)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.maximum(length, 1e-20)
