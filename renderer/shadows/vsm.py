"""Variance shadow maps, one per light, re-rendered every frame (Knuth et al. 2014, sec. 4).

Moments (z, z^2) are 32-bit floats (RG32F) in one 2D texture array with a run of layers per shadow
group (Scene.groups): layer k of group g is layer g * n + k, and layer k belongs to light
shadow_lights[k]. A receiver compares against the other group's layer without the bias that keeps a
surface from shadowing itself, so that the body under a garment is shadowed by it however close. The
renderer keeps a second, larger array for small lights (shadows/lights.py plan_layers). Each group is
drawn in one instanced draw into every layer of its run (instance = light, gl_Layer from the vertex
shader); the nearest surface is kept by MIN blending. A separable Gaussian blur whose width follows
each region's angular size then softens them. The arrays are allocated once per (size, layer count)
and reused frame after frame. For contact-hardening penumbrae (FrameSettings.penumbra "blocker") the
main array also carries a MIP chain, made anew every frame after the maps are drawn: the lighting
pass averages the moments over each pixel's penumbra from it (shading/vsm.glsl).

Casters that hold still (the body under a simulated garment: shadow group 1) are drawn once: while
the caller's `still_key` (the still meshes' versions, the lights' projections) stays the same, a
frame clears and draws group 0's run alone and keeps group 1's layers as they are. The images are the
same either way.
"""

from __future__ import annotations

import moderngl
import numpy as np

from ..errors import InvalidInputError
from ..gpu import rawgl
from ..gpu.context import GLContext, StageTimer
from ..gpu.contract import Image, LightingBuffer
from ..gpu.shaders import compute_shader
from .lights import GROUP_MOMENT_BYTES, MAX_BLUR_RADIUS

# Layers one instanced draw reaches: its projections are a uniform block of this many mat4 (16 KiB,
# the least GL_MAX_UNIFORM_BLOCK_SIZE a GL 4.5 driver has; shaders/shadows/moments.vert).
LAYERS_PER_DRAW = 256
MAT4_BYTES = 64
# ... of a scene with two groups (the most a map holds).
MOMENT_BYTES = 2 * GROUP_MOMENT_BYTES


class ShadowMaps:
    """GPU state of the shadow pass for a fixed shadow-map size and light count."""

    def __init__(self, gl: GLContext, size: int, n_lights: int, moments_prog: moderngl.Program, groups: int = 2):
        """n_lights: the number of shadow-map layers per group (lights that have a shadow map); groups:
        the shadow groups that cast (1 or 2: a run of n_lights layers each). `moments_prog`
        (shadows/moments.vert + .frag) is the caller's: the casters' vertex arrays use it."""
        gl.check_thread()
        if size < 16 or size > 8192:
            raise InvalidInputError(f"shadow-map size must be in [16, 8192], got {size}")
        if groups not in (1, 2):
            raise InvalidInputError(f"a shadow map holds one or two shadow groups, got {groups}")
        self.gl, self.size, self.n_lights, self.groups = gl, size, n_lights, groups
        ctx = gl.ctx
        self.moments = self.fbo = None
        try:
            # One layered framebuffer over every layer: GL 4.5 allows at least 2048 (2 x MAX_LIGHTS here).
            self.moments = ctx.texture_array((size, size, groups * n_lights), 2, dtype="f4")
            self.moments.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.moments.repeat_x = self.moments.repeat_y = False
            self.fbo = ctx.framebuffer(color_attachments=[self.moments])
        except moderngl.Error as exc:
            if self.moments is not None:
                self.moments.release()
            mib = size * size * n_lights * groups * GROUP_MOMENT_BYTES / 2**20
            raise InvalidInputError(
                f"{n_lights} shadow maps of {size}^2 ({mib:.0f} MiB of moments in one texture array) are more than "
                f"this GL driver ({gl.renderer_name}) allocates ({exc}): ask for fewer lights, smaller maps or a "
                "smaller small_light_scale") from None
        self.prog = moments_prog
        # The blur's ping-pong array, made by a frame that blurs and given back by one that does not
        # (every preset's blur scale is 0: the array would double the maps' memory for nothing).
        self.scratch: moderngl.TextureArray | None = None
        self.mipmapped = False   # the moments carry a MIP chain (render(mipmaps=True) made one)
        # With it, each texel's caster share per group and its chain (shadows/coverage.comp).
        self.casters: moderngl.TextureArray | None = None
        self.blur: moderngl.ComputeShader | None = None   # compiled by the first frame that blurs
        self.coverage: moderngl.ComputeShader | None = None   # compiled by the first frame that asks for mipmaps
        # The key group 1's layers were drawn for (None: they hold no still casters' maps).
        self.still_key = None
        self.still_hits = 0   # frames that kept group 1's layers (tests, the benchmark's report)
        # Each layer's light projection, in layer order, for the moments' vertex stage: a whole
        # uniform block (GL leaves a shorter range undefined) per draw of at most LAYERS_PER_DRAW
        # layers, each at a multiple of 16 KiB (every driver's uniform-buffer offset alignment divides it).
        draws = -(-max(n_lights, 1) // LAYERS_PER_DRAW)
        self.projections = ctx.buffer(reserve=draws * LAYERS_PER_DRAW * MAT4_BYTES)

    @property
    def nbytes(self) -> int:
        # moments, and the blur's scratch once a frame has blurred
        layers = self.groups * self.n_lights * (1 if self.scratch is None else 2)
        # A MIP chain adds a third of the moments' own texels (1/4 + 1/16 + ...).
        chain = sum((self.size >> k) ** 2 for k in range(1, self.size.bit_length())) if self.mipmapped else 0
        moments = (self.size * self.size * layers + chain * self.groups * self.n_lights) * GROUP_MOMENT_BYTES
        # The caster shares (two float16 a texel) and their chain.
        return moments + (0 if self.casters is None else (self.size * self.size + chain) * self.n_lights * 4)

    def render(self, casters: list[tuple[moderngl.VertexArray, int]], lights_buffer: moderngl.Buffer,
               shadow_lights_buffer: moderngl.Buffer, view_projs: np.ndarray, timer: StageTimer | None = None,
               enabled: bool = True, blur: bool = True, mipmaps: bool = False, still_key=None) -> None:
        """Render and blur the moments of every shadowed light (layer k: light shadow_lights[k]).
        `casters`: (vertex array, shadow group) per caster, drawn with `self.prog` into its group's run.
        `view_projs`: (n_lights, 16) float32, layer k's light projection (its Light.view_proj).
        `blur` False: no light has a blur width (the blur passes would leave every layer as drawn).
        `mipmaps`: then make the moments' MIP chain (each layer's own), for the lighting pass's
        penumbrae; a chain an earlier frame made stays allocated but unread (level 0 is read).
        `still_key`: group 1's casters hold still while it stays the same (any comparable value; None:
        draw everything every frame)."""
        gl, ctx = self.gl, self.gl.ctx
        gl.check_thread()
        n = self.n_lights
        view_projs = np.ascontiguousarray(view_projs, np.float32)
        if view_projs.shape != (n, 16):
            raise ValueError(f"expected {n} layers' projections (n, 16), got {view_projs.shape}")
        self.projections.write(view_projs.tobytes())
        if not blur and self.scratch is not None:
            # A frame without a blur gives back the array an earlier frame's blur made: the memory a
            # frame reports (nbytes) is what its own settings need.
            self.scratch.release()
            self.scratch = None
        keep = (still_key is not None and enabled and self.groups == 2
                and any(group == 1 for _, group in casters) and any(group != 1 for _, group in casters))
        # Kept layers are blurred as they were drawn: by the blur they were drawn with.
        still_key = (still_key, blur and MAX_BLUR_RADIUS) if keep else None
        hit = keep and self.still_key == still_key
        # The runs drawn this frame: group 1's is kept on a hit.
        drawn = (0,) if hit else tuple(range(self.groups))
        with gl.stage(timer, "shadow_maps"):
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            self.fbo.use()
            ctx.viewport = (0, 0, self.size, self.size)
            if hit:   # group 0's run alone back to the far plane
                rawgl.clear_layers(gl.gl, self.moments.glo, 0, n, self.size, (1.0, 1.0))
            else:
                self.fbo.clear(1.0, 1.0, 1.0, 1.0)
            if enabled:
                ctx.enable(moderngl.BLEND)
                ctx.blend_equation = moderngl.MIN
                # The casters' triangles face outwards (shadows/proxy.py light_facing): the far side
                # of a surface never holds a texel's nearest depth.
                ctx.enable(moderngl.CULL_FACE)
                ctx.cull_face = "back"
                for first in range(0, n, LAYERS_PER_DRAW):
                    count = min(LAYERS_PER_DRAW, n - first)
                    self.projections.bind_to_uniform_block(LightingBuffer.LAYER_PROJECTIONS, offset=first * MAT4_BYTES,
                                                           size=LAYERS_PER_DRAW * MAT4_BYTES)
                    for group in drawn:
                        self.prog["u_first_layer"].value = group * n + first
                        for vao, g in casters:
                            if g == group:
                                vao.render(moderngl.TRIANGLES, instances=count)
                ctx.blend_equation = moderngl.FUNC_ADD
                ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
        self.still_key = still_key
        self.still_hits += int(hit)
        if blur:
            with gl.stage(timer, "blur"):   # the runs drawn: group 1's kept layers are blurred already
                lights_buffer.bind_to_storage_buffer(LightingBuffer.LIGHTS)   # each layer's light's width
                shadow_lights_buffer.bind_to_storage_buffer(LightingBuffer.SHADOW_LIGHTS)
                self._blur(len(drawn) * n)
        if mipmaps:
            with gl.stage(timer, "blur"):   # the penumbrae's filtering, as the blur is
                if self.casters is None:
                    self.casters = ctx.texture_array((self.size, self.size, n), 2, dtype="f2")
                    self.casters.repeat_x = self.casters.repeat_y = False
                    self.coverage = compute_shader(ctx, "shadows/coverage.comp")
                ctx.memory_barrier()
                self.moments.bind_to_image(Image.SHADOW_SRC, read=True, write=False)
                self.casters.bind_to_image(Image.SHADOW_DST, read=False, write=True)
                self.coverage["u_groups"].value = self.groups
                self.coverage["u_group_layers"].value = n
                self.coverage.run((self.size + 7) // 8, (self.size + 7) // 8, n)
                ctx.memory_barrier()
                for t in (self.moments, self.casters):   # every layer's chain, box-filtered
                    t.build_mipmaps()
                    t.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                self.mipmapped = True

    def _blur(self, layers: int) -> None:
        """The first `layers` layers blurred in place."""
        ctx = self.gl.ctx
        if self.scratch is None:
            self.scratch = ctx.texture_array((self.size, self.size, self.groups * self.n_lights), 2, dtype="f4")
        if self.blur is None:
            self.blur = compute_shader(ctx, "shadows/blur.comp")
        self.blur["u_group_layers"].value = self.n_lights
        self.blur["u_max_radius"].value = MAX_BLUR_RADIUS
        # Three box passes per axis, ping-ponging moments <-> scratch: ends in moments.
        src, dst = self.moments, self.scratch
        for axis in ((1, 0), (0, 1)):
            self.blur["u_axis"].value = axis
            for _ in range(3):
                ctx.memory_barrier()
                src.bind_to_image(Image.SHADOW_SRC, read=True, write=False)
                dst.bind_to_image(Image.SHADOW_DST, read=False, write=True)
                self.blur.run((self.size + 63) // 64, 1, layers)
                src, dst = dst, src
        ctx.memory_barrier()

    def read(self) -> np.ndarray:
        """Blurred moments, float32 (n_lights, size, size, 2 x groups): group 0's (z, z^2), then group
        1's; row 0 is the bottom of light space."""
        runs = np.frombuffer(self.moments.read(), np.float32).reshape(self.groups, self.n_lights, self.size,
                                                                       self.size, 2)
        return np.concatenate(list(runs), axis=-1)

    def release(self) -> None:
        for obj in (self.fbo, self.moments, self.scratch, self.casters, self.projections, self.blur, self.coverage):
            if obj is not None:
                obj.release()
