"""Pinhole camera: look-at view, OpenGL perspective projection, and a default that frames the scene."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidInputError
from .mesh import bounds


@dataclass(frozen=True)
class Camera:
    """eye, target, up in world space; vertical field of view in degrees."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_y_deg: float = 35.0

    def __post_init__(self):
        e, t, u = (np.asarray(v, np.float64) for v in (self.eye, self.target, self.up))
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
            raise InvalidInputError("camera eye, target and up must be finite")
        if np.linalg.norm(t - e) <= 0:
            raise InvalidInputError("camera eye and target must differ")
        if np.linalg.norm(np.cross(t - e, u)) <= 1e-12 * np.linalg.norm(t - e) * np.linalg.norm(u):
            raise InvalidInputError("camera up must not be parallel to the viewing direction")
        if not 1.0 <= self.fov_y_deg <= 170.0:
            raise InvalidInputError(f"fov must be in [1, 170] degrees, got {self.fov_y_deg}")

    def view(self) -> np.ndarray:
        e, t, u = (np.asarray(v, np.float64) for v in (self.eye, self.target, self.up))
        f = (t - e) / np.linalg.norm(t - e)
        s = np.cross(f, u)
        s /= np.linalg.norm(s)
        up = np.cross(s, f)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = s, up, -f
        m[:3, 3] = -m[:3, :3] @ e
        return m

    def projection(self, aspect: float, near: float, far: float) -> np.ndarray:
        f = 1.0 / np.tan(np.radians(self.fov_y_deg) / 2.0)
        m = np.zeros((4, 4))
        m[0, 0], m[1, 1] = f / aspect, f
        m[2, 2] = (far + near) / (near - far)
        m[2, 3] = 2.0 * far * near / (near - far)
        m[3, 2] = -1.0
        return m

    def view_proj(self, aspect: float, centre: np.ndarray, radius: float) -> np.ndarray:
        """View-projection with near/far planes fitted around the scene's bounding sphere.

        The depth range is at least a thousandth of the distance either side of the centre, so that
        near < far also for a scene far thinner than its distance (a point-sized one), where
        dist +- 2 radius would round to one value; the near plane is at least far / 10^4 (depth
        precision). InvalidInputError when the float32 matrix the shaders get cannot hold the scene
        (a size or distance beyond float32's range)."""
        dist = float(np.linalg.norm(np.asarray(self.eye, np.float64) - np.asarray(centre, np.float64)))
        half_depth = max(2.0 * float(radius), 1e-3 * dist)
        far = dist + half_depth
        near = max(dist - half_depth, far * 1e-4)
        with np.errstate(all="ignore"):
            m = self.projection(aspect, near, far) @ self.view()
            m32 = m.astype(np.float32)
        if not (far > near > 0.0 and np.isfinite(m32).all() and m32[2, 3] != 0.0 and m32[1, 1] != 0.0):
            raise InvalidInputError(
                f"the scene (radius {float(radius):.3g} m, {dist:.3g} m from the camera) is outside what the "
                "float32 projection can hold; positions are in metres, and the camera must not sit at the scene's "
                "centre")
        return m


def default_camera(centre: np.ndarray, radius: float, aspect: float = 1.0, fov_y_deg: float = 35.0,
                   direction=(0.0, 0.2, 1.0)) -> Camera:
    """Frames the bounding sphere from the front (+Z), slightly above, for a Y-up scene."""
    d = np.asarray(direction, np.float64)
    d /= np.linalg.norm(d)
    half = np.radians(fov_y_deg) / 2.0
    if aspect < 1.0:
        half = np.arctan(np.tan(half) * aspect)
    dist = 1.05 * radius / np.sin(half)
    eye = np.asarray(centre, np.float64) + dist * d
    return Camera(tuple(eye), tuple(np.asarray(centre, np.float64)), (0.0, 1.0, 0.0), fov_y_deg)


def bounds_sphere(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the sphere around an axis-aligned box (what the default camera frames)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-30)


def frame_meshes(meshes, aspect: float = 1.0, fov_y_deg: float = 35.0) -> Camera:
    """The default camera of a scene made of `meshes` (renderer.mesh.Mesh): the same one the
    renderer uses when no camera is given, so other renderers (the reference) can match it."""
    lo, hi = bounds(meshes)
    centre, radius = bounds_sphere(lo, hi)
    return default_camera(centre, radius, aspect, fov_y_deg)
