"""The body the cloth falls on: a union of spheres and capsules (exact signed distances, cheap to
collide with) and a floor, plus the triangle mesh of the same shapes for the renderer.

Conventions: metres, Y-up, the floor at y = 0, the figure facing +Z (the renderer's procedural
conventions, `renderer/procedural.py`). Faces are counter-clockwise seen from outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Capsule:
    """The points within `radius` of the segment a -> b (a sphere when a == b). a, b: (3,) metres."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float


def sphere(centre, radius: float) -> Capsule:
    return Capsule(tuple(centre), tuple(centre), radius)


@dataclass(frozen=True)
class BodyProxy:
    """Capsules (spheres included) and an optional floor plane y = floor_y."""

    capsules: tuple[Capsule, ...]
    floor_y: float | None = 0.0

    def __post_init__(self):
        a = np.array([c.a for c in self.capsules], np.float64).reshape(-1, 3)
        b = np.array([c.b for c in self.capsules], np.float64).reshape(-1, 3)
        r = np.array([c.radius for c in self.capsules], np.float64)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(r > 0)):
            raise ValueError("capsule end points must be finite and radii > 0")
        object.__setattr__(self, "_a", a)
        object.__setattr__(self, "_ab", b - a)
        object.__setattr__(self, "_r", r)

    def closest_axis_points(self, points: np.ndarray) -> np.ndarray:
        """For each point and capsule, the nearest point of the capsule's segment. (N, 3) -> (N, C, 3)."""
        ab = self._ab
        ab2 = np.einsum("cj,cj->c", ab, ab)
        t = np.einsum("ncj,cj->nc", points[:, None, :] - self._a[None], ab)
        t = np.clip(t / np.where(ab2 > 0, ab2, 1.0), 0.0, 1.0)
        return self._a[None] + t[..., None] * ab[None]

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point (N, 3) to the union of capsules and the half-space below the floor;
        negative inside. (N,) float64."""
        points = np.asarray(points, np.float64)
        d = np.linalg.norm(points[:, None, :] - self.closest_axis_points(points), axis=-1) - self._r[None]
        sd = d.min(axis=1) if len(self.capsules) else np.full(len(points), np.inf)
        if self.floor_y is not None:
            sd = np.minimum(sd, points[:, 1] - self.floor_y)
        return sd

    def push_out(self, points: np.ndarray, margin: float, passes: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Move every point closer than `margin` to a shape (or inside it) to distance `margin` along the
        outward normal of the shape it is deepest in. In a crevice where shapes meet (arm and chest,
        leg and floor) that can push it into a neighbour: the points moved are checked again, up to
        `passes` times. Returns (moved points (N, 3), contact mask (N,), outward normals (N, 3),
        zero where there is no contact)."""
        p = np.array(points, np.float64)
        normal = np.zeros_like(p)
        contact = np.zeros(len(p), bool)
        candidates = np.arange(len(p))
        for _ in range(passes):
            moved = np.zeros(len(p), bool)
            if len(self.capsules) and len(candidates):
                c = p[candidates]
                q = self.closest_axis_points(c)
                d = c[:, None, :] - q
                dist = np.sqrt(np.einsum("nck,nck->nc", d, d))
                depth = dist - (self._r + margin)[None]
                k = np.argmin(depth, axis=1)
                rows = np.arange(len(c))
                hit = depth[rows, k] < 0.0
                rows, k = rows[hit], k[hit]
                # A point exactly on the axis has no direction: push it along +Z (the figure's front).
                dk, lk = d[rows, k], dist[rows, k][:, None]
                n = np.where(lk > 1e-12, dk / np.maximum(lk, 1e-12), [0.0, 0.0, 1.0])
                idx = candidates[hit]
                p[idx] = q[rows, k] + n * (self._r[k] + margin)[:, None]
                normal[idx] = n
                moved[idx] = True
            if self.floor_y is not None:
                low = p[candidates, 1] < self.floor_y + margin
                idx = candidates[low]
                p[idx, 1] = self.floor_y + margin
                normal[idx] = (0.0, 1.0, 0.0)
                moved[idx] = True
            contact |= moved
            candidates = np.flatnonzero(moved)
            if not len(candidates):
                break
        return p, contact, normal

    def mesh(self, n_lat: int = 16, n_lon: int = 24, floor_size: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
        """Triangles of the shapes (each capsule a closed surface) and of a square floor of side
        `floor_size` centred under the figure. Returns positions (V, 3) float32, faces (F, 3) int32."""
        parts = [_capsule_mesh(np.asarray(c.a, float), np.asarray(c.b, float), c.radius, n_lat, n_lon)
                 for c in self.capsules]
        if self.floor_y is not None:
            s = 0.5 * floor_size
            p = np.array([[-s, self.floor_y, -s], [s, self.floor_y, -s], [s, self.floor_y, s], [-s, self.floor_y, s]])
            parts.append((p, np.array([[0, 2, 1], [0, 3, 2]])))  # counter-clockwise seen from +Y
        offsets = np.cumsum([0] + [len(p) for p, _ in parts[:-1]])
        positions = np.concatenate([p for p, _ in parts]).astype(np.float32)
        faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)]).astype(np.int32)
        return positions, faces


def _capsule_mesh(a: np.ndarray, b: np.ndarray, radius: float, n_lat: int, n_lon: int):
    """A closed capsule around a -> b: two hemispheres (n_lat // 2 bands each) joined by a cylinder.
    The local frame has its axis w along a -> b (+Y for a sphere)."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    w = axis / length if length > 0 else np.array([0.0, 1.0, 0.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)  # (u, v, w) right-handed
    half = n_lat // 2
    phi = 0.5 * np.pi * np.arange(1, half + 1) / half  # from the pole (0) to the equator (pi/2)
    # Rings from the b pole down to the a pole: (radius of ring, position along the axis). A sphere
    # (length 0) has one equator, not two coinciding ones (a band of zero-area triangles).
    lower = phi[::-1][1:] if length == 0 else phi[::-1]
    ring_r = radius * np.concatenate([np.sin(phi), np.sin(lower)])
    ring_t = np.concatenate([length + radius * np.cos(phi), -radius * np.cos(lower)])
    theta = 2.0 * np.pi * np.arange(n_lon) / n_lon
    # Going around with theta from u towards v while w points up gives the ring's outward normal
    # cross(d_theta, d_down) = outward for the row/column rule below.
    circle = np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v  # (n_lon, 3)
    rings = a + ring_t[:, None, None] * w + ring_r[:, None, None] * circle[None]
    n_rings = len(ring_r)
    top, bottom = n_rings * n_lon, n_rings * n_lon + 1
    positions = np.concatenate([rings.reshape(-1, 3), [b + radius * w, a - radius * w]])
    j = np.arange(n_lon)
    j1 = (j + 1) % n_lon
    i = np.arange(n_rings - 1)[:, None]
    p00, p01 = i * n_lon + j, i * n_lon + j1
    p10, p11 = (i + 1) * n_lon + j, (i + 1) * n_lon + j1
    quads = np.concatenate([np.stack([p00, p10, p01], -1), np.stack([p01, p10, p11], -1)], 1).reshape(-1, 3)
    last = (n_rings - 1) * n_lon
    top_fan = np.stack([np.full(n_lon, top), j, j1], -1)
    bottom_fan = np.stack([last + j, np.full(n_lon, bottom), last + j1], -1)
    return positions, np.concatenate([top_fan, quads, bottom_fan])


def mannequin() -> BodyProxy:
    """A standing figure about 1.74 m tall in an A-pose, feet on the floor, facing +Z: head, neck,
    shoulders, chest, waist, hips, arms and legs as spheres and capsules."""
    caps = (
        sphere((0.0, 1.64, 0.0), 0.10),                                   # head
        Capsule((0.0, 1.44, 0.0), (0.0, 1.56, 0.0), 0.055),               # neck
        Capsule((-0.16, 1.41, 0.0), (0.16, 1.41, 0.0), 0.07),             # shoulders
        Capsule((-0.07, 1.26, 0.01), (0.07, 1.26, 0.01), 0.125),          # chest
        Capsule((0.0, 1.0, 0.0), (0.0, 1.2, 0.0), 0.12),                  # waist
        Capsule((-0.06, 0.90, 0.0), (0.06, 0.90, 0.0), 0.135),            # hips
        Capsule((-0.22, 1.39, 0.0), (-0.36, 0.86, 0.03), 0.045),          # left arm
        Capsule((0.22, 1.39, 0.0), (0.36, 0.86, 0.03), 0.045),            # right arm
        Capsule((-0.09, 0.07, 0.0), (-0.09, 0.84, 0.0), 0.065),           # left leg
        Capsule((0.09, 0.07, 0.0), (0.09, 0.84, 0.0), 0.065),             # right leg
    )
    return BodyProxy(caps, floor_y=0.0)
