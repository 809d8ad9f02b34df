"""Monte Carlo ground truth: the renderer's lighting model (shaders/shading/lighting.frag, paper Eq. 5)
without its approximations (no median cut, no PEM prefiltering, no lobe calibration, no variance
shadow maps), by ray casting with embree. Every accuracy number of the project is measured against it.

Model, per pixel (row, col) and pixel_samples = k: the box-filtered pixel, the mean over its k x k
strata of the radiance seen through one position in each, jittered within the stratum (`strata`: the
positions, why this is unbiased for the pixel's area, the edge test); k = 1 is the pixel centre, not
jittered. Each position casts one primary ray from the near plane of the renderer's projection (so
near clipping matches the rasterizer). At its first hit x:

    n   = normalized barycentric mix of the vertex normals, flipped to the side of the triangle's
          plane the camera sees (two-sided cloth; it may then face slightly away from the camera)
    r   = reflect(-view, n)
    c   = albedo   * integral L(w) V(x, w) max(0, n.w) / pi dw
        + specular * integral L(w) V(x, w) (s + 1) / (2 pi) max(0, r.w)^s dw,   s = 1 / (1 - g)

with albedo, specular and g the barycentric mix of `Material.vertex_arrays` (times / replaced by the
material's texture maps, bilinear on their base level), L the piecewise-constant cube map (the
radiance of the texel containing w) and V(x, w) = 1 when w lies on the seen side of the triangle's
own plane (n_g.w > 0, n_g the geometric normal flipped to face the camera) and a ray from
x + eps * n_g towards w hits nothing (eps = SHADOW_EPS_REL * scene radius). The surface is an opaque
sheet: light reaches the side the camera sees only from that side's half-space, whatever the shading
normal says (the rule of pbrt's BSDF, which reflects only when both directions lie on the same side
of the geometric surface). Without it, a cloth seen from inside a fold or at a grazing angle, where
the interpolated normal leans across the triangle's plane, would show light arriving through the
cloth from its other side. The lobes are not clipped by the horizon of n, as in the renderer's
lookups along n and r; their parts below the triangle's plane are removed by V. g = 1 is the
mirror: L(r) V(x, r), evaluated once, no sampling.
A position that hits nothing sees L along its ray. The image's RGB is the mean over the strata of c
or, for a miss, that L; its alpha the share of strata that hit (0 or 1 at k = 1). The foreground is the
same mean with 0 for a miss: premultiplied RGB over black, what the renderer draws with a black
background. The edge mask marks pixels whose strata do not all see one surface (none at k = 1).

Estimator (Veach 1997, ch. 9: multiple importance sampling, power heuristic with beta = 2). Per
position that hits and per sample index i < n (n samples per stratum; n = spp at k = 1):
  * one environment sample w_e ~ p_env (`EnvironmentSampler`), shared by both terms: one shadow ray
    where either integrand is nonzero, weighted f * p_env / (p_env^2 + q^2) per term (q = f: both
    BRDF-sampling densities equal their integrands, see below);
  * one cosine-weighted sample around n for the diffuse term (q_d = max(0, n.w) / pi; Malley's method),
    weighted q_d^2 / (q_d^2 + p_env^2), when the albedo is not black;
  * one Phong-lobe sample around r for the glossy term (q_g = lobe itself, cos = xi^(1 / (s + 1));
    Lafortune & Willems 1994), weighted q_g^2 / (q_g^2 + p_env^2), when specular > 0 and g < 1.
So spp = samples per technique per pixel, at most 3 shadow rays per sample; rays whose integrand is
zero (below the horizon, black texel) are not cast. With k^2 strata a pixel's spp is split evenly over
them (rounded up, at least min(batches, spp) each: `strata.sample_counts`); the frame's spp is what
was taken.

Batches and stratification: a stratum's sample i goes to batch i % batches (batches = min(batches,
spp)); a pixel's batch mean m_b is the mean over its strata of their batch means (a miss's L counted in
every batch), the estimate is the mean of all samples and its per-pixel standard error comes from the
spread of the pixel's batch means (one-way ANOVA: E[sum_b n_b (m_b - m)^2] = (B - 1) sigma^2 for batch
sizes n_b, sigma^2 the variance of the mean over the strata of one sample each; the standard error is
sqrt(sigma^2 / n)). Within a batch the samples are
stratified in one dimension per technique, which keeps every batch mean unbiased and the batches
independent, so the error estimate stays honest: of the pixel's S n_b samples of the batch (S = k^2
strata), sample j of stratum s takes slot q = sigma_b(s) n_b + j, sigma_b a random permutation of the
strata per pixel and batch (the identity at k = 1: q = j; `strata.stratum_slots`), picks its texel
with a uniform number in [q, q + 1) / (S n_b) (through the CDF, so the bright texels get their exact
share of the samples: the variance of "did this sample find the sun" is gone), and its cosine / Phong
sample takes its polar angle from the reversed slot [S n_b - 1 - q, S n_b - q) / (S n_b).
Measured: the noise at 256 spp falls from 4.7 % to 2.6 % (studio dress) and 4.0 % to 3.2 % (shirt
under a hard sun); with one sample per batch the estimator is plain Monte Carlo. The noise is that of
the shading given the strata's positions; the area's sampling error is not in it (`strata`).

Determinism: the jitter of stratum s comes from a stream of (seed, k, s), the permutations of batch b
from one of (seed, strata, b), and the random stream of every chunk of (samples x hit points) of a
stratum from (seed, batch, first sample, first point), with (strata, stratum) appended for k > 1; the
chunking depends only on the image, spp, batches, k and the module constants.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, bounds_sphere
from ..errors import InvalidInputError, MeshError
from ..mesh import FALLBACK_NORMAL, Mesh, bounds, vertex_normals
from ..shading import brdf
from ..shading.material import MAP_NAMES, Material
from .envsampling import EnvironmentSampler
from .strata import MAX_PIXEL_SAMPLES, EdgeTest, sample_counts, stratum_positions, stratum_slots

# Pixel-samples processed at once: about 1 KB of float64 temporaries each, so ~0.25 GB at peak.
RAYS_PER_CHUNK = 1 << 18
# Shadow-ray origin offset along the geometric normal, relative to the scene's bounding radius.
# embree works in float32 (after trimesh rescales the scene to a ~100-unit box): ~1e-7 relative.
SHADOW_EPS_REL = 1e-4
# Sheer cloth (Material.alpha < 1): a primary ray goes on through at most this many sheets, and no
# further once the share of it left is below MIN_RAY_SHARE (what it would see beyond is then added as
# the environment's); a shadow ray, through at most MAX_LAYERS sheets (then: blocked).
MAX_LAYERS = 16
MIN_RAY_SHARE = 1e-6
# Glossiness closer to 1 than this is the mirror (s > 1e7: a lobe ~0.03 degrees wide, far inside any texel).
MIRROR_ONE_MINUS_G = 1e-7


@dataclass(frozen=True)
class ReferenceFrame:
    """A reference render (the module doc states what each image holds).

    image:      float32 (H, W, 4), linear RGB radiance, the environment where the strata miss, and the
                covered share of the pixel in alpha (0 or 1 at pixel_samples 1), row 0 at the top, the
                same layout as `renderer.Frame.image`.
    noise_std:  float32 (H, W, 3), standard error of each pixel's estimate (from the batches; NaN
                where only one batch was possible, 0 for the background and mirror-only pixels); the
                shading's noise given the strata's positions (the area's sampling error is not in it).
    foreground: float32 (H, W, 4), image with 0 for the strata that miss: premultiplied RGB over black,
                what the renderer draws with a black background; the same alpha.
    edge:       bool (H, W), pixels whose strata do not all see one surface (hit and miss, two meshes,
                two layers: `strata.EdgeTest`); none at pixel_samples 1.
    spp: samples per technique per pixel taken (pixel_samples^2 x the samples per stratum).
    rays_cast: primary + shadow rays. wall_s: seconds. pixel_samples: k, the pixel's k x k strata.
    """

    image: np.ndarray
    noise_std: np.ndarray
    spp: int
    rays_cast: int
    wall_s: float
    foreground: np.ndarray
    edge: np.ndarray
    pixel_samples: int = 1

    def noise_floor_rel(self) -> float:
        """Mean standard error / mean radiance over the covered pixels (NaN if none is covered)."""
        covered = self.image[..., 3] > 0.5
        if not covered.any():
            return float("nan")
        mean_radiance = float(self.image[covered][:, :3].astype(np.float64).mean())
        if mean_radiance <= 0:
            return float("nan")
        return float(self.noise_std[covered].astype(np.float64).mean()) / mean_radiance


def render_reference(meshes: list[Mesh], materials: list[Material], cube: np.ndarray, camera: Camera,
                     width: int, height: int, spp: int, seed: int = 0, batches: int = 8,
                     occlusion: bool = True, pixel_samples: int = 1) -> ReferenceFrame:
    """Render the ground truth of a scene (see the module doc for the model and the estimator).

    meshes, materials: one material per mesh, as `Renderer.create_scene` takes them.
    cube: (6, F, F, 3) linear RGB environment, OpenGL cube convention.
    camera: the renderer's camera; near/far are fitted to the scene's bounds as the renderer does.
    spp: samples per technique per pixel (>= 1), split over the strata. batches: independent batches
    for the noise estimate.
    occlusion: False sets V = 1 everywhere (no ray cast, no sheet): the model of the renderer's
    no-occlusion mode, against which the error of the lighting approximation alone is measured.
    pixel_samples: k in [1, MAX_PIXEL_SAMPLES]: the pixel's area integrated over k x k jittered strata
    (1: its centre, as before).
    Cost: ~1.2-2 M rays/s on one core (embree plus numpy), the same shadow rays at the same spp whatever
    k, plus k^2 primary rays and surface evaluations per pixel; peak memory ~0.25 GB + ~0.7 KB per pixel
    + batches x k^2 bytes per pixel (the strata's slots) for k > 1.
    """
    t0 = time.perf_counter()
    width, height, spp, batches, seed = _check_counts(width, height, spp, batches, seed)
    k = _as_int(pixel_samples, "pixel_samples", 1, MAX_PIXEL_SAMPLES)
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be a renderer.camera.Camera; got {type(camera).__name__}")
    scene = _SceneArrays.build(meshes, materials)
    sampler = EnvironmentSampler(cube)

    centre, radius = bounds_sphere(*bounds(meshes))
    tracer = _ShadowTracer(scene.intersector, SHADOW_EPS_REL * radius, occlusion,
                           scene.alpha_at if scene.sheer else None)
    n_px, strata = width * height, k * k
    per_stratum, batches = sample_counts(spp, k, batches)
    slots = stratum_slots(seed, batches, n_px, strata) if strata > 1 else None
    eye = np.asarray(camera.eye, np.float64)
    forward = np.asarray(camera.target, np.float64) - eye
    edges = EdgeTest(n_px, 2.0 * np.tan(np.radians(camera.fov_y_deg) / 2.0) / height, eye,
                     forward / np.linalg.norm(forward))
    sums = np.zeros((batches, n_px, 3))   # per batch and pixel: the sum over its strata of their batch sums
    exact = np.zeros((n_px, 3))           # the sum over the strata of their mirror terms
    background = np.zeros((n_px, 3))      # the sum over the strata that miss of L along their rays
    opacity = np.zeros(n_px)              # the sum over the strata of the share of their ray the meshes stop
    for s in range(strata):
        origins, dirs = primary_rays(camera, width, height, centre, radius,
                                     stratum_positions(width, height, k, s, seed))
        live, weight = np.arange(n_px), np.ones(n_px)   # the rays still going on, the share of each left
        for layer in range(MAX_LAYERS):
            tri = scene.intersector.intersects_first(origins, dirs)
            hit = tri >= 0
            idx = live[hit]
            surf = _surface(scene, tri[hit], origins[hit], dirs[hit])
            alpha = scene.alpha_at(tri[hit], surf.x)
            seen = weight[hit] * alpha            # the share of the ray this layer's fibres stop
            exact[idx] += seen[:, None] * _integrate(
                sampler, tracer, surf, per_stratum, batches, seed, sums, idx, strata,
                None if slots is None else slots[:, idx, s], (() if strata == 1 else (strata, s)) + _layer(layer),
                seen)
            opacity[idx] += seen
            background[live[~hit]] += weight[~hit, None] * sampler.radiance(dirs[~hit])
            if layer == 0:
                edges.add(idx, scene.face_mesh[tri[hit]], surf.x, surf.n_geom)
            # Through the open weave: on from behind the sheet, with the share the fibres left.
            on = np.flatnonzero(weight[hit] * (1.0 - alpha) > MIN_RAY_SHARE)
            if on.size == 0:
                break
            origins = surf.x[on] - tracer.eps * surf.n_geom[on]
            dirs = dirs[hit][on]
            weight = weight[hit][on] * (1.0 - alpha[on])
            live = idx[on]
        else:   # the share still going after MAX_LAYERS sheets: what it would see beyond them
            background[live] += weight[:, None] * sampler.radiance(dirs)

    mean, std = _pixel_estimate(sums, per_stratum, strata)
    if exact.any():
        mean += exact / strata
    covered = edges.hits > 0
    std[~covered] = 0.0   # the background's L is exact (a pixel with one batch has std NaN)
    foreground = np.zeros((n_px, 4), np.float32)
    foreground[:, :3] = mean
    foreground[:, 3] = opacity / strata
    image = foreground.copy()
    image[:, :3] = mean + background / strata
    frames = tuple(a.reshape(height, width, -1) for a in (image, std.astype(np.float32), foreground))
    edge = edges.edges(strata).reshape(height, width)
    for a in (*frames, edge):
        a.setflags(write=False)
    image, noise, foreground = frames
    return ReferenceFrame(image, noise, per_stratum * strata, int(strata * n_px + tracer.rays_cast),
                          time.perf_counter() - t0, foreground, edge, k)


def _layer(layer: int) -> tuple:
    """Words appended to a chunk's seed for the sheets behind the first (none for the first)."""
    return () if layer == 0 else (1 << 20, layer)


def primary_rays(camera: Camera, width: int, height: int, centre: np.ndarray, radius: float,
                 positions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the pixel centres, row-major from the top row, or through `positions` (float64
    (N, 2), (x, y) in pixel units, x right from the image's left edge and y down from its top edge, so
    the centre of pixel (row, col) is (col + 0.5, row + 0.5)): (origins on the near plane, unit
    directions), each float64 (N, 3). Position (x, y) is NDC (x / W * 2 - 1, 1 - y / H * 2),
    unprojected through the inverse of the renderer's view-projection."""
    inv = np.linalg.inv(camera.view_proj(width / height, np.asarray(centre, np.float64), radius))
    if positions is None:
        y, x = np.meshgrid(1.0 - (np.arange(height) + 0.5) / height * 2.0,
                           (np.arange(width) + 0.5) / width * 2.0 - 1.0, indexing="ij")
        x, y = x.ravel(), y.ravel()
    else:
        x, y = positions[:, 0] / width * 2.0 - 1.0, 1.0 - positions[:, 1] / height * 2.0
    ends = []
    for z in (-1.0, 1.0):  # the near and far planes
        p = np.stack([x, y, np.full(x.size, z), np.ones(x.size)], axis=1) @ inv.T
        ends.append(p[:, :3] / p[:, 3:])
    d = ends[1] - ends[0]
    return ends[0], d / np.linalg.norm(d, axis=1, keepdims=True)


# --- scene ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _SceneArrays:
    """All meshes concatenated in order (vertex order kept), with per-vertex shading inputs."""

    positions: np.ndarray   # float64 (V, 3)
    faces: np.ndarray       # int64 (T, 3), indices into the concatenated vertices
    normals: np.ndarray     # float64 (V, 3), `vertex_normals` of each mesh
    albedo: np.ndarray      # float64 (V, 3)
    material: np.ndarray    # float64 (V, 2) = (specular, glossiness)
    pbr: np.ndarray         # float64 (V, 4) = (metallic, roughness, sheen roughness, 1) (zeros: Phong)
    sheen: np.ndarray       # float64 (V, 3) sheen colour
    uvs: np.ndarray         # float64 (V, 2) (zeros for meshes without UVs)
    face_mesh: np.ndarray   # int64 (T,) the mesh of each triangle
    maps: tuple             # per texture part: (albedo_map, gloss_map / metallic_roughness_map, sheen_map), each or None
    intersector: object     # trimesh.ray.ray_pyembree.RayMeshIntersector
    pbr_parts: tuple = ()   # per texture part: its material is "pbr"
    normal_maps: tuple = ()  # per texture part: (normal map or None, its scale)
    face_part: np.ndarray | None = None   # int64 (T,) the texture part of each triangle (a mesh's texture set)
    placements: tuple = ()  # per texture part: {map name: its (2, 3) placement} (TextureSet.placement)
    # Where a triangle's back is seen (Material.back): each triangle's texture part, and the per-vertex
    # arrays (albedo, material, pbr, sheen), of the side behind its winding (the front's without a back).
    face_part_back: np.ndarray | None = None
    back: tuple = ()
    # Per texture part: its material's anisotropy_rotation, in turns (Material; 0 where isotropic).
    anisotropy_rotations: tuple = ()
    # Per triangle: its sheet's alpha and transmission (Material: the front's, both sides').
    face_alpha: np.ndarray | None = None
    face_transmission: np.ndarray | None = None
    # Per texture part: its alpha map (TextureSet.alpha_texture), read on the front's parts alone.
    alpha_maps: tuple = ()

    @property
    def sheer(self) -> bool:
        return bool((self.face_alpha < 1.0).any()) or any(m is not None for m in self.alpha_maps)

    def alpha_at(self, tri: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The sheet's alpha (N,) at points (N, 3) on triangles tri (N,): the material's, times its
        front's alpha map at the point's UVs where its texture part has one."""
        alpha = self.face_alpha[tri]
        if not any(m is not None for m in self.alpha_maps):
            return alpha
        alpha = alpha.copy()
        part = self.face_part[tri]
        for i, alpha_map in enumerate(self.alpha_maps):
            sel = np.flatnonzero(part == i) if alpha_map is not None else ()
            if len(sel):
                f = self.faces[tri[sel]]
                p0, p1, p2 = (self.positions[f[:, k]] for k in range(3))
                bary = _barycentric(points[sel], p0, p1, p2)
                uv = np.einsum("nk,nkc->nc", bary, self.uvs[f])
                alpha[sel] *= _texture_bilinear(alpha_map, _placed(self.placements[i]["alpha"], uv))[:, 0]
        return alpha

    @property
    def transmits(self) -> bool:
        return bool((self.face_transmission > 0.0).any())

    @classmethod
    def build(cls, meshes: list[Mesh], materials: list[Material]) -> _SceneArrays:
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        meshes, materials = list(meshes), list(materials)
        if not meshes or len(meshes) != len(materials):
            raise InvalidInputError(f"need one material per mesh; got {len(meshes)} meshes, {len(materials)} materials")
        pos, faces, nrm, alb, mat, uvs, face_mesh, maps, pbr, sheen = [], [], [], [], [], [], [], [], [], []
        normal_maps, face_part, pbr_parts, placements, rotations, alpha_maps = [], [], [], [], [], []
        face_part_back, back_arrays, face_alpha, face_transmission = [], [], [], []
        offset = 0
        for i, (mesh, material) in enumerate(zip(meshes, materials)):
            if not isinstance(mesh, Mesh) or not isinstance(material, Material):
                raise InvalidInputError("meshes must be renderer.mesh.Mesh and materials renderer.shading.Material")
            n = mesh.n_vertices
            a, m = material.vertex_arrays(n)
            p, sh = material.pbr_arrays(n)
            pbr.append(p)
            sheen.append(sh)
            for side in material.sides():   # the front, then the back's own parts where it has one
                sets = side.face_texture_sets(mesh.faces, n)
                (face_part if side is material else face_part_back).append(sets.astype(np.int64) + len(maps))
                for ts in side.texture_groups():   # as the geometry pass draws them: one part per set
                    maps.append((*ts.maps(side.is_pbr), ts.sheen_texture()))
                    normal_maps.append((ts.normal_texture(), float(ts.normal_scale)))
                    pbr_parts.append(side.is_pbr)
                    placements.append({name: ts.placement(name) for name in MAP_NAMES})
                    rotations.append(float(side.anisotropy_rotation))
                    alpha_maps.append(ts.alpha_texture() if side is material else None)
            if material.back is None:
                face_part_back.append(face_part[-1])
                back_arrays.append((a, m, p, sh))
            else:
                back_arrays.append((*material.back.vertex_arrays(n), *material.back.pbr_arrays(n)))
            if material.has_textures() and mesh.uvs is None:
                raise MeshError(f"mesh {mesh.name!r} has material maps but no UVs")
            pos.append(mesh.positions)
            faces.append(mesh.faces.astype(np.int64) + offset)
            nrm.append(vertex_normals(mesh.positions, mesh.faces))
            alb.append(a)
            mat.append(m)
            uvs.append(mesh.uvs if mesh.uvs is not None else np.zeros((n, 2), np.float32))
            face_mesh.append(np.full(mesh.n_faces, i, np.int64))
            face_alpha.append(np.full(mesh.n_faces, float(material.alpha)))
            face_transmission.append(np.full(mesh.n_faces, float(material.transmission)))
            offset += n
        positions = np.concatenate(pos).astype(np.float64)
        faces = np.concatenate(faces)
        tm = trimesh.Trimesh(vertices=positions, faces=faces, process=False)
        fronts = (alb, mat, pbr, sheen)
        def cat(parts):
            return np.concatenate(parts).astype(np.float64)

        front_arrays = tuple(cat(a) for a in fronts)
        # The back's arrays where some material has a back, else the front's own (sided: no second mix).
        backs = (tuple(cat([b[k] for b in back_arrays]) for k in range(4))
                 if any(m.back is not None for m in materials) else front_arrays)
        return cls(positions, faces, cat(nrm), *front_arrays, cat(uvs),
                   np.concatenate(face_mesh), tuple(maps), RayMeshIntersector(tm),
                   tuple(pbr_parts), tuple(normal_maps), np.concatenate(face_part), tuple(placements),
                   np.concatenate(face_part_back), backs, tuple(rotations), np.concatenate(face_alpha),
                   np.concatenate(face_transmission), tuple(alpha_maps))


@dataclass
class _Surface:
    """Shading inputs at the N primary hits, float64."""

    x: np.ndarray          # (N, 3) hit points, on the triangle's plane
    n: np.ndarray          # (N, 3) shading normal, turned to the seen side of the triangle's plane
    n_geom: np.ndarray     # (N, 3) the triangle's plane normal, facing the camera (the side seen)
    r: np.ndarray          # (N, 3) reflection of the view ray about n
    albedo: np.ndarray     # (N, 3)
    specular: np.ndarray   # (N,)
    glossiness: np.ndarray  # (N,)
    v: np.ndarray | None = None       # (N, 3) towards the eye
    pbr: np.ndarray | None = None     # (N, 4) metallic, roughness, sheen roughness, 1 + anisotropy (0: Phong)
    sheen: np.ndarray | None = None   # (N, 3) sheen colour
    tangent: np.ndarray | None = None  # (N, 3) the anisotropy's direction (Material.anisotropy_rotation)
    transmission: np.ndarray | None = None  # (N,) the sheet's transmission (None: no sheet here transmits)


def _surface(scene: _SceneArrays, tri: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> _Surface:
    f = scene.faces[tri]
    p0, p1, p2 = (scene.positions[f[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    # Moller & Trumbore 1997 in float64 on the triangle embree reported (embree itself is float32).
    pvec = np.cross(dirs, e2)
    det = _dot(e1, pvec)
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    tvec = origins - p0
    b1 = _dot(tvec, pvec) / det
    b2 = _dot(dirs, np.cross(tvec, e1)) / det
    bary = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, None)
    bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-300)

    def mix(attr: np.ndarray) -> np.ndarray:  # barycentric interpolation of a per-vertex attribute
        return np.einsum("nk,nkc->nc", bary, attr[f])

    x = bary[:, 0:1] * p0 + bary[:, 1:2] * p1 + bary[:, 2:3] * p2
    n_geom = _normalize(np.cross(e1, e2), fallback=None)
    n = _normalize(mix(scene.normals), fallback=n_geom)
    # The triangle's back is seen where the ray runs along its winding's normal (the geometry pass's
    # culling of a two-sided material: renderer._draw_geometry).
    back_seen = _dot(n_geom, -dirs) < 0.0
    n_geom = np.where(back_seen[:, None], -n_geom, n_geom)  # the side the camera sees
    n = np.where(_dot(n, n_geom)[:, None] < 0.0, -n, n)  # two-sided: turned to the seen side, as in gbuffer.frag
    part_of = np.where(back_seen, scene.face_part_back[tri], scene.face_part[tri])
    for i, (normal_map, scale) in enumerate(scene.normal_maps):
        sel = np.flatnonzero(part_of == i) if normal_map is not None else ()
        if len(sel):
            n[sel] = _normal_mapped(n[sel], n_geom[sel], e1[sel], e2[sel],
                                    _placed(scene.placements[i]["normal"], scene.uvs[f[sel]]), bary[sel], normal_map,
                                    scale)
    r = dirs - 2.0 * _dot(dirs, n)[:, None] * n

    def sided(front: np.ndarray, back: np.ndarray) -> np.ndarray:
        if back is front:   # no material here has a back: one side's arrays
            return mix(front)
        return np.where(back_seen[:, None], mix(back), mix(front))

    albedo_b, material_b, pbr_b, sheen_b = scene.back
    albedo = sided(scene.albedo, albedo_b)
    material = sided(scene.material, material_b)
    pbr = sided(scene.pbr, pbr_b)
    pbr_of = scene.pbr_parts
    sheen = sided(scene.sheen, sheen_b)
    uv_all = mix(scene.uvs) if any(m is not None for maps in scene.maps for m in maps) else None
    for i, (albedo_map, gloss_map, sheen_map) in enumerate(scene.maps):
        sel = np.flatnonzero(part_of == i)
        if sel.size == 0 or (albedo_map is None and gloss_map is None and sheen_map is None):
            continue
        uv, placed = uv_all[sel], scene.placements[i]
        if albedo_map is not None:
            albedo[sel] *= _texture_bilinear(albedo_map, _placed(placed["albedo"], uv))
        if gloss_map is not None and pbr_of[i]:   # glTF's metallic-roughness texture
            pbr[sel, :2] *= _texture_bilinear(gloss_map, _placed(placed["second"], uv))
        elif gloss_map is not None:
            material[sel] = _texture_bilinear(gloss_map, _placed(placed["second"], uv))
        if sheen_map is not None:   # KHR_materials_sheen's colour and roughness textures
            texel = _texture_bilinear(sheen_map, _placed(placed["sheen"], uv))
            sheen[sel] *= texel[:, :3]
            pbr[sel, 2] *= texel[:, 3]
    tangent = None
    if (pbr[:, 3] > 1.0).any():
        turns = np.asarray(scene.anisotropy_rotations, np.float64)[part_of]
        tangent = anisotropy_direction(n, e1, e2, scene.uvs[f], turns)
    transmission = scene.face_transmission[tri] if scene.transmits else None
    return _Surface(x, n, n_geom, r, albedo, material[:, 0], np.clip(material[:, 1], 0.0, 1.0), -dirs,
                    pbr, sheen, tangent, transmission)


# Where a surface has no UV gradient (a mesh without UVs), an anisotropy's direction starts from the
# world's up axis in the surface's plane (the x axis where the surface faces up): gbuffer.frag's rule.
UP_AXIS, SIDE_AXIS = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])


def anisotropy_direction(n, e1, e2, uv_corners, turns) -> np.ndarray:
    """The unit direction (N, 3) an anisotropic highlight stretches along: the surface gradient of u in
    the plane of n (gbuffer.frag's frame, from the triangle's edges here), turned by `turns` (N,)
    counter-clockwise about n, from u towards v."""
    duv1, duv2 = uv_corners[:, 1] - uv_corners[:, 0], uv_corners[:, 2] - uv_corners[:, 0]
    t = np.cross(e2, n) * duv1[:, :1] + np.cross(n, e1) * duv2[:, :1]
    det = _dot(n, np.cross(e1, e2))
    t = np.where(det[:, None] < 0.0, -t, t)
    t = t - _dot(t, n)[:, None] * n
    length = np.linalg.norm(t, axis=1)
    up = np.where((np.abs(n[:, 1]) < 0.999)[:, None], UP_AXIS, SIDE_AXIS)
    fallback = up - _dot(up, n)[:, None] * n
    t = np.where((length > 1e-30)[:, None], t, fallback)
    t = _normalize(t, fallback=None)
    angle = 2.0 * np.pi * turns
    return np.cos(angle)[:, None] * t + np.sin(angle)[:, None] * np.cross(n, t)


def _placed(placement: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """UVs (..., 2) in a map's own (TextureSet.placement), as gbuffer.frag places them."""
    return uv @ placement[:, :2].T + placement[:, 2]


def _normal_mapped(n, n_geom, e1, e2, uv_corners, bary, normal_map, scale) -> np.ndarray:
    """The shading normal through a tangent-space normal map, in the frame gbuffer.frag builds (the
    surface gradients of u and v in the plane of n, from the triangle's edges here and the screen
    derivatives there: the same vectors), turned to the seen side as gbuffer.frag turns it."""
    duv1, duv2 = uv_corners[:, 1] - uv_corners[:, 0], uv_corners[:, 2] - uv_corners[:, 0]
    dp2perp, dp1perp = np.cross(e2, n), np.cross(n, e1)
    t = dp2perp * duv1[:, :1] + dp1perp * duv2[:, :1]
    b = dp2perp * duv1[:, 1:] + dp1perp * duv2[:, 1:]
    det = _dot(n, np.cross(e1, e2))
    m = np.maximum(_dot(t, t), _dot(b, b))
    ok = m > 1e-300
    s = np.where(det < 0.0, -1.0, 1.0) / np.sqrt(np.where(ok, m, 1.0))
    uv = np.einsum("nk,nkc->nc", bary, uv_corners)
    tn = _texture_bilinear(normal_map, uv) * 2.0 - 1.0
    mapped = s[:, None] * (t * (tn[:, :1] * scale) + b * (tn[:, 1:2] * scale)) + n * tn[:, 2:]
    mapped = _normalize(mapped, fallback=n)
    mapped = np.where(_dot(mapped, n_geom)[:, None] < 0.0, -mapped, mapped)
    return np.where(ok[:, None], mapped, n)


def _barycentric(points: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (N, 3) of points on (or near) triangles (p0, p1, p2), each (N, 3)."""
    e1, e2, d = p1 - p0, p2 - p0, points - p0
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    d1, d2 = _dot(d, e1), _dot(d, e2)
    det = d11 * d22 - d12 * d12
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    b1 = (d22 * d1 - d12 * d2) / det
    b2 = (d11 * d2 - d12 * d1) / det
    bary = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, None)
    return bary / np.maximum(bary.sum(axis=1, keepdims=True), 1e-300)


def _texture_bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with repeat wrapping, GL convention (uv (0, 0) is the bottom-left of the image,
    whose row 0 is its top, as `scene.SceneMesh` uploads it): img (H, W, C), uv (N, 2) -> (N, C)."""
    h, w = img.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = (1.0 - uv[:, 1]) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    out = 0.0
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            out = out + wy * wx * img[(y0 + dy) % h, (x0 + dx) % w].astype(np.float64)
    return out


# --- integration ------------------------------------------------------------------------------


class _ShadowTracer:
    """V(x, w): by any-hit queries where every sheet is opaque; where some is sheer, the product of
    (1 - alpha) over the sheets the ray crosses (closest-hit queries, sheet after sheet, at most
    MAX_LAYERS). Counts the rays it casts."""

    def __init__(self, intersector, eps: float, occlusion: bool = True, alpha_at=None):
        """alpha_at: the sheets' alpha at (triangles, points) (`_SceneArrays.alpha_at`); None: all opaque."""
        self.intersector, self.eps, self.occlusion, self.rays_cast = intersector, eps, occlusion, 0
        self.alpha_at = alpha_at

    def visible(self, x: np.ndarray, n_geom: np.ndarray, w: np.ndarray, behind: bool = False) -> np.ndarray:
        """(M,): w lies on the side of the surface n_geom faces (the other side with `behind`: the
        light a sheet's fibres pass on) and the ray from x, offset to that side, escapes: bool, or
        float where a sheet is sheer (the share of it that does). A direction on the sheet's other
        side goes through the sheet itself: no ray is cast (its fibres' share: `alpha` of the caller).
        Without occlusion, every direction is visible."""
        if not self.occlusion:
            return np.ones(len(w), bool)
        side = -1.0 if behind else 1.0
        vis = np.zeros(len(w), bool if self.alpha_at is None else np.float64)
        front = np.flatnonzero(side * _dot(n_geom, w) > 0.0)
        if front.size:
            origins = x[front] + (side * self.eps) * n_geom[front]
            if self.alpha_at is None:
                self.rays_cast += front.size
                vis[front] = ~self.intersector.intersects_any(origins, w[front])
            else:
                vis[front] = self._transmittance(origins, w[front])
        return vis

    def _transmittance(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        share = np.ones(len(dirs))
        live = np.arange(len(dirs))
        for _ in range(MAX_LAYERS):
            self.rays_cast += live.size
            tri, ray, where = self.intersector.intersects_id(origins, dirs, multiple_hits=False,
                                                             return_locations=True)
            if ray.size == 0:
                return share
            share[live[ray]] *= 1.0 - self.alpha_at(tri, where)
            on = np.flatnonzero(share[live[ray]] > 0.0)
            if on.size == 0:
                return share
            ray, tri = ray[on], tri[on]
            live = live[ray]
            dirs = dirs[ray]
            origins = where[on] + self.eps * dirs
        share[live] = 0.0
        return share


def _integrate(sampler: EnvironmentSampler, tracer: _ShadowTracer, surf: _Surface, spp: int, batches: int,
               seed: int, sums: np.ndarray, pixel: np.ndarray, strata: int = 1,
               slots: np.ndarray | None = None, stream: tuple = (), weight: np.ndarray | None = None) -> np.ndarray:
    """spp samples at each of one stratum's N hits (surf): adds each batch's sum of a hit's samples,
    times its weight (N,) (the share of its ray the hit's fibres stop; None: 1), to
    sums[batch, pixel[hit]] (sums (B, pixels, 3)) and returns the hits' exact mirror terms (N, 3),
    unweighted. A sheet that transmits reflects (1 - transmission) of its model's light and adds
    what its fibres pass on from behind (`_sample_transmitted`).
    slots: uint8 (B, N), each hit's block of its pixel's `strata` x n_b stratified slots per batch
    (None with one stratum); stream: words appended to every chunk's seed (the stratum's)."""
    n_px = len(surf.x)
    if n_px == 0:
        return np.zeros((0, 3))
    one_minus_g = 1.0 - surf.glossiness
    is_pbr = surf.pbr[:, 3] > 0.5 if surf.pbr is not None else np.zeros(n_px, bool)
    mirror = (surf.specular > 0) & (one_minus_g <= MIRROR_ONE_MINUS_G) & ~is_pbr
    has_d = (surf.albedo.max(axis=1) > 0) & ~is_pbr
    has_g = (surf.specular > 0) & ~mirror & ~is_pbr
    pbr = _PBRInputs.of(surf) if is_pbr.any() else None
    exponent = 1.0 / np.maximum(one_minus_g, MIRROR_ONE_MINUS_G)

    # Batch b holds the samples k = b, b + B, ...: n_b of them, summed per pixel into sums[b].
    counts = np.bincount(np.arange(spp) % batches, minlength=batches)
    per_chunk = max(1, RAYS_PER_CHUNK // n_px)  # samples per chunk
    px_chunk = min(n_px, RAYS_PER_CHUNK)
    for b, n_b in enumerate(counts):
        for j0 in range(0, n_b, per_chunk):
            n_j = min(per_chunk, n_b - j0)
            for p0 in range(0, n_px, px_chunk):
                p1 = min(n_px, p0 + px_chunk)
                rng = np.random.default_rng([seed, b, j0, p0, *stream])
                pix = np.tile(np.arange(p0, p1), n_j)
                j = np.repeat(np.arange(j0, j0 + n_j), p1 - p0)
                # Stratified within the pixel's batch (see the module doc): slot q of the pixel's
                # S n_b draws its texel from [q, q + 1) / (S n_b), its BRDF sample's polar angle from
                # the reversed slot.
                q, total = (j, n_b) if slots is None else (slots[b, pix].astype(np.int64) * n_b + j, n_b * strata)
                u_texel = (q + rng.random(len(j))) / total
                u_lobe = (total - 1 - q + rng.random(len(j))) / total
                if pbr is None:
                    est = _sample_chunk(sampler, tracer, surf, pix, has_d, has_g, exponent, rng, u_texel, u_lobe)
                else:   # the Phong pixels' techniques, then the physically based pixels'
                    est = np.zeros((len(pix), 3))
                    phong, physical = np.flatnonzero(~is_pbr[pix]), np.flatnonzero(is_pbr[pix])
                    if phong.size:
                        est[phong] = _sample_chunk(sampler, tracer, surf, pix[phong], has_d, has_g, exponent, rng,
                                                   u_texel[phong], u_lobe[phong])
                    if physical.size:
                        est[physical] = _sample_chunk_pbr(sampler, tracer, surf, pbr, pix[physical], rng,
                                                          u_texel[physical], u_lobe[physical])
                if surf.transmission is not None:
                    est = _with_transmitted(est, sampler, tracer, surf, pix, rng, u_texel, u_lobe)
                sum_j = est.reshape(n_j, p1 - p0, 3).sum(axis=0)
                sums[b, pixel[p0:p1]] += sum_j if weight is None else weight[p0:p1, None] * sum_j

    exact = np.zeros((n_px, 3))
    if mirror.any():  # deterministic: no variance
        idx = np.flatnonzero(mirror)
        w = surf.r[idx]
        vis = tracer.visible(surf.x[idx], surf.n_geom[idx], w)
        exact[idx] = surf.specular[idx, None] * sampler.radiance(w) * vis[:, None]
        if surf.transmission is not None:
            exact[idx] *= (1.0 - surf.transmission[idx])[:, None]
    return exact


def _with_transmitted(est: np.ndarray, sampler: EnvironmentSampler, tracer: _ShadowTracer, surf: _Surface,
                      pix: np.ndarray, rng: np.random.Generator, u_texel: np.ndarray,
                      u_lobe: np.ndarray) -> np.ndarray:
    """est (the reflected light's samples) times (1 - transmission), plus one sample of the light the
    fibres pass on: transmission x base x integral over the sheet's other side of L(w) V(x, w)
    max(0, -n.w) / pi dw (base: the albedo, x (1 - metallic) for a physically based pixel), by an
    environment sample and a cosine-weighted one about -n, combined by the power heuristic."""
    t = surf.transmission[pix]
    out = est * (1.0 - t)[:, None]
    idx = np.flatnonzero(t > 0.0)
    if idx.size == 0:
        return out
    p = pix[idx]
    tint = surf.albedo[p] * t[idx, None]
    if surf.pbr is not None:
        tint = np.where((surf.pbr[p, 3] > 0.5)[:, None], tint * (1.0 - np.clip(surf.pbr[p, :1], 0.0, 1.0)), tint)
    back, x, ng = -surf.n[p], surf.x[p], surf.n_geom[p]
    w, p_env = sampler.sample(idx.size, rng, u_texel[idx])
    radiance = sampler.radiance(w)
    q = np.maximum(_dot(back, w), 0.0) / np.pi
    need = (q > 0.0) & (radiance.max(axis=1) > 0.0)
    sel = np.flatnonzero(need)
    vis = tracer.visible(x[sel], ng[sel], w[sel], behind=True)
    out[idx[sel]] += (radiance[sel] * tint[sel] * (q[sel] * p_env[sel] / (p_env[sel] ** 2 + q[sel] ** 2)
                                                   * vis)[:, None])
    w, q = _sample_cosine(back, rng, u_lobe[idx])
    radiance, p_env = sampler.radiance_pdf(w)
    need = (q > 0.0) & (radiance.max(axis=1) > 0.0)
    sel = np.flatnonzero(need)
    vis = tracer.visible(x[sel], ng[sel], w[sel], behind=True)
    out[idx[sel]] += radiance[sel] * tint[sel] * (q[sel] ** 2 / (q[sel] ** 2 + p_env[sel] ** 2) * vis)[:, None]
    return out


def _pixel_estimate(sums: np.ndarray, spp: int, strata: int) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's mean (N, 3) and standard error (N, 3) from its batch sums (B, N, 3) over `strata`
    strata of `spp` samples each: the running mean and between-batch sum of squares of the pixel's batch
    means (Chan et al. 1979's pairwise update, batch by batch)."""
    batches = len(sums)
    counts = np.bincount(np.arange(spp) % batches, minlength=batches)
    mean = np.zeros(sums.shape[1:])
    between_ss = np.zeros(sums.shape[1:])
    done = 0
    for b, n_b in enumerate(counts):
        delta = sums[b] / (n_b * strata) - mean
        mean += delta * (n_b / (done + n_b))
        between_ss += delta ** 2 * (done * n_b / (done + n_b))
        done += n_b
    if batches >= 2:
        # E[sum_b n_b (m_b - m)^2] = (B - 1) sigma^2, sigma^2 the variance of one sample (of every stratum).
        return mean, np.sqrt(between_ss / (batches - 1) / spp)
    return mean, np.full(mean.shape, np.nan)


def _sample_chunk(sampler: EnvironmentSampler, tracer: _ShadowTracer, surf: _Surface, pix: np.ndarray,
                  has_d: np.ndarray, has_g: np.ndarray, exponent: np.ndarray, rng: np.random.Generator,
                  u_texel: np.ndarray, u_lobe: np.ndarray) -> np.ndarray:
    """One sample of every technique for each entry of pix (pixel indices, repeated per sample):
    the MIS-weighted contributions, float64 (M, 3)."""
    m = len(pix)
    est = np.zeros((m, 3))
    n, r, x, ng = surf.n[pix], surf.r[pix], surf.x[pix], surf.n_geom[pix]
    albedo, spec, s = surf.albedo[pix], surf.specular[pix], exponent[pix]
    d_on, g_on = has_d[pix], has_g[pix]

    # (a) environment sampling, shared by both terms.
    w, p_env = sampler.sample(m, rng, u_texel)
    radiance = sampler.radiance(w)
    cos_n = _dot(n, w)
    f_d = np.where(d_on & (cos_n > 0.0), cos_n / np.pi, 0.0)
    f_g = np.where(g_on, _phong_lobe(_dot(r, w), s), 0.0)
    # f * L * V / p_env * p_env^2 / (p_env^2 + q^2), with q = f for both BRDF-sampling techniques.
    weight = albedo * (f_d * p_env / (p_env ** 2 + f_d ** 2))[:, None] \
        + (spec * f_g * p_env / (p_env ** 2 + f_g ** 2))[:, None]
    need = ((f_d > 0.0) | (f_g > 0.0)) & (radiance.max(axis=1) > 0.0)
    _add_visible(est, need, tracer, x, ng, w, radiance * weight)

    # (b1) cosine-weighted hemisphere around n, for the diffuse term.
    idx = np.flatnonzero(d_on)
    if idx.size:
        w, q = _sample_cosine(n[idx], rng, u_lobe[idx])
        radiance, p_env = sampler.radiance_pdf(w)
        weight = albedo[idx] * (q ** 2 / (q ** 2 + p_env ** 2))[:, None]
        need = (q > 0.0) & (radiance.max(axis=1) > 0.0)
        _add_visible(est, need, tracer, x[idx], ng[idx], w, radiance * weight, idx)

    # (b2) Phong lobe around r, for the glossy term.
    idx = np.flatnonzero(g_on)
    if idx.size:
        w, q = _sample_phong(r[idx], s[idx], rng, u_lobe[idx])
        radiance, p_env = sampler.radiance_pdf(w)
        weight = (spec[idx] * q ** 2 / (q ** 2 + p_env ** 2))[:, None]
        need = (q > 0.0) & (radiance.max(axis=1) > 0.0)
        _add_visible(est, need, tracer, x[idx], ng[idx], w, radiance * weight, idx)
    return est


@dataclass(frozen=True)
class _PBRInputs:
    """The physically based pixels' parameters, all pixels (N, ...): the shading normal facing the
    eye (`facing_normal`), base colour, metallic, roughness and sheen roughness (clamped to the lobe
    tables' first node, as the shader clamps them), sheen colour, the sheen layer's albedo at the
    view (material_lobes: the same E the renderer reads), and the share of BRDF samples drawn from
    GGX's visible normals (the rest cosine-weighted, for the diffuse and sheen terms); where a
    material is anisotropic, each pixel's anisotropy and its direction, made perpendicular to the
    facing normal (None: every pixel isotropic)."""

    n: np.ndarray
    base: np.ndarray
    metallic: np.ndarray
    roughness: np.ndarray
    sheen: np.ndarray
    sheen_roughness: np.ndarray
    sheen_albedo: np.ndarray
    p_specular: np.ndarray
    anisotropy: np.ndarray | None = None
    tangent: np.ndarray | None = None

    @classmethod
    def of(cls, surf: _Surface) -> _PBRInputs:
        from ..lighting import material_lobes

        metallic = np.clip(surf.pbr[:, 0], 0.0, 1.0)
        roughness = np.clip(surf.pbr[:, 1], material_lobes.ROUGHNESS[0], 1.0)
        sheen_roughness = np.clip(surf.pbr[:, 2], material_lobes.ROUGHNESS[0], 1.0)
        n = facing_normal(surf.n, surf.v)
        e = material_lobes.load().sheen_albedo(sheen_roughness, _dot(n, surf.v))
        anisotropy = tangent = None
        if surf.tangent is not None:
            anisotropy = np.clip(surf.pbr[:, 3] - 1.0, 0.0, 1.0)
            tangent = brdf.tangent_frame(n, surf.tangent)[0]
        return cls(n, surf.albedo, metallic, roughness, surf.sheen, sheen_roughness, e, 0.5 + 0.4 * metallic,
                   anisotropy, tangent)

    def f(self, n, v, w, pix) -> np.ndarray:
        """The exact BRDF times n.w (M, 3), brdf.pbr."""
        tangent, anisotropy = (None, None) if self.tangent is None else (self.tangent[pix], self.anisotropy[pix])
        return brdf.pbr(n, v, w, self.base[pix], self.metallic[pix], self.roughness[pix], self.sheen[pix],
                        self.sheen_roughness[pix], self.sheen_albedo[pix], tangent, anisotropy)

    def frame(self, pix) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t, b, alpha_t, alpha_b) of the pixels' GGX layer: the anisotropy's frame, or any tangent
        frame of the normal where every pixel is isotropic (alpha_t = alpha_b = roughness^2)."""
        if self.tangent is None:
            t, b = _basis(self.n[pix])
            alpha = self.roughness[pix] ** 2
            return t, b, alpha, alpha
        t = self.tangent[pix]
        return (t, np.cross(self.n[pix], t), *brdf.anisotropic_alphas(self.roughness[pix], self.anisotropy[pix]))

    def pdf(self, n, v, w, pix) -> np.ndarray:
        """The density of the BRDF-sampling mixture at w (M,)."""
        h = brdf.half_vector(v, w)
        if self.tangent is None:
            alpha = self.roughness[pix] ** 2
            spec = brdf.ggx_reflection_pdf(_dot(n, v), np.clip(_dot(n, h), 0.0, 1.0), _dot(v, h), alpha)
        else:
            t, b, at, ab = self.frame(pix)
            spec = brdf.ggx_reflection_pdf_anisotropic(np.stack([_dot(v, t), _dot(v, b), _dot(v, n)], axis=1),
                                                       np.stack([_dot(h, t), _dot(h, b), _dot(h, n)], axis=1), at, ab)
        cosine = np.maximum(_dot(n, w), 0.0) / np.pi
        ps = self.p_specular[pix]
        return ps * spec + (1.0 - ps) * cosine


def _sample_chunk_pbr(sampler: EnvironmentSampler, tracer: _ShadowTracer, surf: _Surface, mat: _PBRInputs,
                      pix: np.ndarray, rng: np.random.Generator, u_texel: np.ndarray,
                      u_lobe: np.ndarray) -> np.ndarray:
    """One environment sample and one BRDF sample (GGX's visible normals with probability
    p_specular, else cosine-weighted) per entry of pix, combined by the power heuristic."""
    m = len(pix)
    est = np.zeros((m, 3))
    n, v, x, ng = mat.n[pix], surf.v[pix], surf.x[pix], surf.n_geom[pix]

    w, p_env = sampler.sample(m, rng, u_texel)
    radiance = sampler.radiance(w)
    f = mat.f(n, v, w, pix)
    q = mat.pdf(n, v, w, pix)
    need = (f.max(axis=1) > 0.0) & (radiance.max(axis=1) > 0.0)
    _add_visible(est, need, tracer, x, ng, w, radiance * f * (p_env / (p_env ** 2 + q ** 2))[:, None])

    specular = rng.random(m) < mat.p_specular[pix]
    w = np.empty((m, 3))
    idx = np.flatnonzero(~specular)
    if idx.size:
        w[idx] = _sample_cosine(n[idx], rng, u_lobe[idx])[0]
    idx = np.flatnonzero(specular)
    if idx.size:
        t, b, at, ab = mat.frame(pix[idx])
        vi = v[idx]
        v_local = np.stack([_dot(vi, t), _dot(vi, b), np.maximum(_dot(vi, n[idx]), 1e-6)], axis=1)
        v_local /= np.linalg.norm(v_local, axis=1, keepdims=True)
        h_local = brdf.sample_ggx_visible_normals(v_local, at, u_lobe[idx], rng.random(idx.size), ab)
        h = t * h_local[:, :1] + b * h_local[:, 1:2] + n[idx] * h_local[:, 2:]
        w[idx] = 2.0 * _dot(vi, h)[:, None] * h - vi
    f = mat.f(n, v, w, pix)
    q = mat.pdf(n, v, w, pix)
    radiance, p_env = sampler.radiance_pdf(w)
    need = (q > 0.0) & (f.max(axis=1) > 0.0) & (radiance.max(axis=1) > 0.0)
    q_safe = np.where(q > 0.0, q, 1.0)
    _add_visible(est, need, tracer, x, ng, w, radiance * f * (q_safe / (q_safe ** 2 + p_env ** 2))[:, None])
    return est


# A physically based pixel's shading normal is bent towards the view where it faces away by more than
# this (n.v below it): the BRDF is defined on the normal's hemisphere only, so a normal turned to the
# seen side that still leans away from the eye (a fold's lip, a silhouette) would reflect nothing.
# The same rule as shaders/shading/lobes.glsl (facing_normal); Phong pixels keep theirs.
MIN_N_DOT_V = 0.05


def facing_normal(n: np.ndarray, v: np.ndarray) -> np.ndarray:
    """n where n.v >= MIN_N_DOT_V; else the unit vector in the plane of n and v at n.v = MIN_N_DOT_V."""
    nv = _dot(n, v)
    p = n - nv[:, None] * v
    length = np.linalg.norm(p, axis=1, keepdims=True)
    bent = np.sqrt(1.0 - MIN_N_DOT_V ** 2) * p / np.maximum(length, 1e-300) + MIN_N_DOT_V * v
    return np.where((nv < MIN_N_DOT_V)[:, None] & (length > 1e-12), bent, n)


def _basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangents (t, b) of an orthonormal frame whose z is the unit axis (M, 3): Duff et al. 2017,
    "Building an orthonormal basis, revisited" (branchless, no singularity)."""
    ax, ay, az = axis[:, 0], axis[:, 1], axis[:, 2]
    sign = np.where(az >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + az)
    b = ax * ay * a
    return (np.stack([1.0 + sign * ax * ax * a, sign * b, -sign * ax], axis=1),
            np.stack([b, sign + ay * ay * a, -ay], axis=1))


def _add_visible(est, need, tracer, x, ng, w, value, idx=None) -> None:
    """est[idx][need] += value[need] times the share of the shadow ray that escapes."""
    sel = np.flatnonzero(need)
    vis = tracer.visible(x[sel], ng[sel], w[sel])
    if vis.dtype == bool:
        sel = sel[vis]
        target = sel if idx is None else idx[sel]
        est[target] += value[sel]  # one entry per pixel-sample: indices are unique
    else:
        target = sel if idx is None else idx[sel]
        est[target] += value[sel] * vis[:, None]


def _phong_lobe(cos_r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Normalized Phong lobe (s + 1) / (2 pi) max(0, cos)^s (paper Eq. 3; integrates to 1)."""
    c = np.maximum(cos_r, 0.0)
    with np.errstate(under="ignore"):
        return (s + 1.0) / (2.0 * np.pi) * c ** s


def _sample_cosine(n: np.ndarray, rng: np.random.Generator, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cosine-weighted directions around unit n (M, 3) (Malley's method: uniform on the disc, lifted to
    the hemisphere; sin^2 = u0) and their pdf cos / pi. u0 (M,): uniform numbers, possibly stratified."""
    rad, phi = np.sqrt(u0), 2.0 * np.pi * rng.random(len(n))
    cos_t = np.sqrt(np.maximum(1.0 - u0, 0.0))
    return _to_world(n, rad * np.cos(phi), rad * np.sin(phi), cos_t), cos_t / np.pi


def _sample_phong(r: np.ndarray, s: np.ndarray, rng: np.random.Generator,
                  u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions from the normalized Phong lobe around unit r (M, 3) with exponents s (M,): the CDF of
    cos is cos^(s + 1), so cos = u0^(1 / (s + 1)) (Lafortune & Willems 1994). Returns (dirs, pdf = lobe)."""
    cos_t = u0 ** (1.0 / (s + 1.0))
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    phi = 2.0 * np.pi * rng.random(len(r))
    w = _to_world(r, sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t)
    return w, _phong_lobe(cos_t, s)


def _to_world(axis: np.ndarray, lx: np.ndarray, ly: np.ndarray, lz: np.ndarray) -> np.ndarray:
    """Local (lx, ly, lz) in `_basis`'s frame about the unit axis (M, 3)."""
    t, bt = _basis(axis)
    w = t * lx[:, None] + bt * ly[:, None] + axis * lz[:, None]
    return w / np.linalg.norm(w, axis=1, keepdims=True)


# --- helpers ----------------------------------------------------------------------------------


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _normalize(v: np.ndarray, fallback: np.ndarray | None) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    ok = length > 1e-300
    out = v / np.where(ok, length, 1.0)
    return np.where(ok, out, np.asarray(FALLBACK_NORMAL) if fallback is None else fallback)


def _as_int(value, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise InvalidInputError(f"{name} must be an integer in [{lo}, {hi}]; got {value!r}")
    return int(value)


def _check_counts(width, height, spp, batches, seed) -> tuple[int, int, int, int, int]:
    return (_as_int(width, "width", 1, 8192), _as_int(height, "height", 1, 8192), _as_int(spp, "spp", 1, 1 << 20),
            _as_int(batches, "batches", 1, 1024), _as_int(seed, "seed", 0, 2**63 - 1))
