"""The renderer a service holds for hours: PEM sets built once per environment map, scenes uploaded
once, then frame after frame with new vertex positions and no new GL objects.

A frame's path: positions -> normals -> shadow maps (moments, one per light) -> blur -> geometry
(position, normals, material per pixel) -> shading (paper Eq. 5, once per covered pixel) -> readback. Every stage is timed (wall clock after a finish; GPU timer queries where
the driver's are meaningful).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TypedDict

import moderngl
import numpy as np

from .aovs import from_gbuffer
from .camera import Camera, bounds_sphere, default_camera
from .config import MAX_LIGHTS
from .errors import InvalidInputError, RenderStoppedError
from .gpu import rawgl
from .gpu.context import GLContext, StageTimer
from .gpu.contract import (
    G_BUFFER_UNITS,
    SHEER_LAYERS,
    EdgeTexture,
    GeometryTexture,
    Image,
    LightingBuffer,
    LightingTexture,
    Mode,
)
from .gpu.shaders import compute_shader, program, set_uniform
from .lighting import material_lobes
from .lighting.pem import PEMSet
from .lighting.pem_plan import PAPER_PEMS, REGIONS_PER_TEXTURE, SUB_LIGHT_BYTES, PEMSettings
from .mesh import Mesh
from .plan import LightPlan, LightPlanner, discs_per_region, glossy_closed_form, no_diffuse_pems, snap_box
from .scene import Scene
from .settings import PAPER_FRAME, Background, FrameSettings, ShadingMode
from .shading.background import BackgroundMap
from .shading.material import Material
from .shadows.lights import LIGHT_DTYPE
from .shadows.vsm import LAYERS_PER_DRAW, ShadowMaps

_MODE_INDEX = {ShadingMode.FULL: Mode.FULL, ShadingMode.NO_OCCLUSION: Mode.NO_OCCLUSION, ShadingMode.AO_GREY: Mode.AO_GREY,
               ShadingMode.AO_COLOUR: Mode.AO_COLOUR, ShadingMode.MANY_LIGHTS: Mode.MANY_LIGHTS}




# The error split's oracle (render_views(visibility=)): (points, geometric normals, coverage) -> VIS_i.
VisibilityOracle = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


# Screen lines (slices) and steps per side of the contact-shadow search (lighting.frag).
CONTACT_SLICES, CONTACT_STEPS = 4, 8
# How far behind what the camera sees the contact search takes it to be solid, in units of its radius:
# a garment's near layer at a silhouette does not shadow the far layer from a light behind both
# (docs/sweep.md).
CONTACT_THICKNESS = 0.5

# A sample shows the surface a pixel's centre shaded when it lies within this many pixel footprints
# of that surface's plane (shaders/edges/resolve.frag): a sheet's neighbouring triangles do, a
# garment over the body a centimetre behind it at 256 x 256 does not.
EDGE_PLANE_TOLERANCE_PX = 1.0
# A pixel's samples lie in one plane when opposite samples' window depths sum alike within this
# (edges/classify.frag): a 24-bit depth buffer's step is ~6e-8.
PLANE_DEPTH_TOLERANCE = 1e-6


def _mat3_bytes(m: np.ndarray) -> bytes:
    """A 3 x 3 matrix as a GLSL mat3 uniform (column-major)."""
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()


def _plane_depth_tolerance(sample_positions: np.ndarray) -> float:
    """classify.frag's tolerance: PLANE_DEPTH_TOLERANCE where sample s and n - 1 - s of the driver's
    pattern lie opposite each other about the pixel's centre (the pattern has pairs to test a plane
    with), else -1: every pixel a surface touches is resolved as an edge."""
    n = len(sample_positions)
    symmetric = n >= 4 and np.allclose(sample_positions + sample_positions[::-1], 1.0, atol=1e-4)
    return PLANE_DEPTH_TOLERANCE if symmetric else -1.0




class FrameTimings(TypedDict):
    """What `Renderer.render` measured and did (JSON as it stands: the service and the benchmarks
    read it by these names)."""

    wall_ms: dict[str, float]        # per stage: upload, shadow_maps, blur, light_tables, geometry, shading,
                                     # sheer_layers (the geometry and blends behind sheer cloth), readback
    gpu_ms: dict[str, float]         # the same stages' GPU time where the driver has timer queries
    total_wall_ms: float             # the stages' sum
    frame_wall_ms: float             # the whole call
    n_lights: int
    shadowed_lights: int
    shadow_layers: int               # main-map layers drawn
    sharp_layers: int                # sharp-map layers drawn (lights sharing one count once)
    shadow_texel: float | None       # the main maps' median texel, world units
    n_triangles: int
    shadow_triangles: int            # triangles the shadow pass drew, proxies counted as drawn
    device: str                      # the GL renderer
    lighting_pass: str               # "fragment" or "compute"
    normals: str | None              # where new positions got their normals ("cpu", "gpu"; None: none came)
    views: int                       # frames that shared this one's upload and shadow maps (render_views)


@dataclass
class Frame:
    """A rendered frame. image: float32 (H, W, 4) linear HDR RGB + coverage alpha, row 0 at the top;
    aovs: the passes FrameSettings.aovs asked for (renderer/aovs.py), each float32 (H, W) or (H, W, 3)."""

    image: np.ndarray
    timings: FrameTimings
    settings: dict = field(default_factory=dict)
    aovs: dict = field(default_factory=dict)


@dataclass
class _FrameInputs:
    """What every view of a frame shades with, the lighting pass's inputs beyond its view: the scene, its
    PEM set and settings, the light plan, the shadow maps the shadow pass made (main and sharp arrays),
    the lights' buffer, the render targets (output and G-buffer), the glossy discs per region and the
    background."""

    scene: Scene
    pems: PEMSet
    settings: FrameSettings
    lp: LightPlan
    arrays: dict
    lights_buf: moderngl.Buffer
    fbo: object
    gbuf: list
    discs: int
    background: BackgroundMap | None


LIGHTING_PASSES = ("fragment", "compute")


def _geometry_targets(ctx: moderngl.Context, w: int, h: int, pbr: bool
                      ) -> tuple[list[moderngl.Texture], moderngl.Texture]:
    """The geometry pass's textures and depth buffer for a w x h image: position + specular, normal +
    glossiness, geometric normal, albedo (and with `pbr` the physically based materials' parameters),
    32-bit floats so that g = 1 - 1e-7 and positions far from the origin keep their precision."""
    gbuf = [ctx.texture((w, h), 4, dtype="f4") for _ in range(5 if pbr else 4)]
    for t in gbuf:
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
    # A texture, which the edges pass reads (edges/classify.frag).
    return gbuf, ctx.depth_texture((w, h))


class _StillTarget:
    """The targets of a pass for the meshes that hold still (Renderer._geometry_pass, _coverage_pass),
    of the frame's own formats, and what they were drawn for (`key`; None: nothing): the geometry
    pass's, or with `samples` the coverage pass's multisampled depth alone."""

    def __init__(self, ctx: moderngl.Context, w: int, h: int, pbr: bool, samples: int = 0):
        self.shape, self.key = (w, h, pbr, samples), None
        if samples:
            self.textures, self.depth = [], ctx.depth_texture((w, h), samples=samples)
        else:
            self.textures, self.depth = _geometry_targets(ctx, w, h, pbr)
        self.fbo = ctx.framebuffer(self.textures, self.depth)

    def release(self) -> None:
        for obj in (self.fbo, self.depth, *self.textures):
            obj.release()


class _SheerTargets:
    """Renderer._sheer_layers's: the last layer's depth, and a layer's lit colour over the geometry
    pass's depth (the lighting pass's test)."""

    def __init__(self, ctx: moderngl.Context, w: int, h: int, depth: moderngl.Texture):
        self.peel_depth = ctx.depth_texture((w, h))
        self.layer = ctx.texture((w, h), 4, dtype="f4")
        self.layer_fbo = ctx.framebuffer([self.layer], depth)

    def release(self) -> None:
        for obj in (self.layer_fbo, self.layer, self.peel_depth):
            obj.release()


class _Targets:
    """A frame's render targets for one image size, material kind and sample count: the lighting pass's
    output and the geometry targets it reads (`gbuf`), which share one depth buffer; with several
    samples a pixel (FrameSettings.aa_samples) also the coverage pass's multisampled depth (`ms_depth`)
    and the anti-aliased image (`final`), which `output_fbo`, the image read back, is then."""

    def __init__(self, ctx: moderngl.Context, w: int, h: int, pbr: bool, samples: int):
        self.key = (w, h, pbr, samples)
        self.samples = samples
        # A texture, so that the compute lighting pass can store into it (Renderer.lighting_pass).
        self.color = ctx.texture((w, h), 4, dtype="f4")
        self.gbuf, self.depth = _geometry_targets(ctx, w, h, pbr)
        self.image_fbo = ctx.framebuffer([self.color], self.depth)
        self.gbuf_fbo = ctx.framebuffer(self.gbuf, self.depth)
        self.ms_depth, self.ms_fbo, self.final, self.edge_marks, self.final_fbo = None, None, None, None, None
        self.sample_positions: np.ndarray | None = None   # (samples, 2) in the pixel, set by the coverage pass
        self._sheer: _SheerTargets | None = None
        if samples > 1:
            self.ms_depth = ctx.depth_texture((w, h), samples=samples)
            self.ms_fbo = ctx.framebuffer([], self.ms_depth)
            self.final = ctx.texture((w, h), 4, dtype="f4")
            self.edge_marks = ctx.depth_renderbuffer((w, h))   # the edge pixels (Renderer._edges_pass)
            self.final_fbo = ctx.framebuffer([self.final], self.edge_marks)

    @property
    def output_fbo(self):
        return self.final_fbo if self.samples > 1 else self.image_fbo

    def sheer_targets(self, ctx: moderngl.Context) -> _SheerTargets:
        """The layers behind sheer cloth's targets (made on first use)."""
        if self._sheer is None:
            w, h = self.key[:2]
            self._sheer = _SheerTargets(ctx, w, h, self.depth)
        return self._sheer

    def release(self) -> None:
        if self._sheer is not None:
            self._sheer.release()
        for obj in (self.final_fbo, self.edge_marks, self.final, self.ms_fbo, self.ms_depth, self.gbuf_fbo, self.image_fbo,
                    self.depth, *self.gbuf, self.color):
            if obj is not None:
                obj.release()


def default_lighting_pass(gl_renderer: str) -> str:
    """The lighting pass a GL renderer runs fastest: $GARMENT_RENDER_LIGHTING_PASS when set, else
    the fragment pass on llvmpipe (its early depth test skips uncovered blocks) and the compute pass
    on a GPU (an H100 runs fragment shaders on the few multiprocessors that can rasterize: 8.8 ms of
    GPU time against 1.0 ms; docs/gpu/README.md). `garment-render speed` times both. They give the
    same image (tests/test_render.py)."""
    return _by_renderer("GARMENT_RENDER_LIGHTING_PASS", LIGHTING_PASSES, gl_renderer)


def _by_renderer(variable: str, choices: tuple[str, str], gl_renderer: str, given: str | None = None,
                 what: str = "") -> str:
    """`given` (the argument `what`) when not None, else $variable when set, each one of `choices`;
    else choices[0] on Mesa's llvmpipe (the CPU: every pass shares the cores with Python and numpy)
    and choices[1] on a GPU."""
    name, chosen = (what, given) if given is not None else (f"${variable}", os.environ.get(variable))
    if chosen:
        if chosen not in choices:
            raise InvalidInputError(f"{name} must be one of {choices}, got {chosen!r}")
        return chosen
    return choices[0] if "llvmpipe" in gl_renderer.lower() else choices[1]


NORMALS = ("cpu", "gpu")


def default_normals(gl_renderer: str) -> str:
    """Where a frame's new positions get their vertex normals: $GARMENT_RENDER_NORMALS when set,
    else numpy on llvmpipe (a compute pass there runs on the same CPU cores, through a shader
    compiler's code instead of numpy's loops) and the compute pass on a GPU (on an H100 the upload
    stage of `speed --large` went from 32 ms to 1.1 ms; docs/gpu/README.md). `garment-render speed
    --large` times both. They give the same normals up to float32 rounding (tests/test_render.py)."""
    return _by_renderer("GARMENT_RENDER_NORMALS", NORMALS, gl_renderer)


class Renderer:
    """Owns the GL context (or borrows one) and the per-size GPU resources reused across frames."""

    def __init__(self, gl: GLContext | None = None, lighting_pass: str | None = None, normals: str | None = None):
        """`lighting_pass`: "fragment" (a full-screen triangle) or "compute"; `normals`: where a frame's
        new positions get their vertex normals, "cpu" (numpy) or "gpu" (a compute pass). None: what
        this GL renderer runs fastest (default_lighting_pass, default_normals)."""
        self._owns_gl = gl is None
        self.gl = gl or GLContext()
        ctx = self.gl.ctx
        try:
            name = self.gl.renderer_name
            self.lighting_pass = _by_renderer("GARMENT_RENDER_LIGHTING_PASS", LIGHTING_PASSES, name, lighting_pass,
                                              "lighting_pass")
            self.normals = _by_renderer("GARMENT_RENDER_NORMALS", NORMALS, name, normals, "normals")
        except InvalidInputError:
            if self._owns_gl:
                self.gl.release()
            raise
        defines = {"GLOSS_TABLE_SIZE": PEMSet.GLOSS_TABLE_SIZE, "REGIONS_PER_TEXTURE": REGIONS_PER_TEXTURE,
                   "MAX_LIGHTS": MAX_LIGHTS}
        # The lighting pass reads its per-light tables from uniform blocks where the driver's blocks
        # hold them (the light order and the contact search's table always do: 16 KiB, GL's least;
        # the lights and the glossy discs on llvmpipe and NVIDIA, 64 KiB): llvmpipe loads a uniform
        # block's entry once for a block of pixels and gathers a storage buffer's per pixel (the shirt
        # on its form, balanced: shading 135 -> about 70 ms); else from storage buffers.
        self._block_bytes = int(ctx.info["GL_MAX_UNIFORM_BLOCK_SIZE"])
        self._lights_block = self._uniform_block(MAX_LIGHTS * LIGHT_DTYPE.itemsize)
        if self._lights_block:
            defines["LIGHTS_CAPACITY"] = MAX_LIGHTS
        self._defines = defines
        self._shade_progs: dict[tuple, tuple[moderngl.Program, moderngl.VertexArray]] = {}
        # The background pass's programs, a cube's and a lat-long's (made on first use).
        self._bg_progs: dict[bool, tuple[moderngl.Program, moderngl.VertexArray]] = {}
        # The edges pass's programs (_edge_program), per program and sample count.
        self._edge_progs: dict[tuple[str, int], tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._shadow_maps: dict[str, ShadowMaps] = {}
        self._target: _Targets | None = None
        # The still meshes' targets of the geometry and coverage passes (_with_still_meshes).
        self._still_targets: dict[str, _StillTarget] = {}
        # Plans each frame's lights and maps on the CPU, keeping the last plan while it holds (renderer/plan.py).
        self.planner = LightPlanner()
        self.geometry_still_hits = 0   # frames whose still meshes were copied, not drawn (tests)
        self._readback: np.ndarray | None = None
        self._buffers: dict[str, moderngl.Buffer] = {}
        self._sheen_offsets: dict[str, int] = {}   # per lobe table (`_lobe_table`)
        self._gloss_buf = ctx.buffer(reserve=4 * PEMSet.GLOSS_TABLE_SIZE)
        # The moments program is needed to build vertex arrays before any shadow map exists.
        self._shadow_prog = program(ctx, "shadows/moments.vert", "shadows/moments.frag",
                                    {"LAYERS_PER_DRAW": LAYERS_PER_DRAW})
        self.gbuffer_prog = program(ctx, "shading/surface.vert", "shading/gbuffer.frag")
        self._programs = {"moments": self._shadow_prog, "gbuffer": self.gbuffer_prog,
                          "coverage": program(ctx, "edges/coverage.vert", "edges/coverage.frag")}
        if self.normals == "gpu":
            self._programs["normals"] = compute_shader(ctx, "mesh/normals.comp")

    def _background_program(self, latlong: bool) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """The background pass's program for a lat-long texture or a cube (shading/background.frag)."""
        if latlong not in self._bg_progs:
            prog = program(self.gl.ctx, "shading/background.vert", "shading/background.frag",
                           {"BACKGROUND_LATLONG": 1} if latlong else None)
            self._bg_progs[latlong] = (prog, self.gl.ctx.vertex_array(prog, []))
        return self._bg_progs[latlong]

    def _shade_variant(self, mode: ShadingMode, diffuse: str, two_textures: bool,
                       glossy: str = "pem", contact: bool = False, sub_lights: int = 1,
                       lobes: tuple[int, int] | None = None, blocker: bool = False, oracle: bool = False,
                       catcher: bool = False, sheets: str | bool = False
                       ) -> tuple[moderngl.Program | moderngl.ComputeShader, moderngl.VertexArray | None]:
        """The lighting program of a mode and diffuse source (a full-screen pass over the geometry
        pass's targets), compiled on first use (one variant each; the diffuse source matters to the
        full and no-occlusion modes only); `two_textures`: the PEM set spans two textures (more than
        REGIONS_PER_TEXTURE regions), whose second needs loops of its own; `sub_lights`: discs per
        region in the glossy closed form (FrameSettings.sub_lights; 1 where no glossy term is in
        closed form, plan.discs_per_region); `lobes`: (GGX lobes, sheen lobes) of a scene with a
        physically based material (None: Phong materials only, one lobe a pixel); `blocker`: some
        light's penumbra follows the blocker's distance (FrameSettings.penumbra, area lights); `oracle`:
        the full mode with each light's visibility read from a texture (`render_views(visibility=)`);
        `catcher`: the full mode's shadow catcher (Background.SHADOW_CATCHER); `sheets`: "sheer" or
        "transmission" where some mesh is sheer or some transmits (Scene.has_sheets: each mesh's pair
        read by its id; the transmitted term compiled in for "transmission" alone)."""
        closed = no_diffuse_pems(mode, diffuse)
        wide = glossy_closed_form(mode, glossy)
        oracle = oracle and mode is ShadingMode.FULL
        contact = contact and mode is ShadingMode.FULL and not oracle
        blocker = blocker and not oracle
        compute = self.lighting_pass == "compute"
        catcher = catcher and mode is ShadingMode.FULL
        key = (mode, diffuse if closed else "pem", two_textures, wide, contact, compute, sub_lights, lobes, blocker,
               oracle, catcher, sheets)
        if key not in self._shade_progs:
            defines = {**self._defines, "MODE": int(_MODE_INDEX[mode]), "TWO_PEM_TEXTURES": int(two_textures)}
            if wide:
                defines["GLOSSY_WIDE"] = 1   # large lights' glossy term in closed form where the lobe is wide
            if closed:
                defines["DIFFUSE_LIGHTS"] = 1   # no diffuse PEM lookups
            if sub_lights > 1:
                defines["SUB_LIGHTS"] = sub_lights
                if self._sub_lights_block(sub_lights):
                    defines["SUB_LIGHTS_CAPACITY"] = MAX_LIGHTS * sub_lights
            if lobes is not None:
                defines.update(PBR=1, LOBES_GGX=lobes[0], LOBES_SHEEN=lobes[1], TABLE_R=len(material_lobes.ROUGHNESS),
                               TABLE_J=len(material_lobes.THETA_V), TABLE_R0=f"{material_lobes.ROUGHNESS[0]:.9g}",
                               TABLE_THETA_MAX=f"{material_lobes.THETA_V[-1]:.9g}")
            if blocker:
                defines["PENUMBRA_BLOCKER"] = 1
            if oracle:
                defines["ORACLE_VISIBILITY"] = 1
            if catcher:
                defines["SHADOW_CATCHER"] = 1
            if sheets:
                defines["SHEETS"] = 1
                if sheets == "transmission":
                    defines["TRANSMISSION"] = 1
            if contact:
                defines.update(CONTACT_SHADOWS=1, CONTACT_SLICES=CONTACT_SLICES, CONTACT_STEPS=CONTACT_STEPS)
            if compute:
                defines["LIGHTING_COMPUTE"] = 1
                self._shade_progs[key] = (compute_shader(self.gl.ctx, "shading/lighting.frag", defines), None)
            else:
                prog = program(self.gl.ctx, "shading/background.vert", "shading/lighting.frag", defines)
                self._shade_progs[key] = (prog, self.gl.ctx.vertex_array(prog, []))
        return self._shade_progs[key]

    def _uniform_block(self, size: int) -> int:
        """`size` when a uniform block of that many bytes fits the driver's, else 0 (a storage buffer
        instead)."""
        return size if size <= self._block_bytes else 0

    def _sub_lights_block(self, sub_lights: int) -> int:
        """The bytes of the glossy discs' uniform block at `sub_lights` discs per light (0: a storage
        buffer)."""
        return self._uniform_block(MAX_LIGHTS * sub_lights * SUB_LIGHT_BYTES)

    # -- resources --------------------------------------------------------------------------
    def build_pems(self, cube: np.ndarray, settings: PEMSettings = PAPER_PEMS,
                   timer: StageTimer | None = None) -> PEMSet:
        """Build the PEM set of a cube map (6, F, F, 3); the caller owns it (cache it per map)."""
        return PEMSet(self.gl, cube, settings, timer)

    def pem_set(self, env, settings: PEMSettings, cache: bool = True) -> PEMSet:
        """`env`'s (an EnvironmentMap) PEM set for `settings` (Quality.pems(materials=...)): from the
        user's cache folder when a process made it before (user_cache.py), else built and stored there
        for the next one (the light decomposition is in it); `cache` False: built and not stored. Its
        `source` says which ("disk" or "built"); the caller owns it (release())."""
        if not cache:
            return self.build_pems(env.cube, settings)
        from .cache import PEMCache
        from .user_cache import user_cache_dir

        store = PEMCache(self.gl, disk_dir=user_cache_dir("pem-sets"), name="user")
        pems = store.get(env.content_hash, env.cube, settings)
        pems.source = "disk" if store.stats.disk_hits else "built"
        return pems

    def create_scene(self, meshes: list[Mesh], materials: list[Material] | None = None,
                     casters: list[bool] | None = None,
                     proxies: dict[float, list[np.ndarray | None]] | None = None,
                     variants: list[list[Material | None]] | None = None, catcher: int | None = None) -> Scene:
        """`proxies`: the shadow pass's triangles (shadows/proxy.py shadow_faces) made in advance off
        the GL thread, per detail one face array per mesh (None: made on first use); a 4M-triangle mesh takes seconds.
        `variants`: colourways, one material (or None: the mesh's own) per mesh each (Scene.add_variant).
        `catcher`: the mesh (a floor, casting nothing) a shadow-catcher frame draws as its shadows alone
        (Background.SHADOW_CATCHER; procedural.floor_under makes one)."""
        if catcher is not None and (isinstance(catcher, bool) or not isinstance(catcher, (int, np.integer))
                                    or not 0 <= catcher < len(meshes)):
            raise InvalidInputError(f"catcher must name one of the {len(meshes)} meshes by its place, got {catcher!r}")
        materials = materials or [Material() for _ in meshes]
        everything = list(materials) + [m for v in variants or () for m in v if m is not None]
        if any(isinstance(m, Material) and m.is_pbr for m in everything) and "gbuffer_pbr" not in self._programs:
            self._programs["gbuffer_pbr"] = program(self.gl.ctx, "shading/surface.vert", "shading/gbuffer.frag",
                                                    {"PBR": 1})
        scene = Scene(self.gl, meshes, materials, self._programs, casters, proxies, variants)
        scene.catcher = None if catcher is None else int(catcher)
        return scene

    def _shadow_maps_for(self, which: str, size: int, n_lights: int, groups: int) -> ShadowMaps:
        """The main ("main") or small lights' ("sharp") shadow-map array, re-made only when its size,
        layer count or shadow groups change."""
        sm = self._shadow_maps.get(which)
        if sm is None or sm.size != size or sm.n_lights != n_lights or sm.groups != groups:
            if sm is not None:
                del self._shadow_maps[which]   # a failed allocation below leaves no released array behind
                sm.release()
            sm = self._shadow_maps[which] = ShadowMaps(self.gl, size, n_lights, self._shadow_prog, groups)
        return sm

    def _target_for(self, w: int, h: int, pbr: bool = False, samples: int = 1) -> _Targets:
        """The frame's render targets (_Targets) of an image size, made anew when it, the material kind
        (`pbr`: a fifth geometry target for the physically based materials' parameters) or the samples
        a pixel change."""
        if self._target is None or self._target.key != (w, h, pbr, samples):
            if self._target is not None:
                self._target.release()
                self._target = None   # a failed allocation below leaves no released targets behind
            self.check_device(samples)
            self._target = _Targets(self.gl.ctx, w, h, pbr, samples)
        return self._target

    def check_device(self, aa_samples: int) -> None:
        """InvalidInputError naming the limit where this GL renderer cannot take a frame's samples a pixel
        (GL_MAX_SAMPLES: 4 on llvmpipe): what a service checks when a scene is registered."""
        if aa_samples > 1 and aa_samples > self.gl.ctx.max_samples:
            raise InvalidInputError(f"aa_samples must be at most {self.gl.ctx.max_samples} on this GL renderer "
                                    f"({self.gl.renderer_name}), got {aa_samples}")

    def _buffer(self, name: str, data: bytes, size: int | None = None) -> moderngl.Buffer:
        """A per-frame buffer holding `data` (at its start), re-created only when its size (that of
        the data, or `size` bytes: a uniform block's whole declared size) changes."""
        size = len(data) if size is None else size
        buf = self._buffers.get(name)
        if buf is None or buf.size != size:
            if buf is not None:
                buf.release()
            buf = self._buffers[name] = self.gl.ctx.buffer(reserve=size)
        buf.write(data)
        return buf

    # -- a frame ----------------------------------------------------------------------------
    def background_map(self, source: np.ndarray) -> BackgroundMap:
        """The background of a map (`render(..., background=)`): a lat-long source image (H, W, 3)
        itself, or a cube (6, F, F, 3) resampled from another layout at twice its density
        (`shading.background.background_face_size`); with its MIP chain."""
        self.gl.check_thread()
        return BackgroundMap(self.gl, source)

    def render(self, scene: Scene, pems: PEMSet, settings: FrameSettings = PAPER_FRAME,
               camera: Camera | None = None, positions: list[np.ndarray | None] | None = None,
               normals: list[np.ndarray | None] | None = None, background: BackgroundMap | None = None,
               visibility: VisibilityOracle | None = None) -> Frame:
        """One frame. background: the map seen behind the scene (`background_map`); None shows the
        PEM set's own cube, as coarse as its faces. The stages: upload, the light plan (numpy), the
        shadow maps, the geometry pass, the lighting pass, the readback. `visibility`: see render_views."""
        return self.render_views(scene, pems, settings, [camera], positions, normals, background,
                                 visibility=visibility)[0]

    def render_views(self, scene: Scene, pems: PEMSet, settings: FrameSettings = PAPER_FRAME,
                     cameras: list[Camera | None] = (None,), positions: list[np.ndarray | None] | None = None,
                     normals: list[np.ndarray | None] | None = None, background: BackgroundMap | None = None,
                     variants: list[int] = (0,), visibility: VisibilityOracle | None = None,
                     stop: Callable[[], bool] | None = None) -> list[Frame]:
        """One frame of the scene seen from several cameras (a turntable, named views) in several
        material variants (colourways, `Scene.add_variant`): the positions are uploaded, the lights
        planned and the shadow maps drawn once (they are in light space, fitted to what any camera
        sees), then each (camera, variant) pair has its own geometry pass, lighting pass and readback.
        Frames come camera by camera, each camera's variants in the order given. The first frame's
        timings hold the shared stages; every frame's hold its own passes (`views`: how many frames
        shared them).

        `visibility` (the error split's oracle, full mode only; renderer/reference/visibility.py): a
        function of the geometry pass's surface points and geometric normals (float32 (H, W, 3) each,
        row 0 at the bottom) and their coverage (bool (H, W)) that gives every light's VIS_i there
        (float32 (n_lights, H, W)); the lighting pass reads it instead of the shadow maps and the
        contact search, and shades as ever.

        `stop`: asked before every image but the first; when it answers True the render ends there
        with `RenderStoppedError` (a service's request that timed out or whose client left)."""
        gl = self.gl
        gl.check_thread()
        if settings.background is Background.SHADOW_CATCHER and getattr(scene, "catcher", None) is None:
            raise InvalidInputError("a shadow-catcher frame needs the scene's floor: create_scene(..., catcher=k) "
                                    "with k its place (procedural.floor_under makes one under the meshes)")
        cameras = list(cameras) or [None]
        variants = list(variants) or [0]
        for v in variants:
            if not 0 <= v < scene.n_variants:
                raise InvalidInputError(f"material variant {v} is not in the scene (it has {scene.n_variants})")
        shared = StageTimer()
        t_frame = time.perf_counter()

        t0 = time.perf_counter()
        if positions is not None:
            scene.set_positions(positions, normals)
        shared.wall_ms["upload"] = (time.perf_counter() - t0) * 1e3

        # The cameras first: the shadow maps are fitted to what they see.
        w, h = settings.width, settings.height
        lo, hi = scene.bounds()
        centre, radius = bounds_sphere(lo, hi)
        cameras = [c or default_camera(centre, radius, w / h) for c in cameras]
        view_projs = [c.view_proj(w / h, centre, radius) for c in cameras]
        # The geometry pass's depth ranges fitted to the scene's box snapped outwards (snap_box): the
        # same while a garment moves within its cells, so that it keeps what holds still
        # (_geometry_pass). Depth is its alone: x, y and w, which the other passes read, are the same.
        snapped = bounds_sphere(*snap_box(lo, hi, scene.footprint_unit))
        depth_vps = [c.view_proj(w / h, *snapped).T.astype(np.float32).tobytes() for c in cameras]
        # What any camera sees (a camera that sees nothing adds nothing; none seeing anything: the casters).
        seen = [b for b in (scene.visible_bounds(vp) for vp in view_projs) if b is not None]
        receivers = (np.min([b[0] for b in seen], axis=0), np.max([b[1] for b in seen], axis=0)) if seen else None
        # A turned environment: the set's view whose lights are turned (the same textures).
        pems = pems.turned(settings.environment_rotation_deg)
        lp = self.planner.plan(scene, pems, settings, receivers)
        # One buffer for the storage-buffer readers and, where it fits, the lighting pass's uniform block
        # (then the block's whole declared size).
        lights_buf = self._buffer("lights", lp.lights.tobytes(), self._lights_block or None)
        arrays = self._shadow_pass(scene, settings, lp, lights_buf, shared)

        targets = self._target_for(w, h, scene.has_pbr, settings.aa_samples)
        if settings.aa_samples == 1 and "coverage" in self._still_targets:   # no coverage pass now: its memory back
            self._still_targets.pop("coverage").release()
        fbo, gbuf = targets.image_fbo, targets.gbuf
        # The PEM set's tables the shading pass reads (the glossy discs), made once per set when a
        # frame first asks for them: that frame reports them as their own stage.
        discs = discs_per_region(settings)
        t0 = time.perf_counter()
        if pems.prepare_tables(discs):
            shared.wall_ms["light_tables"] = (time.perf_counter() - t0) * 1e3
        shared_ms = (time.perf_counter() - t_frame) * 1e3
        report = self._frame_report(scene, pems, settings, lp, arrays, positions is not None,
                                    len(cameras) * len(variants))
        inputs = _FrameInputs(scene, pems, settings, lp, arrays, lights_buf, fbo, gbuf, discs, background)
        frames = []
        for camera, view_proj, depth_vp in zip(cameras, view_projs, depth_vps):
            vp_bytes = view_proj.T.astype(np.float32).tobytes()
            for variant in variants:
                if frames and stop is not None and stop():
                    raise RenderStoppedError(f"stopped after {len(frames)} of {len(cameras) * len(variants)} images")
                timer = shared if not frames else StageTimer()
                t_view = time.perf_counter()
                self._geometry_pass(scene, camera, depth_vp, targets, w, h, timer, variant)
                oracle = self._oracle_texture(visibility, gbuf, lp.n, w, h) if visibility is not None else None
                # Sheer cloth: the background goes in under the layers seen through it (_sheer_layers).
                contact_radius = self._lighting_pass(inputs, camera, view_proj, vp_bytes, timer, oracle, variant,
                                                     background=not scene.sheer)
                if oracle is not None:
                    oracle.release()
                if targets.samples > 1:
                    self._edges_pass(inputs, targets, view_proj, depth_vp, camera, timer, background=not scene.sheer)
                # The passes are the nearest surfaces' (read before the layers behind sheer cloth).
                aovs = self._read_aovs(settings.aovs, gbuf, camera, timer) if settings.aovs else {}
                if scene.sheer:
                    self._sheer_layers(inputs, targets, camera, view_proj, vp_bytes, depth_vp, timer, variant)
                image = self._readback_image(targets.output_fbo, w, h, timer)
                timings: FrameTimings = {**timer.as_dict(), **report[0]}   # its stages, then the frame's counts
                timings["frame_wall_ms"] = (time.perf_counter() - t_view) * 1e3 + (shared_ms if not frames else 0.0)
                info = {**report[1], "camera": {"eye": list(camera.eye), "target": list(camera.target),
                                                "fov_y_deg": camera.fov_y_deg},
                        # The contact search's distance in world units (0: none this frame).
                        "contact_radius": contact_radius}
                frames.append(Frame(image, timings, info, aovs))
        return frames

    def _frame_report(self, scene: Scene, pems: PEMSet, settings: FrameSettings, lp: LightPlan, arrays: dict,
                      uploaded: bool, views: int) -> tuple[dict, dict]:
        """What every view of a frame reports alike: its counts (FrameTimings beyond the stages) and
        its settings (Frame.settings beyond the camera and the contact search), made once a frame."""
        plan, layers, n, n_shadowed, texels = lp.plan, lp.layers, lp.n, lp.n_shadowed, lp.texels
        timings = {}
        timings["n_lights"] = n
        timings["shadowed_lights"] = n_shadowed
        timings["shadow_layers"] = plan.n_layers if n_shadowed else 0
        timings["sharp_layers"] = len(plan.sharp_lights) if n_shadowed else 0
        # The median main-map texel the casters' fit gave, in world units.
        main_texels = texels[(layers >= 0) & ~plan.sharp, 0]
        timings["shadow_texel"] = float(np.median(main_texels)) if len(main_texels) else None
        timings["n_triangles"] = scene.n_triangles
        # Triangles the shadow pass drew: the small lights' maps at full detail, the others' at caster_detail.
        # The proxy's count only where one was drawn (counting makes it: seconds for a large mesh).
        n_main = len(plan.main_lights)
        full = sum(sm.shadow_triangles(1.0) for sm in scene.meshes if sm.caster)
        coarse = sum(sm.shadow_triangles(settings.caster_detail) for sm in scene.meshes if sm.caster) if n_main else 0
        timings["shadow_triangles"] = len(plan.sharp_lights) * full + n_main * coarse
        timings["device"] = self.gl.renderer_name
        timings["lighting_pass"] = self.lighting_pass
        timings["normals"] = self.normals if uploaded else None
        timings["views"] = views
        info = {"frame": settings.as_dict(), "pems": pems.summary(),
                "shadow_bytes": sum(a.nbytes for a in arrays.values()) if n_shadowed else 0,
                "shadowed_lights": n_shadowed}
        return timings, info


    def _shadow_pass(self, scene: Scene, settings: FrameSettings, lp: LightPlan, lights_buf: moderngl.Buffer,
                     timer: StageTimer) -> dict[str, ShadowMaps]:
        """Every shadowed light's moments: the main maps and the small lights' sharp maps."""
        plan, k, blur = lp.plan, settings.small_light_scale, lp.blur
        # The main array (casters at caster_detail; a proxy is made only when one is drawn: a large
        # mesh's takes seconds), then the small lights' array (casters at full detail).
        casters = [sm for sm in scene.meshes if sm.caster]
        groups = max(scene.shadow_groups, 1)   # a scene that casts nothing keeps one (unused) pair
        shadow_maps = self._shadow_maps_for("main", settings.shadow_size, max(len(plan.main_lights), 1), groups)
        arrays = {"main": shadow_maps}
        if len(plan.main_lights):
            # The still group's maps (group 1: the body a garment is worn on) are kept while its
            # meshes, their proxy's detail and every light's projection stay the same (ShadowMaps.render).
            still = (scene.still_key(1), settings.caster_detail, lp.lights.tobytes(), plan.main_lights.tobytes())
            shadow_maps.render([(sm.shadow_vao(settings.caster_detail), sm.group) for sm in casters], lights_buf,
                               self._buffer("shadow_lights_main", plan.main_lights.tobytes()),
                               lp.lights["view_proj"][plan.main_lights], timer, blur=blur,
                               mipmaps=lp.blocker, still_key=still)
        if len(plan.sharp_lights):
            # The sharp maps draw the casters themselves, never a proxy: a proxy's facets show in a
            # sharp shadow (and drawn from one, the interiors' lamps measured no faster on the held-out
            # maps: docs/broad-benchmark.md).
            arrays["sharp"] = self._shadow_maps_for("sharp", settings.shadow_size * k, len(plan.sharp_lights), groups)
            still = (scene.still_key(1), lp.lights.tobytes(), plan.sharp_lights.tobytes())
            arrays["sharp"].render([(sm.shadow_vao(1.0), sm.group) for sm in casters], lights_buf,
                                   self._buffer("shadow_lights_sharp", plan.sharp_lights.tobytes()),
                                   lp.lights["view_proj"][plan.sharp_lights], timer, blur=blur,
                                   still_key=still)
        elif "sharp" in self._shadow_maps:   # no small light now: give its memory back
            self._shadow_maps.pop("sharp").release()
        return arrays

    def _geometry_pass(self, scene: Scene, camera: Camera, vp_bytes: bytes, targets: _Targets, w: int, h: int,
                       timer: StageTimer, variant: int = 0) -> None:
        """The nearest surface's position, normals and material (variant `variant`) per pixel
        (gbuffer.frag); with several samples a pixel, then their depths (_coverage_pass). The meshes
        that hold still (every one outside shadow group 0: the body, a floor) are drawn into targets of
        their own only when they, their material or the camera change, and copied in under the moving
        ones each frame: on a CPU rasterizer a body costs as much as the garment (the vertex stage runs
        on one thread)."""
        gl = self.gl
        with gl.stage(timer, "geometry"):
            g = self._programs["gbuffer_pbr"] if scene.has_pbr else self.gbuffer_prog
            g["u_view_proj"].write(vp_bytes)
            set_uniform(g, "u_camera_pos", tuple(float(x) for x in camera.eye))
            def draw(fbo, meshes, clear=True):
                self._draw_geometry(g, fbo, meshes, w, h, variant, clear)

            # The camera is in vp_bytes (its view and its depth range, fitted to the snapped box).
            self._with_still_meshes(scene, variant, (vp_bytes, g.glo), targets.gbuf_fbo, (targets.gbuf, targets.depth), draw,
                                    lambda: self._still_target_for("geometry", w, h, scene.has_pbr))
            if targets.samples > 1:
                self._coverage_pass(scene, vp_bytes, targets)

    def _with_still_meshes(self, scene: Scene, variant: int, key: tuple, fbo, textures: tuple[list, object], draw,
                           kept_target) -> None:
        """Draw the scene's meshes (material variant `variant`) into `fbo` with `draw(fbo, meshes,
        clear)`: the meshes that hold still from their own targets (`kept_target()`, drawn again only
        when they or `key` change), copied in (`textures`: fbo's colour textures and depth), then the
        moving ones over them."""
        moving = [sm for sm in scene.meshes if sm.group == 0]
        still = [sm for sm in scene.meshes if sm.group != 0]
        if not (moving and still):
            draw(fbo, scene.meshes)
            return
        key = (tuple((sm.serial, sm.version, sm.variants[variant]) for sm in still), *key)
        kept = kept_target()
        if kept.key != key:
            kept.key = None   # a draw that fails half-way leaves nothing to be kept
            draw(kept.fbo, still)
            kept.key = key
        elif kept.shape[3] == 0:
            self.geometry_still_hits += 1   # the geometry pass's (tests)
        colour, depth = textures
        w, h = kept.shape[:2]
        for src, dst in zip(kept.textures, colour):
            rawgl.copy_image(self.gl.gl, src.glo, dst.glo, rawgl.GL_TEXTURE_2D, w, h)
        depth_target = rawgl.GL_TEXTURE_2D_MULTISAMPLE if kept.shape[3] else rawgl.GL_TEXTURE_2D
        rawgl.copy_image(self.gl.gl, kept.depth.glo, depth.glo, depth_target, w, h)
        # Drawn after the still meshes: where a moving and a still surface lie at the same depth (a
        # garment through its body) the still one is in front, where the garment was when it was
        # drawn first.
        draw(fbo, moving, False)

    def _coverage_pass(self, scene: Scene, vp_bytes: bytes, targets: _Targets) -> None:
        """The surfaces' depth at every sample of every pixel (targets.ms_depth), positions alone and
        no shading: what the edges pass (_edges_pass) tells a pixel's coverage and surfaces from."""
        ctx = self.gl.ctx
        w, h, _, samples = targets.key
        prog = self._programs["coverage"]
        prog["u_view_proj"].write(vp_bytes)

        def draw(fbo, meshes, clear=True):
            fbo.use()
            ctx.viewport = (0, 0, w, h)
            if clear:
                fbo.clear(depth=1.0)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
            ctx.depth_func = "<"
            for sm in meshes:
                sm.coverage_vao().render(moderngl.TRIANGLES)
            ctx.disable(moderngl.DEPTH_TEST)

        self._with_still_meshes(scene, 0, (vp_bytes,), targets.ms_fbo, ([], targets.ms_depth), draw,
                                lambda: self._still_target_for("coverage", w, h, False, samples))
        if targets.sample_positions is None:
            targets.ms_fbo.use()
            targets.sample_positions = rawgl.sample_positions(self.gl.gl, samples)

    def _edge_program(self, name: str, samples: int) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """One of the edges pass's programs (edges/classify.frag or edges/resolve.frag), a full-screen
        triangle, compiled once per sample count."""
        if (name, samples) not in self._edge_progs:
            prog = program(self.gl.ctx, "shading/background.vert", f"edges/{name}.frag", {"AA_SAMPLES": samples})
            self._edge_progs[name, samples] = (prog, self.gl.ctx.vertex_array(prog, []))
        return self._edge_progs[name, samples]

    def _edges_pass(self, inputs: _FrameInputs, targets: _Targets, view_proj: np.ndarray, depth_vp: bytes,
                    camera: Camera, timer: StageTimer, background: bool = True) -> None:
        """Each pixel from its samples: the pixels one surface covers whole and those none touches at
        once (edges/classify.frag), then the edge pixels alone (edges/resolve.frag): colour premultiplied
        by coverage and alpha the coverage; then the background blended in under it where the frame has
        one."""
        ctx = self.gl.ctx
        w, h = inputs.settings.width, inputs.settings.height
        with self.gl.stage(timer, "edges"):
            targets.ms_depth.use(location=EdgeTexture.MS_DEPTH)
            targets.depth.use(location=EdgeTexture.DEPTH)
            targets.gbuf[0].use(location=EdgeTexture.POSITION)
            targets.gbuf[2].use(location=EdgeTexture.GEOMETRIC)
            targets.color.use(location=EdgeTexture.COLOUR)
            targets.final_fbo.use()
            ctx.viewport = (0, 0, w, h)
            ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
            ctx.enable(moderngl.DEPTH_TEST)
            classify, vao = self._edge_program("classify", targets.samples)
            set_uniform(classify, "u_plane_depth_tolerance", _plane_depth_tolerance(targets.sample_positions))
            ctx.depth_func = "1"   # every pixel writes its mark
            vao.render(moderngl.TRIANGLES, vertices=3)
            resolve, vao = self._edge_program("resolve", targets.samples)
            inv = np.linalg.inv(np.frombuffer(depth_vp, np.float32).reshape(4, 4).T.astype(np.float64))
            set_uniform(resolve, "u_inv_view_proj", inv.T.astype(np.float32).tobytes())
            if "u_sample_positions" in resolve:   # the compiler keeps the entries the program reads
                n_kept = resolve["u_sample_positions"].array_length
                resolve["u_sample_positions"].write(targets.sample_positions[:n_kept].tobytes())
            set_uniform(resolve, "u_camera_pos", tuple(float(x) for x in camera.eye))
            set_uniform(resolve, "u_footprint_per_distance", 2.0 * float(np.tan(np.radians(camera.fov_y_deg) / 2.0)) / h)
            set_uniform(resolve, "u_plane_tolerance_px", EDGE_PLANE_TOLERANCE_PX)
            ctx.depth_func = ">"   # the edge pixels (marked 0) alone
            vao.render(moderngl.TRIANGLES, vertices=3)
            ctx.depth_func = "<"
            ctx.disable(moderngl.DEPTH_TEST)
            if background and inputs.settings.background is Background.ENVIRONMENT:
                self._background_under(inputs, view_proj)

    def _background_under(self, inputs: _FrameInputs, view_proj: np.ndarray) -> None:
        """The background under what the surfaces cover, into the bound framebuffer: c = c + (1 -
        alpha) * background, alpha kept."""
        ctx = self.gl.ctx
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = (moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE, moderngl.ZERO, moderngl.ONE)
        self._draw_background(inputs, view_proj)
        ctx.blend_func = moderngl.DEFAULT_BLENDING
        ctx.disable(moderngl.BLEND)

    def _sheer_layers(self, inputs: _FrameInputs, targets: _Targets, camera: Camera, view_proj: np.ndarray,
                      vp_bytes: bytes, depth_vp: bytes, timer: StageTimer, variant: int) -> None:
        """What sheer cloth lets through (Material.alpha < 1), by depth peeling (Everitt 2001): the
        image so far holds the nearest surfaces' colour premultiplied by their alpha (lighting.frag);
        each of the next SHEER_LAYERS - 1 layers is the nearest surface behind the last one's depth,
        drawn only where the image is not yet opaque (gbuffer.frag, PEEL), lit as the first was
        (its own sheer pixels premultiplied) and blended under the image (shading/under.frag); then the
        background under all. The meshes that hold still are drawn with the others (no kept layer)."""
        ctx, scene, settings = self.gl.ctx, inputs.scene, inputs.settings
        w, h = settings.width, settings.height
        extra = targets.sheer_targets(ctx)
        out = targets.final if targets.samples > 1 else targets.color
        g = self._peel_program(scene.has_pbr)
        under, under_vao = self._under_program()
        # Opaque meshes that hold still (a body) come from the geometry pass's kept targets, copied in
        # under each layer's cloth (_with_still_meshes): the nearest of them lies behind every layer
        # until it is itself a layer, and then the image is opaque there (peel_mask.frag).
        g0 = self._programs["gbuffer_pbr"] if scene.has_pbr else self.gbuffer_prog
        kept = all(not sm.material.is_sheer for sm in scene.meshes if sm.group != 0)
        mask, mask_vao = self._under_program("peel_mask")

        def draw(fbo, meshes, clear=True):
            still_alone = kept and all(sm.group != 0 for sm in meshes) and len(meshes) < len(scene.meshes)
            self._draw_geometry(g0 if still_alone else g, fbo, meshes, w, h, variant, clear)

        for prog in (g, g0):
            prog["u_view_proj"].write(depth_vp)
            set_uniform(prog, "u_camera_pos", tuple(float(x) for x in camera.eye))
        for _ in range(1, SHEER_LAYERS):
            with self.gl.stage(timer, "sheer_layers"):
                rawgl.copy_image(self.gl.gl, targets.depth.glo, extra.peel_depth.glo, rawgl.GL_TEXTURE_2D, w, h)
                extra.peel_depth.use(location=GeometryTexture.PEEL_DEPTH)
                out.use(location=GeometryTexture.PEEL_OPACITY)
                if kept:
                    self._with_still_meshes(scene, variant, (depth_vp, g0.glo), targets.gbuf_fbo,
                                            (targets.gbuf, targets.depth), draw,
                                            lambda: self._still_target_for("geometry", w, h, scene.has_pbr))
                else:
                    draw(targets.gbuf_fbo, scene.meshes)
                extra.layer_fbo.use()
                ctx.viewport = (0, 0, w, h)
                ctx.enable(moderngl.DEPTH_TEST)
                ctx.depth_func = "1"
                mask_vao.render(moderngl.TRIANGLES, vertices=3)
                ctx.depth_func = "<"
                ctx.disable(moderngl.DEPTH_TEST)
            layer_inputs = replace(inputs, fbo=extra.layer_fbo)
            self._lighting_pass(layer_inputs, camera, view_proj, vp_bytes, timer, None, variant, background=False)
            with self.gl.stage(timer, "sheer_layers"):
                targets.output_fbo.use()
                ctx.viewport = (0, 0, w, h)
                ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = (moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE, moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE)
                extra.layer.use(location=LightingTexture.UNDER_LAYER)
                under_vao.render(moderngl.TRIANGLES, vertices=3)
                ctx.blend_func = moderngl.DEFAULT_BLENDING
                ctx.disable(moderngl.BLEND)
        if settings.background is Background.ENVIRONMENT:
            with self.gl.stage(timer, "sheer_layers"):
                targets.output_fbo.use()
                ctx.viewport = (0, 0, w, h)
                self._background_under(inputs, view_proj)

    def _peel_program(self, pbr: bool) -> moderngl.Program:
        """The geometry pass's program for the layers behind sheer cloth (gbuffer.frag with PEEL)."""
        name = "gbuffer_peel_pbr" if pbr else "gbuffer_peel"
        if name not in self._programs:
            defines = {"PEEL": 1, **({"PBR": 1} if pbr else {})}
            self._programs[name] = program(self.gl.ctx, "shading/surface.vert", "shading/gbuffer.frag", defines)
        return self._programs[name]

    def _under_program(self, name: str = "under") -> tuple[moderngl.Program, moderngl.VertexArray]:
        """A full-screen pass of the layers behind sheer cloth (shading/under.frag, peel_mask.frag)."""
        if name not in self._edge_progs:
            prog = program(self.gl.ctx, "shading/background.vert", f"shading/{name}.frag")
            self._edge_progs[name] = (prog, self.gl.ctx.vertex_array(prog, []))
        return self._edge_progs[name]

    def _draw_background(self, inputs: _FrameInputs, view_proj: np.ndarray) -> None:
        """The environment seen along each pixel's view ray (shading/background.frag), into the bound
        framebuffer."""
        background = inputs.background
        (background if background is not None else inputs.pems.env_texture).use(location=LightingTexture.ENVIRONMENT)
        bg_prog, bg_vao = self._background_program(background is not None and background.latlong)
        bg_prog["u_inv_view_proj"].write(np.linalg.inv(view_proj).T.astype(np.float32).tobytes())
        set_uniform(bg_prog, "u_env_from_world", _mat3_bytes(inputs.pems.env_from_world))
        bg_vao.render(moderngl.TRIANGLES, vertices=3)

    def _draw_geometry(self, g: moderngl.Program, fbo, meshes: list, w: int, h: int, variant: int,
                       clear: bool = True) -> None:
        ctx = self.gl.ctx
        fbo.use()
        ctx.viewport = (0, 0, w, h)
        if clear:
            # w = -1 marks a pixel no surface covers (a covered one's are >= 0: specular weight,
            # glossiness, 1, 1), so that the lighting pass's contact search reads positions alone.
            fbo.clear(0.0, 0.0, 0.0, -1.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        ctx.depth_func = "<"
        for sm in meshes:
            set_uniform(g, "u_shadow_group", float(sm.group))
            set_uniform(g, "u_mesh_id", float(sm.index + 1))
            set_uniform(g, "u_convex_surface", sm.convex)
            buffers = sm.variants[variant]
            # A material with a back (Material.back): its front where the camera sees a triangle's
            # front (counter-clockwise as seen), its back elsewhere, each drawn with the other culled.
            sides = [(buffers, None)] if buffers.back is None else [(buffers, "back"), (buffers.back, "front")]
            for side, culled in sides:
                if culled is not None:
                    ctx.enable(moderngl.CULL_FACE)
                    ctx.front_face, ctx.cull_face = "ccw", culled
                for part in side.parts:   # one draw per texture set
                    part.bind(g)
                    part.vao_for(g).render(moderngl.TRIANGLES)
            ctx.disable(moderngl.CULL_FACE)

    def _still_target_for(self, which: str, w: int, h: int, pbr: bool, samples: int = 0) -> _StillTarget:
        """The still meshes' targets of a pass ("geometry" or "coverage") for an image size (made anew,
        empty, when it or the samples change)."""
        t = self._still_targets.get(which)
        if t is None or t.shape != (w, h, pbr, samples):
            if t is not None:
                t.release()
            self._still_targets.pop(which, None)
            t = self._still_targets[which] = _StillTarget(self.gl.ctx, w, h, pbr, samples)
        return t

    def _lighting_pass(self, inputs: _FrameInputs, camera: Camera, view_proj: np.ndarray, vp_bytes: bytes,
                       timer: StageTimer, oracle: moderngl.TextureArray | None = None, variant: int = 0,
                       background: bool = True) -> float:
        """One view's background (`background` False: none, a layer behind sheer cloth or one that
        sheer cloth will blend under), then per covered pixel c = sum_i VIS_i * PEM_i (lighting.frag), into
        inputs.fbo. Binds what the light plan and the shadow pass made and dispatches; plans nothing.
        Returns the contact search's distance in world units (0: none)."""
        gl, ctx = self.gl, self.gl.ctx
        scene, pems, settings, lp, arrays = inputs.scene, inputs.pems, inputs.settings, inputs.lp, inputs.arrays
        lights_buf, fbo, gbuf, discs = inputs.lights_buf, inputs.fbo, inputs.gbuf, inputs.discs
        w, h = settings.width, settings.height
        regions, n, disc_radius, n_shadowed = lp.regions, lp.n, lp.disc_radius, lp.n_shadowed
        shadow_maps = arrays["main"]
        groups = max(scene.shadow_groups, 1)
        with gl.stage(timer, "shading"):
            fbo.use()
            ctx.viewport = (0, 0, w, h)
            fbo.depth_mask = False   # the depth buffer is the geometry pass's: clear the colour only
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            lights_buf.bind_to_storage_buffer(LightingBuffer.LIGHTS)
            if self._lights_block:
                lights_buf.bind_to_uniform_block(LightingBuffer.LIGHTS)
            if discs > 1:
                block = self._sub_lights_block(discs)
                buf = self._buffer("sub_lights_block" if block else "sub_lights", pems.sub_lights_bytes(discs),
                                   block or None)
                if block:
                    buf.bind_to_uniform_block(LightingBuffer.SUB_LIGHTS)
                else:
                    buf.bind_to_storage_buffer(LightingBuffer.SUB_LIGHTS)
            self._gloss_buf.write(pems.gloss_table().tobytes())
            self._gloss_buf.bind_to_storage_buffer(LightingBuffer.GLOSS_LEVELS)
            for unit, t in zip(G_BUFFER_UNITS, gbuf):   # four targets, five with a physically based material
                t.use(location=unit)
            pems.bind(LightingTexture.PEM0, LightingTexture.PEM1, LightingTexture.PEM_NORM)
            shadow_maps.moments.use(location=LightingTexture.MOMENTS)
            arrays.get("sharp", shadow_maps).moments.use(location=LightingTexture.MOMENTS_SHARP)
            if lp.blocker:
                shadow_maps.casters.use(location=LightingTexture.CASTERS)   # the penumbrae's blocker search (PENUMBRA_BLOCKER)
            if background and settings.background is Background.ENVIRONMENT and settings.aa_samples == 1:
                # (With several samples a pixel the background goes in after the edges: _edges_pass.)
                ctx.disable(moderngl.DEPTH_TEST)
                self._draw_background(inputs, view_proj)
            # Lighting pass: a full-screen triangle at the far plane, drawn where the geometry pass's
            # depth is nearer (covered pixels only; the depth buffer is not written).
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = ">"
            contact = settings.contact_shadow_texels > 0 and n_shadowed > 0
            lobes = (settings.lobes, settings.lobes if scene.has_sheen else 0) if scene.has_pbr else None
            catcher = settings.background is Background.SHADOW_CATCHER
            p, vao = self._shade_variant(settings.mode, settings.diffuse, n > REGIONS_PER_TEXTURE, settings.glossy,
                                         contact, discs, lobes, lp.blocker, oracle is not None, catcher,
                                         scene.has_sheets and ("transmission" if scene.transmits else "sheer"))
            if scene.has_sheets:
                p["u_sheets"].write(scene.sheets(variant))
                set_uniform(p, "u_group_alpha", scene.group_alpha())
            if catcher:
                set_uniform(p, "u_catcher_id", float(scene.catcher + 1))
            if oracle is not None:
                oracle.use(location=LightingTexture.ORACLE)
            if lobes is not None:
                table, sheen_offset = self._lobe_table(*lobes)
                table.bind_to_storage_buffer(LightingBuffer.MATERIAL_LOBES)
                set_uniform(p, "u_sheen_offset", sheen_offset)
            contact_radius = 0.0
            if "u_contact_radius" in p:
                contact_radius = lp.contact_radius
                p["u_contact_radius"] = contact_radius
                p["u_contact_thickness"] = CONTACT_THICKNESS * contact_radius
                p["u_view_proj"].write(vp_bytes)
                # Per light, what contact_visibility needs of it alone: its direction in clip space
                # (x, y, w) and its angular radius (at least 0.01 rad: the disc's width across the
                # occluded sectors, half a sector at least in the shader).
                lc = np.einsum("ij,nj->ni", view_proj[:, :3], regions.directions)
                screen = np.stack([lc[:, 0], lc[:, 1], lc[:, 3], np.clip(disc_radius, 0.01, np.pi / 2)], axis=1)
                self._buffer("light_screen", screen.astype(np.float32).tobytes(), MAX_LIGHTS * 16
                             ).bind_to_uniform_block(LightingBuffer.LIGHT_SCREEN)
                p["u_image_size"] = (float(w), float(h))
                p["u_focal_px"] = 0.5 * h / float(np.tan(np.radians(camera.fov_y_deg) / 2.0))
            self._buffer("light_order", lp.order.tobytes(), MAX_LIGHTS * 4).bind_to_uniform_block(LightingBuffer.LIGHT_ORDER)
            if "u_kind_end" in p:   # the compiler keeps the entries up to the last kind this variant loops over
                p["u_kind_end"].write(lp.kind_end[:p["u_kind_end"].array_length].tobytes())
            set_uniform(p, "u_camera_pos", tuple(float(x) for x in camera.eye))
            set_uniform(p, "u_env_from_world", _mat3_bytes(pems.env_from_world))
            set_uniform(p, "u_n_lights", n)
            set_uniform(p, "u_diffuse_level", pems.lookup_level(pems.diffuse_level()))
            set_uniform(p, "u_min_sigma_texels", settings.min_sigma_texels)
            set_uniform(p, "u_two_groups", groups == 2)
            set_uniform(p, "u_group_layers", float(shadow_maps.n_lights))
            set_uniform(p, "u_group_layers_sharp", float(arrays.get("sharp", shadow_maps).n_lights))
            set_uniform(p, "u_normal_offset_texels", settings.normal_offset_texels)
            set_uniform(p, "u_bleed_reduction", settings.bleed_reduction)
            if vao is None:   # the compute pass: every pixel, uncovered ones left as drawn
                ctx.memory_barrier()
                fbo.color_attachments[0].bind_to_image(Image.LIGHTING_OUT, read=False, write=True)
                p.run((w + 7) // 8, (h + 7) // 8)
                ctx.memory_barrier()
            else:
                vao.render(moderngl.TRIANGLES, vertices=3)
            fbo.depth_mask = True
            ctx.depth_func = "<"
            ctx.disable(moderngl.DEPTH_TEST)
        return contact_radius

    def _oracle_texture(self, visibility: VisibilityOracle, gbuf: list[moderngl.Texture], n: int, w: int,
                        h: int) -> moderngl.TextureArray:
        """The oracle's VIS_i per pixel and light as a texture array (`render_views(visibility=)`)."""
        position = np.frombuffer(gbuf[0].read(), np.float32).reshape(h, w, 4)
        geometric = np.frombuffer(gbuf[2].read(), np.float32).reshape(h, w, 4)
        vis = np.asarray(visibility(position[..., :3], geometric[..., :3], position[..., 3] >= 0.0), np.float32)
        if vis.shape != (n, h, w) or not np.isfinite(vis).all():
            raise InvalidInputError(f"the visibility oracle must give finite values of shape {(n, h, w)}, "
                                    f"got {vis.shape}")
        tex = self.gl.ctx.texture_array((w, h, n), 1, np.clip(vis, 0.0, 1.0).tobytes(), dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return tex

    def _lobe_table(self, ggx: int, sheen: int) -> tuple[moderngl.Buffer, int]:
        """The fitted lobes the PBR variant reads (lobes.glsl): the GGX table, then the sheen table,
        and where the sheen table starts (floats); made once per lobe counts."""
        key = f"lobes_{ggx}_{sheen}"
        if key not in self._buffers:
            tables = material_lobes.load()
            parts = [tables.packed("ggx", ggx)] + ([tables.packed("sheen", sheen)] if sheen else [])
            self._buffers[key] = self.gl.ctx.buffer(np.concatenate(parts).tobytes())
            self._sheen_offsets[key] = len(parts[0])
        return self._buffers[key], self._sheen_offsets[key]

    @staticmethod
    def _read_aovs(names: tuple[str, ...], gbuf: list, camera: Camera, timer: StageTimer) -> dict[str, np.ndarray]:
        """The passes beside the image from the geometry pass's targets (renderer/aovs.py)."""
        t0 = time.perf_counter()

        def read(k: int) -> np.ndarray:
            t = gbuf[k]
            return np.frombuffer(t.read(), np.float32).reshape(t.height, t.width, 4)[::-1]

        out = from_gbuffer(names, read, camera.eye)
        timer.wall_ms["aovs"] = (time.perf_counter() - t0) * 1e3
        return out

    def _readback_image(self, fbo, w: int, h: int, timer: StageTimer) -> np.ndarray:
        t0 = time.perf_counter()
        # Into a host array kept with the targets (no 16 MB allocation per frame at 1024x1024), then
        # one copy that turns the rows over (GL rows start at the bottom): the caller owns the image.
        if self._readback is None or self._readback.shape != (h, w, 4):
            self._readback = np.empty((h, w, 4), np.float32)
        fbo.read_into(self._readback, components=4, dtype="f4")
        image = self._readback[::-1].copy()
        timer.wall_ms["readback"] = (time.perf_counter() - t0) * 1e3
        return image

    def release(self) -> None:
        self.gl.check_thread()
        for sm in self._shadow_maps.values():
            sm.release()
        self._shadow_maps = {}
        if self._target is not None:
            self._target.release()
        for t in self._still_targets.values():
            t.release()
        self._target, self._still_targets, self._readback = None, {}, None
        for buf in self._buffers.values():
            buf.release()
        self._gloss_buf.release()
        variants = [obj for progs in (self._shade_progs, self._bg_progs, self._edge_progs) for pair in progs.values()
                    for obj in pair[::-1] if obj is not None]
        for obj in (*variants, *self._programs.values()):
            obj.release()
        if self._owns_gl:
            self.gl.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
