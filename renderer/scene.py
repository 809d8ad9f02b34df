"""GPU-resident meshes of a scene. Topology and materials are uploaded once; every frame only
writes new positions (and normals) into the existing buffers, so a service can render frame after
frame for hours without creating GL objects."""

from __future__ import annotations

import hashlib
import itertools
import math

import moderngl
import numpy as np

from .errors import MeshError
from .gpu.context import GLContext
from .gpu.contract import MAX_SHEET_MESHES, GeometryTexture, NormalsBuffer
from .gpu.shaders import set_uniform
from .mesh import FALLBACK_NORMAL, Mesh, box, box_corners, vertex_normals
from .shading.material import MAP_NAMES, Material, TextureSet
from .shadows.lights import RECEIVER_ONLY, SHADOW_GROUPS, shadow_groups  # noqa: F401 (Scene's vocabulary)
from .shadows.proxy import shadow_faces


def frustum_planes(view_proj: np.ndarray) -> np.ndarray | None:
    """The six planes (6, 4) of a world -> clip matrix's frustum, normalized so that
    p @ planes[:, :3].T + planes[:, 3] is each plane's signed distance in world units, >= 0 inside
    (None for a degenerate matrix)."""
    vp = np.asarray(view_proj, np.float64)
    planes = np.stack([vp[3] + vp[0], vp[3] - vp[0], vp[3] + vp[1], vp[3] - vp[1], vp[3] + vp[2], vp[3] - vp[2]])
    norms = np.linalg.norm(planes[:, :3], axis=1)
    if not np.all(norms > 0):
        return None
    return planes / norms[:, None]


# The 12 edges of a box or frustum by corner index (mesh.box_corners' order: corners one bit apart).
_BOX_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])


def _frustum(view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """A frustum's planes (frustum_planes) and its eight corners in world space (box_corners' order
    over NDC), or None for a degenerate matrix."""
    planes = frustum_planes(view_proj)
    if planes is None:
        return None
    try:
        inv = np.linalg.inv(np.asarray(view_proj, np.float64))
    except np.linalg.LinAlgError:
        return None
    f = np.c_[box_corners(-np.ones(3), np.ones(3)), np.ones(8)] @ inv.T
    return planes, f[:, :3] / f[:, 3:]


def box_in_frustum(lo, hi, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The axis-aligned box around the part of box (lo, hi) inside the frustum of `view_proj`, or
    None if none is."""
    frustum = _frustum(view_proj)
    return None if frustum is None else _clip_box(lo, hi, *frustum)


def _clip_box(lo, hi, planes: np.ndarray, frustum: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """`box_in_frustum` with the frustum's planes and corners given. The intersection is a convex
    polytope whose corners are the box's corners in the frustum, the frustum's corners in the box,
    and where the edges of either cross the other's faces."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    tol = 1e-9 * max(float(np.linalg.norm(hi - lo)), 1.0)
    box = box_corners(lo, hi)

    def in_frustum(q):
        return (q @ planes[:, :3].T + planes[:, 3] >= -tol).all(axis=1)

    def in_box(q):
        return ((q >= lo - tol) & (q <= hi + tol)).all(axis=1)

    points = [box[in_frustum(box)], frustum[in_box(frustum)]]
    # Box edges against the frustum's planes.
    a, b = box[_BOX_EDGES[:, 0]], box[_BOX_EDGES[:, 1]]
    da, db = a @ planes[:, :3].T + planes[:, 3], b @ planes[:, :3].T + planes[:, 3]    # (12, 6)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = da / (da - db)
    edge, plane = np.nonzero(np.isfinite(t) & (t >= 0.0) & (t <= 1.0))
    q = a[edge] + t[edge, plane][:, None] * (b - a)[edge]
    points.append(q[in_frustum(q)])
    # Frustum edges against the box's faces.
    a, b = frustum[_BOX_EDGES[:, 0]], frustum[_BOX_EDGES[:, 1]]
    for axis in range(3):
        for value in (lo[axis], hi[axis]):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (value - a[:, axis]) / (b[:, axis] - a[:, axis])
            ok = np.isfinite(t) & (t >= 0.0) & (t <= 1.0)
            q = a[ok] + t[ok, None] * (b - a)[ok]
            points.append(q[in_box(q)])
    points = np.concatenate(points)
    if not len(points):
        return None
    return points.min(axis=0), points.max(axis=0)


# Verdicts of convex_surface kept in the user's cache folder (user_cache.py), a few hundred bytes each.
CONVEXITY_CACHE_BYTES = 1 << 20


def convex_surface(positions: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the mesh bounds a convex volume, whichever way its triangles wind (cloth is two-sided):
    watertight once its vertices are merged by position (an OBJ's UV seams split them), one body, and
    convex at every edge, as trimesh judges them (its test reads the winding: an inward-wound mesh is
    turned first). A ball is; a body is not, nor a garment (a sheet). The verdict is kept in the
    user's cache folder, keyed by the arrays' bytes: a command that renders the same meshes again
    neither imports trimesh (half a second) nor merges their vertices."""
    if len(faces) == 0:
        return False
    from . import user_cache

    positions = np.ascontiguousarray(positions, np.float64)
    faces = np.ascontiguousarray(faces, np.int64)
    digest = hashlib.sha256(f"{positions.shape}{faces.shape}".encode())
    digest.update(positions.data)
    digest.update(faces.data)

    def judge() -> dict[str, np.ndarray]:
        import trimesh

        mesh = trimesh.Trimesh(positions, faces, process=True)
        if not mesh.is_watertight:   # a sheet: no volume to be convex
            return {"convex": np.array(False)}
        if mesh.volume < 0.0:
            mesh.invert()
        return {"convex": np.array(bool(mesh.is_convex))}

    verdict = user_cache.cached_arrays(user_cache.user_cache_dir("convexity"), digest.hexdigest()[:32],
                                       ("renderer.scene",), judge, CONVEXITY_CACHE_BYTES)
    return bool(verdict["convex"])


def longest_edge(positions: np.ndarray, faces: np.ndarray) -> float:
    """The longest edge of a triangle mesh (0 without faces)."""
    if len(faces) == 0:
        return 0.0
    tri = np.asarray(positions, np.float64)[faces]                      # (F, 3, 3)
    return float(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max())


# Work groups per dispatch dimension that every GL 4.5 driver takes (llvmpipe's limit): larger meshes'
# normals pass dispatches a second dimension.
MAX_GROUPS_X = 65535


_SERIALS = itertools.count()


def _seen_box(sm: SceneMesh, frustum: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """Scene.visible_bounds for one mesh: the part of its box in the frustum (a floor of two
    triangles), and within it the box of its vertices in view (a body whose head and legs are out of
    the frame), each plane moved out by the mesh's reach. None: nothing of it in view."""
    clipped = _clip_box(*sm.box, *frustum)
    if clipped is None:
        return None
    if np.allclose(clipped[0], sm.box[0]) and np.allclose(clipped[1], sm.box[1]):
        return clipped   # all in view: no vertex to leave out
    p = np.asarray(sm.positions, np.float32)
    # Plane by plane in float32 (one matrix-vector product each): 8 ms for 2M vertices here,
    # where one (V, 6) product in float64 took 200 ms of every frame.
    inside = np.ones(len(p), bool)
    for plane in frustum[0].astype(np.float32):
        inside &= p @ plane[:3] >= -sm.reach - plane[3]
    if not inside.any():
        return None
    seen = box(p[inside])
    return np.maximum(seen[0], clipped[0]), np.minimum(seen[1], clipped[1])


class SceneMesh:
    """One mesh's buffers, vertex arrays and material textures; owned by its `Scene`."""

    def __init__(self, gl: GLContext, mesh: Mesh, material: Material, programs: dict, caster: bool,
                 proxy_faces: dict[float, np.ndarray] | None = None, group: int = 0, pbr: bool = False):
        """`group`: the mesh's shadow group (Scene), 0 or 1 for a caster, RECEIVER_ONLY otherwise;
        `pbr`: the scene has a physically based material, so every mesh carries its parameters
        (zeros for a Phong one) to the geometry pass's PBR variant (programs["gbuffer_pbr"])."""
        ctx = gl.ctx
        self.mesh, self.material, self.caster, self.group = mesh, material, caster, group
        self.index = 0   # its place in its scene (Scene sets it)
        self.n_vertices = mesh.positions.shape[0]
        # Bumped by every set_positions: the shadow pass keeps the maps of casters that hold still
        # (shadows/vsm.py, the still group's layers) while their versions stay the same; the serial
        # tells this mesh from any other the process made (an id() can be reused once one is freed).
        self.version = 0
        self.serial = next(_SERIALS)
        # Scene.visible_bounds' box of this mesh, kept while it holds still: ((version, camera), box).
        self.seen_box: tuple | None = None
        self._pbr, self._programs = pbr, programs
        # Checked before any GL object exists, so that a refused proxy leaks nothing.
        self._check_maps(material)
        uvs = mesh.uvs if mesh.uvs is not None else np.zeros((self.n_vertices, 2), np.float32)
        self._proxy_faces = {}
        for detail, faces in (proxy_faces or {}).items():
            faces = np.asarray(faces)
            if faces.ndim != 2 or faces.shape[1] != 3 or (len(faces) and (faces.min() < 0 or faces.max() >= self.n_vertices)):
                raise MeshError(f"mesh {mesh.name!r}: a caster proxy must be (M, 3) indices of its {self.n_vertices} vertices")
            self._proxy_faces[float(detail)] = np.ascontiguousarray(faces, np.int32)
        self.positions = mesh.positions
        self.box = box(mesh.positions)   # (lo, hi), kept with the positions: read every frame
        # Twice the longest edge as registered (cloth stretches by far less): how far outside the
        # camera's frustum a vertex of a triangle that crosses it can lie (Scene.visible_bounds).
        self.reach = 2.0 * longest_edge(mesh.positions, mesh.faces)
        # A convex surface (a ball) sees only its own far side in its map from a light below its plane; a
        # body or a garment sees other parts of itself there too (shading/vsm.glsl, own_counts). Judged
        # at registration.
        # (A receiver that casts nothing is judged by no group of its own.)
        self.convex = caster and convex_surface(mesh.positions, mesh.faces)
        normals = vertex_normals(mesh.positions, mesh.faces)
        self.vbo_pos = ctx.buffer(np.ascontiguousarray(mesh.positions, np.float32).tobytes(), dynamic=True)
        self.vbo_nrm = ctx.buffer(normals.astype(np.float32).tobytes(), dynamic=True)
        self.vbo_uv = ctx.buffer(np.ascontiguousarray(uvs, np.float32).tobytes())
        self.ibo = ctx.buffer(np.ascontiguousarray(mesh.faces, np.int32).tobytes())
        # New positions' normals on the GPU (programs["normals"], Renderer's `normals`): the faces
        # around each vertex, made on the first frame that needs them.
        self._normals_prog = programs.get("normals")
        self._adjacency: tuple[moderngl.Buffer, moderngl.Buffer] | None = None
        self._ctx, self._moments_prog = ctx, programs["moments"]
        # The anti-aliasing's depth-only pass over every triangle (Renderer._coverage_pass), made on first use.
        self._coverage_prog = programs["coverage"]
        self._coverage_vao: moderngl.VertexArray | None = None
        # The shadow pass's triangles per detail (shadows/proxy.py shadow_faces: the proxy, light
        # facing): given (made off the GL thread by a caller that knows the detail it will use), else
        # made on first use per detail.
        self._proxies: dict[float, tuple[moderngl.Buffer, moderngl.VertexArray, int]] = {}
        # The material's buffers, textures and geometry-pass vertex array; more variants (colourways,
        # Scene.add_variant) share everything else.
        self.variants: list[MaterialBuffers] = [MaterialBuffers(self, material)]

    def _check_maps(self, material: Material) -> None:
        if material.has_textures() and self.mesh.uvs is None:
            raise MeshError(f"mesh {self.mesh.name!r} has material maps but no UVs")

    def add_variant(self, material: Material | None) -> None:
        """One more material for this mesh (a colourway; Scene.add_variant checked its maps): its own
        per-vertex buffers and textures, or None: the registered material's, shared."""
        self.variants.append(MaterialBuffers(self, material) if material is not None else self.variants[0])

    def drop_variants(self) -> None:
        """Back to the registered material alone."""
        for v in self.variants[1:]:
            if v is not self.variants[0]:
                v.release()
        del self.variants[1:]

    def shadow_vao(self, detail: float = 1.0) -> moderngl.VertexArray:
        """The casters' vertex array for the shadow pass at a share `detail` of the triangles (the
        same vertex buffer; its triangles are made once, from the mesh as registered, and drawn with
        back faces culled)."""
        detail = min(float(detail), 1.0)
        if detail not in self._proxies:
            faces = self._proxy_faces.pop(detail, None)
            if faces is None:
                faces = shadow_faces(self.mesh.positions, self.mesh.faces, detail)
            ibo = self._ctx.buffer(faces.tobytes())
            vao = self._ctx.vertex_array(self._moments_prog, [(self.vbo_pos, "3f", "in_position")],
                                         index_buffer=ibo, index_element_size=4)
            self._proxies[detail] = (ibo, vao, len(faces))
        return self._proxies[detail][1]

    def coverage_vao(self) -> moderngl.VertexArray:
        """The vertex array of the anti-aliasing's depth-only pass: every triangle, positions alone."""
        if self._coverage_vao is None:
            self._coverage_vao = self._ctx.vertex_array(self._coverage_prog, [(self.vbo_pos, "3f", "in_position")],
                                                        index_buffer=self.ibo, index_element_size=4)
        return self._coverage_vao

    def shadow_triangles(self, detail: float = 1.0) -> int:
        """Triangles the shadow pass draws per light at this detail (a piece drawn both ways twice)."""
        self.shadow_vao(detail)
        return self._proxies[min(float(detail), 1.0)][2]

    def set_positions(self, positions: np.ndarray, normals: np.ndarray | None = None) -> None:
        """New frame: positions (V, 3) float32 (validated by the caller through Mesh.with_positions);
        without `normals`, the area-weighted vertex normals are made from them, on the GPU when the
        renderer has the normals program."""
        if normals is None and self._normals_prog is None:
            normals = vertex_normals(positions, self.mesh.faces)
        self.positions = positions
        self.version += 1
        self.box = box(positions)
        self.vbo_pos.write(np.ascontiguousarray(positions, np.float32).tobytes())
        if normals is None:
            self._normals_on_gpu()
        else:
            self.vbo_nrm.write(np.ascontiguousarray(normals, np.float32).tobytes())

    def _normals_on_gpu(self) -> None:
        if self._adjacency is None:
            corners = self.mesh.faces.ravel()   # corner c of face c // 3 at vertex corners[c]
            order = np.argsort(corners, kind="stable")
            start = np.zeros(self.n_vertices + 1, np.int32)
            np.cumsum(np.bincount(corners, minlength=self.n_vertices), out=start[1:])
            self._adjacency = (self._ctx.buffer(start.tobytes()), self._ctx.buffer((order // 3).astype(np.int32).tobytes()))
        p = self._normals_prog
        p["u_n_vertices"].value = self.n_vertices
        p["u_fallback"].value = FALLBACK_NORMAL
        units = (NormalsBuffer.POSITIONS, NormalsBuffer.FACES, NormalsBuffer.ADJACENCY_START, NormalsBuffer.ADJACENCY,
                 NormalsBuffer.NORMALS)
        for unit, buf in zip(units, (self.vbo_pos, self.ibo, *self._adjacency, self.vbo_nrm), strict=True):
            buf.bind_to_storage_buffer(unit)
        groups = (self.n_vertices + 63) // 64
        p.run(min(groups, MAX_GROUPS_X), (groups + MAX_GROUPS_X - 1) // MAX_GROUPS_X)
        self._ctx.memory_barrier()   # the normals are read as a vertex attribute next

    def release(self) -> None:
        for buf in self._adjacency or ():
            buf.release()
        self._adjacency = None
        for ibo, vao, _ in self._proxies.values():
            vao.release()
            ibo.release()
        self._proxies = {}
        if self._coverage_vao is not None:
            self._coverage_vao.release()
            self._coverage_vao = None
        for v in {id(v): v for v in self.__dict__.get("variants", ())}.values():   # a shared one once
            v.release()
        for obj in (self.vbo_pos, self.vbo_nrm, self.vbo_uv, self.ibo):
            obj.release()


class TexturePart:
    """The triangles of a mesh that read one texture set (Material.texture_groups) on the GPU: its
    textures and the geometry pass's vertex array over them (all of the mesh's triangles when the
    material has one set)."""

    def __init__(self, ctx, textures: TextureSet, is_pbr: bool, program, attributes, ibo, n_faces: int,
                 anisotropy_rotation: float = 0.0, front: bool = True):
        self.textures = []
        # The material's anisotropy direction, radians from growing u (Material.anisotropy_rotation).
        self.anisotropy_rotation = 2.0 * math.pi * float(anisotropy_rotation)
        albedo_map, gloss_map = textures.maps(is_pbr)
        normal_map = textures.normal_texture()
        sheen_map = textures.sheen_texture()
        self.albedo_tex = self._texture(ctx, albedo_map, 3, (1.0, 1.0, 1.0))
        self.gloss_tex = self._texture(ctx, gloss_map, 2, (0.0, 0.0))
        self.normal_tex = self._texture(ctx, normal_map, 3, (0.5, 0.5, 1.0))
        self.sheen_tex = self._texture(ctx, sheen_map, 4, (1.0, 1.0, 1.0, 1.0))
        # The sheet's alpha map is its front's (TextureSet.alpha_map): a back's part reads none.
        alpha_map = textures.alpha_texture() if front else None
        self.alpha_tex = self._texture(ctx, alpha_map, 1, (1.0,))
        self.use_maps = (albedo_map is not None, gloss_map is not None, sheen_map is not None, alpha_map is not None)
        # The normal map's scale of x and y; 0: no normal map.
        self.normal_scale = float(textures.normal_scale) if normal_map is not None else 0.0
        # Each map's placement as gbuffer.frag's mat3x2 (column-major: the affine map's columns).
        self.placements = {name: textures.placement(name).T.astype(np.float32).tobytes() for name in MAP_NAMES}
        self.ibo = ibo   # owned here unless it is the mesh's own (one part)
        self.n_faces = n_faces
        self.vao = ctx.vertex_array(program, attributes, index_buffer=ibo, index_element_size=4, skip_errors=True)
        self._ctx, self._attributes, self._other_vaos = ctx, attributes, {}

    def vao_for(self, program) -> moderngl.VertexArray:
        """The part's vertex array for a variant of the geometry pass's program (its own, or one made
        once for another: the layers behind sheer cloth, renderer.py _sheer_layers)."""
        if program.glo == self.vao.program.glo:
            return self.vao
        if program.glo not in self._other_vaos:
            self._other_vaos[program.glo] = self._ctx.vertex_array(program, self._attributes, index_buffer=self.ibo,
                                                                   index_element_size=4, skip_errors=True)
        return self._other_vaos[program.glo]

    def _texture(self, ctx, data, comps, default):
        if data is None:
            data = np.asarray(default, np.float32).reshape(1, 1, comps)
        h, w = data.shape[:2]
        # Row 0 of an image is its top; GL's t = 0 is the bottom: flip so that uv (0, 0) is bottom-left.
        tex = ctx.texture((w, h), comps, np.ascontiguousarray(data[::-1], np.float32).tobytes(), dtype="f4")
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.textures.append(tex)
        return tex

    def bind(self, program) -> None:
        """The part's textures on their units (GeometryTexture) and its uniforms (gbuffer.frag)."""
        self.albedo_tex.use(location=GeometryTexture.ALBEDO_MAP)
        self.gloss_tex.use(location=GeometryTexture.GLOSS_MAP)
        self.normal_tex.use(location=GeometryTexture.NORMAL_MAP)
        self.sheen_tex.use(location=GeometryTexture.SHEEN_MAP)
        self.alpha_tex.use(location=GeometryTexture.ALPHA_MAP)
        set_uniform(program, "u_normal_scale", self.normal_scale)
        set_uniform(program, "u_use_albedo_map", self.use_maps[0])
        set_uniform(program, "u_use_gloss_map", self.use_maps[1])
        set_uniform(program, "u_use_sheen_map", self.use_maps[2])
        set_uniform(program, "u_use_alpha_map", self.use_maps[3])
        set_uniform(program, "u_anisotropy_rotation", self.anisotropy_rotation)
        for name, placement in self.placements.items():
            if f"u_{name}_placement" in program:
                program[f"u_{name}_placement"].write(placement)

    def release(self, own_ibo: bool) -> None:
        for obj in (self.vao, *self._other_vaos.values(), *self.textures, *((self.ibo,) if own_ibo else ())):
            obj.release()
        self._other_vaos = {}


class MaterialBuffers:
    """One material of a mesh on the GPU: its per-vertex buffers and, per texture set, the part of
    the mesh that reads it (TexturePart: one draw of the geometry pass each) over the mesh's own
    positions, normals and UVs (SceneMesh.variants)."""

    def __init__(self, sm: SceneMesh, material: Material, front: bool = True):
        ctx, n = sm._ctx, sm.n_vertices
        self.material = material
        albedo, mat = material.vertex_arrays(n)
        pbr_values, sheen = material.pbr_arrays(n) if sm._pbr else (None, None)
        groups = material.texture_groups()
        face_sets = material.face_texture_sets(sm.mesh.faces, n) if len(groups) > 1 else None
        self.buffers = [ctx.buffer(albedo.tobytes()), ctx.buffer(mat.tobytes())]
        if sm._pbr:
            self.buffers += [ctx.buffer(pbr_values.tobytes()), ctx.buffer(sheen.tobytes())]
        attributes = [(sm.vbo_pos, "3f", "in_position"), (sm.vbo_nrm, "3f", "in_normal"),
                      (self.buffers[0], "3f", "in_albedo"), (self.buffers[1], "2f", "in_material"),
                      (sm.vbo_uv, "2f", "in_uv")]
        if sm._pbr:
            attributes += [(self.buffers[2], "4f", "in_pbr"), (self.buffers[3], "3f", "in_sheen")]
        program = sm._programs["gbuffer_pbr" if sm._pbr else "gbuffer"]
        self.parts: list[TexturePart] = []
        self._own_ibos = face_sets is not None
        for k, textures in enumerate(groups):
            if face_sets is None:
                ibo, n_faces = sm.ibo, int(sm.mesh.faces.shape[0])
            else:
                faces = sm.mesh.faces[face_sets == k]
                if not len(faces):
                    continue   # a set no triangle reads
                ibo, n_faces = ctx.buffer(np.ascontiguousarray(faces, np.int32).tobytes()), len(faces)
            self.parts.append(TexturePart(ctx, textures, material.is_pbr, program, attributes, ibo, n_faces,
                                          material.anisotropy_rotation, front))
        # The cloth's other side (Material.back): drawn where the camera sees a triangle's back.
        self.back = MaterialBuffers(sm, material.back, front=False) if material.back is not None else None

    def release(self) -> None:
        for part in self.parts:
            part.release(self._own_ibos)
        for obj in self.buffers:
            obj.release()
        if self.back is not None:
            self.back.release()


class Scene:
    """Meshes of one scene (garment plus body, ...) with their materials, resident on the GPU."""

    def __init__(self, gl: GLContext, meshes: list[Mesh], materials: list[Material], programs: dict,
                 casters: list[bool] | None = None, proxies: dict[float, list[np.ndarray | None]] | None = None,
                 variants: list[list[Material | None]] | None = None):
        """`programs`: the renderer's "moments" and "gbuffer" programs (owned by the renderer);
        `proxies`: caster proxies made in advance, {detail: faces per mesh (None: make on use)};
        `variants`: colourways (`add_variant`) made with the scene, whose materials it is compiled for."""
        gl.check_thread()
        if not meshes:
            raise MeshError("a scene needs at least one mesh")
        if len(materials) != len(meshes):
            raise MeshError(f"got {len(meshes)} meshes but {len(materials)} materials")
        casters = casters or [True] * len(meshes)
        groups = shadow_groups(casters)
        self.gl = gl
        self.meshes: list[SceneMesh] = []
        self._group_alpha: tuple[float, float] | None = None
        # A physically based material anywhere: the geometry and lighting passes' PBR variants, and
        # whether any has a sheen layer (its lobes are compiled in only then).
        self.has_pbr = any(mat.is_pbr for mat in materials) or any(
            m is not None and m.is_pbr for v in variants or () for m in v)
        try:
            for detail, faces in (proxies or {}).items():
                if len(faces) != len(meshes):
                    raise MeshError(f"caster proxies at detail {detail}: got {len(faces)} face arrays for "
                                    f"{len(meshes)} meshes")
            for k, (m, mat, c) in enumerate(zip(meshes, materials, casters)):
                given = {d: faces[k] for d, faces in (proxies or {}).items() if faces[k] is not None}
                self.meshes.append(SceneMesh(gl, m, mat, programs, c, given, groups[k], self.has_pbr))
                self.meshes[-1].index = k   # its place in the scene (the id pass: renderer/aovs.py)
            # How many shadow groups cast (0-2): one casting mesh needs one pair of moments a texel.
            self.shadow_groups = len({sm.group for sm in self.meshes if sm.caster})
            self._shading_needs()
            # The length the shadow maps' footprint sizes are stepped against (fit_light_view_projs):
            # the casters' box diagonal at creation, fixed so that the steps do not follow the cloth,
            # and proportional to the scene so that its scale does not change the image.
            lo, hi = self.bounds(casters_only=True)
            diagonal = float(np.linalg.norm(np.asarray(hi, np.float64) - lo))
            self.footprint_unit = diagonal if np.isfinite(diagonal) and diagonal > 0.0 else 1.0
            for v in variants or ():
                self.add_variant(v)
        except Exception:
            self.release()
            raise

    @property
    def n_variants(self) -> int:
        """Material variants (colourways): 1, the registered materials, plus those added."""
        return len(self.meshes[0].variants)

    def add_variant(self, materials: list[Material | None]) -> int:
        """A colourway: one material per mesh (None: the mesh keeps its registered one, its buffers
        shared). Returns its index for `Renderer.render_views`. Only the geometry pass differs between
        variants: the shadow maps and the light plan are the frame's."""
        if len(materials) != len(self.meshes):
            raise MeshError(f"a colourway needs one material (or None) per mesh: {len(self.meshes)}, got {len(materials)}")
        if any(m is not None and m.is_pbr for m in materials) and not self.has_pbr:
            raise MeshError("a colourway with a physically based (pbr) material needs a scene registered with one: "
                            "this scene's materials are all Phong")
        for sm, m in zip(self.meshes, materials):   # every mesh checked before any is given a variant
            if m is not None:
                sm._check_maps(m)
                if abs(m.mean_alpha() - sm.material.mean_alpha()) > 1e-6:
                    raise MeshError(f"a colourway keeps its fabric's open weave: mesh {sm.index}'s alpha is "
                                    f"{sm.material.mean_alpha():g} over its area, the colourway's {m.mean_alpha():g} "
                                    "(the shadow maps, which every colourway shares, are drawn through it): give the "
                                    "colourway the fabric's alpha, or register a scene of its own for the other fabric")
        for sm, m in zip(self.meshes, materials):
            sm.add_variant(m)
        self._shading_needs()
        return self.n_variants - 1

    def drop_variants(self) -> None:
        """Back to the registered materials alone (what they read decides the shading again)."""
        for sm in self.meshes:
            sm.drop_variants()
        self._shading_needs()

    def _shading_needs(self) -> None:
        """What the materials of every variant ask of the shading: whether any has a sheen layer (its
        lobes are compiled in only then), the glossiest lookup any pixel can make
        (Material.max_glossiness; 0: no glossy lobe), and whether any pixel can have a glossy lobe at
        all (False: a diffuse-only scene)."""
        materials = [mb.material for sm in self.meshes for mb in sm.variants]
        self.has_sheen = any(m.has_sheen() for m in materials)
        self.max_glossiness = max(m.max_glossiness() for m in materials)
        self.has_glossy_lobe = any(m.has_glossy_lobe() for m in materials)
        # Sheer or transmitting cloth anywhere (Material.alpha, .transmission): the lighting pass's
        # variant that reads each mesh's pair, and for sheer cloth the layers seen through it.
        self.has_sheets = any(m.is_sheer or m.transmits for m in materials)
        self.sheer = any(m.is_sheer for m in materials)
        self.transmits = any(m.transmits for m in materials)
        if self.has_sheets and any(m.is_sheer or m.transmits for sm in self.meshes[MAX_SHEET_MESHES:]
                                   for m in (mb.material for mb in sm.variants)):
            raise MeshError(f"sheer or transmitting materials are drawn on a scene's first {MAX_SHEET_MESHES} "
                            "meshes; put those meshes first")

    def group_alpha(self) -> tuple[float, float]:
        """Each shadow group's casters' alpha over their area (Material.mean_alpha; the largest of its
        casters': a group whose casters differ is as opaque as its most opaque), which scales the
        occlusion its maps give (vsm.glsl): an alpha map's holes are not resolved in the shadows. The
        registered materials' (a colourway keeps them), so worked out once."""
        if self._group_alpha is None:
            out = [1.0, 1.0]
            for g in (0, 1):
                alphas = [sm.material.mean_alpha() for sm in self.meshes if sm.caster and sm.group == g]
                out[g] = max(alphas) if alphas else 1.0
            self._group_alpha = (out[0], out[1])
        return self._group_alpha

    def sheets(self, variant: int = 0) -> bytes:
        """(alpha, transmission) of each of the first MAX_SHEET_MESHES meshes in material variant
        `variant`, float32 pairs (the lighting pass's u_sheets; (1, 0) past the scene's meshes)."""
        out = np.zeros((MAX_SHEET_MESHES, 2), np.float32)
        out[:, 0] = 1.0
        for sm in self.meshes[:MAX_SHEET_MESHES]:
            m = sm.variants[variant].material
            out[sm.index] = (float(m.alpha), float(m.transmission))
        return out.tobytes()

    def set_positions(self, positions: list[np.ndarray | None], normals: list[np.ndarray | None] | None = None):
        self.gl.check_thread()
        if len(positions) != len(self.meshes):
            raise MeshError(f"got positions for {len(positions)} meshes, the scene has {len(self.meshes)}")
        normals = normals or [None] * len(positions)
        for sm, p, n in zip(self.meshes, positions, normals):
            if p is not None:
                sm.set_positions(p, n)

    def still_key(self, group: int) -> tuple:
        """What the shadow maps of one group's casters depend on in the scene: which meshes, and the
        version of their positions."""
        return tuple((sm.serial, sm.version) for sm in self.meshes if sm.caster and sm.group == group)

    def bounds(self, casters_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
        los, his = [], []
        for sm in self.meshes:
            if casters_only and not sm.caster:
                continue
            los.append(sm.box[0])
            his.append(sm.box[1])
        if not los:
            return self.bounds(False)
        return np.min(los, axis=0), np.max(his, axis=0)

    def visible_bounds(self, view_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The box of every mesh's vertices the camera (`view_proj`, world -> clip) can see, each
        frustum plane moved out by the mesh's reach (twice its longest edge) so that a triangle
        crossing the frame with its corners outside still counts (None: nothing in view). What the
        shadow maps are fitted to (shadows.lights.fit_light_view_projs' receivers)."""
        frustum = _frustum(view_proj)
        if frustum is None:
            return None
        vp_key = np.asarray(view_proj, np.float64).tobytes()
        los, his = [], []
        for sm in self.meshes:
            # A mesh that holds still (outside group 0: a body, a floor) keeps its box while it and the
            # camera do, as the geometry pass keeps its targets: a body's costs a millisecond a frame.
            key = (sm.version, vp_key)
            if sm.group != 0 and sm.seen_box is not None and sm.seen_box[0] == key:
                seen = sm.seen_box[1]
            else:
                seen = _seen_box(sm, frustum)
                sm.seen_box = (key, seen) if sm.group != 0 else None
            if seen is not None:
                los.append(seen[0])
                his.append(seen[1])
        if not los:
            return None
        return np.min(los, axis=0), np.max(his, axis=0)

    @property
    def n_triangles(self) -> int:
        return int(sum(sm.mesh.faces.shape[0] for sm in self.meshes))

    def release(self) -> None:
        for sm in self.meshes:
            sm.release()
        self.meshes = []
