"""Exact visibility of the renderer's lights: the oracle of the error split (`garment-render error-split`).

The method's visibility VIS_i is a variance shadow map's estimate of how much of light i's region a
surface point sees. Here the same quantity comes from rays: from each covered pixel's surface point
(the geometry pass's, offset along the triangle's own normal as the reference's shadow rays are),
`rays_per_light` rays towards each light's region, spread over the region's texels by their radiance
times solid angle (stratified in the texel's CDF, jittered within the texel), each tested with
embree's any-hit query against every mesh (from RAY_START_REL along the ray). VIS_i is the share of the rays above the triangle's
plane that escape: the lighting pass applies its own share-above-the-plane factor on top, as it does
to a shadow map's VIS_i, so the oracle replaces exactly the maps (and the contact search) and
nothing else. What the renderer gives with it is what perfect shadow maps of its lights would give.
"""

from __future__ import annotations

import numpy as np

from ..camera import bounds_sphere
from ..envmap.cube import cube_solid_angles, face_uv_to_dir
from ..errors import InvalidInputError
from ..lighting.median_cut import LUMINANCE_RGB, RegionSet
from ..mesh import Mesh, bounds
from .montecarlo import SHADOW_EPS_REL

# Rays per any-hit query: bounds the temporaries (~100 B a ray).
RAYS_PER_QUERY = 1 << 19
# Each ray starts this far along its direction (relative to the scene's bounding radius, ~1 mm on a
# body): where a garment meets the body within the depth buffer's precision, the geometry pass's point
# may lie a hair inside the body, and every ray from it would hit the body's inside (measured: 24 of
# 24,660 pixels black on the polo at 256^2, its collar); a contact shadow is centimetres wide.
RAY_START_REL = 1e-3


class ExactVisibility:
    """A `Renderer.render(visibility=)` oracle for one scene and one PEM set's regions."""

    def __init__(self, meshes: list[Mesh], cube: np.ndarray, regions: RegionSet, rays_per_light: int = 16,
                 seed: int = 0):
        """`cube`: the (6, F, F, 3) map the regions were cut from (its face size is the labels')."""
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        face = regions.labels.shape[1]
        if cube.shape[:3] != (6, face, face):
            raise InvalidInputError(f"the cube's faces must be the regions' ({face}^2), got {cube.shape}")
        if rays_per_light < 1:
            raise InvalidInputError(f"rays per light must be >= 1, got {rays_per_light}")
        positions, faces, offset = [], [], 0
        for m in meshes:
            positions.append(m.positions.astype(np.float64))
            faces.append(m.faces.astype(np.int64) + offset)
            offset += m.n_vertices
        tm = trimesh.Trimesh(vertices=np.concatenate(positions), faces=np.concatenate(faces), process=False)
        self.intersector = RayMeshIntersector(tm)
        radius = bounds_sphere(*bounds(meshes))[1]
        self.eps, self.start = SHADOW_EPS_REL * radius, RAY_START_REL * radius
        self.face, self.k, self.seed = face, int(rays_per_light), seed
        self.n = regions.n_regions
        weight = (np.maximum(cube.astype(np.float64), 0.0) @ LUMINANCE_RGB) * cube_solid_angles(face)
        labels = regions.labels.ravel()
        order = np.argsort(labels, kind="stable")
        ends = np.searchsorted(labels[order], np.arange(self.n + 1))
        self._texels, self._cdfs = [], []
        flat_w = weight.ravel()
        for i in range(self.n):
            idx = order[ends[i]:ends[i + 1]]
            if not idx.size:
                raise InvalidInputError(f"region {i} has no texel")
            w = flat_w[idx]
            # A black region: its texels by solid angle (its light carries nothing, its VIS_i nothing).
            w = w if w.sum() > 0 else cube_solid_angles(face).ravel()[idx]
            cdf = np.cumsum(w)
            self._texels.append(idx)
            self._cdfs.append(cdf / cdf[-1])
        self.rays_cast = 0

    def _directions(self, i: int, count: int, rng: np.random.Generator) -> np.ndarray:
        """(count, k, 3) directions into region i, each pixel's k stratified over the region's CDF."""
        u = (np.arange(self.k)[None, :] + rng.random((count, self.k))) / self.k
        t = self._texels[i][np.minimum(np.searchsorted(self._cdfs[i], u), len(self._cdfs[i]) - 1)]
        f, rem = np.divmod(t, self.face * self.face)
        row, col = np.divmod(rem, self.face)
        s = 2.0 / self.face
        uu = -1.0 + (col + rng.random(t.shape)) * s
        vv = -1.0 + (row + rng.random(t.shape)) * s
        d = face_uv_to_dir(f, uu, vv)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def __call__(self, points: np.ndarray, geometric: np.ndarray, covered: np.ndarray) -> np.ndarray:
        h, w = covered.shape
        out = np.ones((self.n, h, w), np.float32)
        x = points[covered].astype(np.float64)
        ng = geometric[covered].astype(np.float64)
        ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-30)
        m = len(x)
        if not m:
            return out
        rng = np.random.default_rng(self.seed)
        origin = x + self.eps * ng
        chunk = max(1, RAYS_PER_QUERY // self.k)
        for i in range(self.n):
            vis = np.ones(m, np.float32)
            for a in range(0, m, chunk):
                b = min(m, a + chunk)
                d = self._directions(i, b - a, rng)                       # (p, k, 3)
                above = np.einsum("pkc,pc->pk", d, ng[a:b]) > 0.0
                p_idx, k_idx = np.nonzero(above)
                free = np.zeros(above.shape, bool)
                if p_idx.size:
                    self.rays_cast += p_idx.size
                    dirs = d[p_idx, k_idx]
                    free[p_idx, k_idx] = ~self.intersector.intersects_any(origin[a:b][p_idx] + self.start * dirs,
                                                                           dirs)
                n_above = above.sum(axis=1)
                # No ray above the plane: the lighting pass's share-above factor is 0 there anyway.
                vis[a:b] = np.where(n_above > 0, free.sum(axis=1) / np.maximum(n_above, 1), 1.0)
            out[i][covered] = vis
        return out
