"""Variance shadow maps, one per light, re-rendered every frame (Knuth et al. 2014, sec. 4).

Moments (z, z^2) are 32-bit floats in a 2D texture array, one layer per light (shadow_lights[layer]
is the layer's light), a pair per shadow group (xy: the casters of group 0, zw: group 1; Scene.groups):
a receiver compares against the other group's pair without the bias that keeps a surface from
shadowing itself, so that the body under a garment is shadowed by it however close. The renderer
keeps a second, larger array for small lights (shadows/lights.py plan_layers). All layers are drawn
in batches of instanced draws (instance = layer, gl_Layer from the vertex shader); the nearest
surface of each group is kept by MIN blending. A separable Gaussian blur whose width follows each
region's angular size then softens them. The arrays are allocated once per (size, layer count) and
reused frame after frame. For contact-hardening penumbrae (FrameSettings.penumbra "blocker") the main
array also carries a MIP chain, made anew every frame after the maps are drawn: the lighting pass
averages the moments over each pixel's penumbra from it (shading/vsm.glsl).

Casters that hold still (the body under a simulated garment: shadow group 1) are drawn once: their
layers are copied aside after they are drawn, and while the caller's `still_key` (the still meshes'
versions, the lights' projections) stays the same, a frame starts each layer from that copy instead
of a clear and draws the moving group alone. The images are the same either way (MIN blending is
order-free); the copy costs the main maps' memory once more.
"""

from __future__ import annotations

import moderngl
import numpy as np

from ..errors import InvalidInputError
from ..gpu import rawgl
from ..gpu.context import GLContext, StageTimer
from ..gpu.shaders import compute_shader
from .lights import MAX_BLUR_RADIUS

# Layers per instanced draw: bounds the layered framebuffer (GL_MAX_FRAMEBUFFER_LAYERS >= 2048).
LAYERS_PER_BATCH = 64
# Bytes per texel, layer and shadow group: (z, z^2) as float32 (RG32F for one group, RGBA32F for two).
GROUP_MOMENT_BYTES = 8
# ... of a scene with two groups (the most a map holds).
MOMENT_BYTES = 2 * GROUP_MOMENT_BYTES


class ShadowMaps:
    """GPU state of the shadow pass for a fixed shadow-map size and light count."""

    def __init__(self, gl: GLContext, size: int, n_lights: int, moments_prog: moderngl.Program, groups: int = 2):
        """n_lights: the number of shadow-map layers (lights that have a shadow map); groups: the
        shadow groups that cast (1: RG32F moments, 2: RGBA32F)."""
        """`moments_prog` (shadows/moments.vert + .frag) is the caller's: the casters' vertex arrays use it."""
        gl.check_thread()
        if size < 16 or size > 8192:
            raise InvalidInputError(f"shadow-map size must be in [16, 8192], got {size}")
        if groups not in (1, 2):
            raise InvalidInputError(f"a shadow map holds one or two shadow groups, got {groups}")
        self.gl, self.size, self.n_lights, self.groups = gl, size, n_lights, groups
        ctx = gl.ctx
        comps = 2 * groups
        self.moments = None
        try:
            self._allocate(ctx, size, n_lights, comps)
        except moderngl.Error as exc:
            target = getattr(self, "target", None)
            for t in {id(t): t for t in (target, self.moments) if t is not None}.values():
                t.release()
            mib = size * size * n_lights * comps * 4 / 2**20
            raise InvalidInputError(
                f"{n_lights} shadow maps of {size}^2 ({mib:.0f} MiB of moments in one texture array) are more than "
                f"this GL driver ({gl.renderer_name}) allocates ({exc}): ask for fewer lights, smaller maps or a "
                "smaller small_light_scale") from None
        self.prog = moments_prog
        self.mipmapped = False   # the moments carry a MIP chain (render(mipmaps=True) made one)
        # With it, each texel's caster share per group and its chain (shadows/coverage.comp).
        self.casters: moderngl.TextureArray | None = None
        fmt = {"MOMENT_FORMAT": "rgba32f" if groups == 2 else "rg32f"}
        self.blur = compute_shader(ctx, "shadows/blur.comp", fmt)
        self._format = fmt
        self.coverage: moderngl.ComputeShader | None = None   # compiled by the first frame that asks for mipmaps
        self.copy = compute_shader(ctx, "shadows/copy_layers.comp", fmt)
        # The still group's layers as drawn (before any blur), and the key they were drawn for.
        self.still: moderngl.TextureArray | None = None
        self.still_key = None
        self.still_hits = 0   # frames that started from the copy (tests, the benchmark's report)

    def _allocate(self, ctx, size: int, n_lights: int, comps: int) -> None:
        self.moments = ctx.texture_array((size, size, n_lights), comps, dtype="f4")
        self.moments.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.moments.repeat_x = self.moments.repeat_y = False
        # The blur's ping-pong array, made by a frame that blurs and given back by one that does not
        # (every preset's blur scale is 0: the array would double the maps' memory for nothing).
        self.scratch: moderngl.TextureArray | None = None
        self._fbos = []
        # One framebuffer per batch of layers would need layer offsets that moderngl cannot set;
        # instead each batch renders into a batch-sized array that is then blurred into place.
        self.batch_layers = min(n_lights, LAYERS_PER_BATCH)
        self.target = (self.moments if n_lights <= LAYERS_PER_BATCH
                       else ctx.texture_array((size, size, self.batch_layers), comps, dtype="f4"))
        self.fbo = ctx.framebuffer(color_attachments=[self.target])

    @property
    def nbytes(self) -> int:
        # moments, the blur's scratch once a frame has blurred, and the batch target when the lights
        # need more than one draw
        layers = (self.n_lights + (0 if self.scratch is None else self.batch_layers)
                  + (0 if self.target is self.moments else self.batch_layers)
                  + (0 if self.still is None else self.n_lights))
        # A MIP chain adds a third of the moments' own texels (1/4 + 1/16 + ...).
        chain = sum((self.size >> k) ** 2 for k in range(1, self.size.bit_length())) if self.mipmapped else 0
        moments = (self.size * self.size * layers + chain * self.n_lights) * GROUP_MOMENT_BYTES * self.groups
        # The caster shares (two float16 a texel) and their chain.
        return moments + (0 if self.casters is None else (self.size * self.size + chain) * self.n_lights * 4)

    def render(self, casters: list[tuple[moderngl.VertexArray, int]], lights_buffer: moderngl.Buffer,
               shadow_lights_buffer: moderngl.Buffer, timer: StageTimer | None = None, enabled: bool = True,
               blur: bool = True, mipmaps: bool = False, still_key=None) -> None:
        """Render and blur the moments of every shadowed light (layer k: light shadow_lights[k]).
        `casters`: (vertex array, shadow group) per caster, drawn with `self.prog` into every layer.
        `blur` False: no light has a blur width (the blur passes would leave every layer as drawn).
        `mipmaps`: then make the moments' MIP chain (each layer's own), for the lighting pass's
        penumbrae; a chain an earlier frame made stays allocated but unread (level 0 is read).
        `still_key`: group 1's casters hold still while it stays the same (any comparable value; None:
        draw everything every frame, and give the copy's memory back)."""
        gl, ctx = self.gl, self.gl.ctx
        gl.check_thread()
        lights_buffer.bind_to_storage_buffer(0)
        shadow_lights_buffer.bind_to_storage_buffer(2)
        groups = ((self.size + 7) // 8, (self.size + 7) // 8)
        if not blur and self.scratch is not None:
            # A frame without a blur gives back the array an earlier frame's blur made: the memory a
            # frame reports (nbytes) is what its own settings need.
            self.scratch.release()
            self.scratch = None
        keep = (still_key is not None and enabled and self.groups == 2
                and any(group == 1 for _, group in casters) and any(group != 1 for _, group in casters))
        if not keep and self.still is not None:
            self.still.release()
            self.still, self.still_key = None, None
        hit = keep and self.still is not None and self.still_key == still_key
        if keep and self.still is None:
            self.still = ctx.texture_array((self.size, self.size, self.n_lights), 2 * self.groups, dtype="f4")
        for first in range(0, self.n_lights, self.batch_layers):
            count = min(self.batch_layers, self.n_lights - first)
            with gl.stage(timer, "shadow_maps"):
                ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
                if hit:
                    self._copy_layers(self.still, first, self.target, 0, count)
                else:
                    self.fbo.use()
                    ctx.viewport = (0, 0, self.size, self.size)
                    self.fbo.clear(1.0, 1.0, 1.0, 1.0)   # both groups' pairs at the far plane
                if enabled:
                    self.fbo.use()
                    ctx.viewport = (0, 0, self.size, self.size)
                    ctx.enable(moderngl.BLEND)
                    ctx.blend_equation = moderngl.MIN
                    self.prog["u_first_light"].value = first
                    # The still group first, then its layers set aside; a frame that starts from
                    # them draws the moving group alone.
                    if keep and not hit:
                        self._draw(casters, (1,), count)
                        self._copy_layers(self.target, 0, self.still, first, count)
                        self.fbo.use()
                    self._draw(casters, (0,) if keep else (0, 1), count)
                    ctx.blend_equation = moderngl.FUNC_ADD
                    ctx.disable(moderngl.BLEND)
            if blur:
                with gl.stage(timer, "blur"):
                    self._blur_batch(first, count)
            if self.target is not self.moments:
                # The batch's layers into place: part of making the maps, whether blurred or not.
                with gl.stage(timer, "shadow_maps"):
                    self._copy_layers(self.target, 0, self.moments, first, count)
        if keep:
            self.still_key = still_key
            self.still_hits += int(hit)
        if mipmaps:
            with gl.stage(timer, "blur"):   # the penumbrae's filtering, as the blur is
                if self.casters is None:
                    self.casters = ctx.texture_array((self.size, self.size, self.n_lights), 2, dtype="f2")
                    self.casters.repeat_x = self.casters.repeat_y = False
                    self.coverage = compute_shader(ctx, "shadows/coverage.comp", self._format)
                ctx.memory_barrier()
                self.moments.bind_to_image(1, read=True, write=False)
                self.casters.bind_to_image(2, read=False, write=True)
                self.coverage.run(*groups, self.n_lights)
                ctx.memory_barrier()
                for t in (self.moments, self.casters):   # every layer's chain, box-filtered
                    t.build_mipmaps()
                    t.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                self.mipmapped = True

    def _draw(self, casters, groups: tuple[int, ...], count: int) -> None:
        for vao, group in casters:
            if group in groups:
                self.prog["u_group"].value = group
                vao.render(moderngl.TRIANGLES, instances=count)

    def _copy_layers(self, src, src_first: int, dst, dst_first: int, count: int) -> None:
        if src is self.still or dst is self.still:   # a plain copy: the driver's, no shader
            rawgl.copy_layers(self.gl.gl, src.glo, src_first, dst.glo, dst_first, self.size, count)
            return
        ctx = self.gl.ctx
        ctx.memory_barrier()
        src.bind_to_image(1, read=True, write=False)
        dst.bind_to_image(2, read=False, write=True)
        self.copy["u_src_first"].value = src_first
        self.copy["u_first_layer"].value = dst_first
        self.copy.run((self.size + 7) // 8, (self.size + 7) // 8, count)
        ctx.memory_barrier()

    def _blur_batch(self, first: int, count: int) -> None:
        ctx = self.gl.ctx
        if self.scratch is None:
            self.scratch = ctx.texture_array((self.size, self.size, self.batch_layers), 2 * self.groups, dtype="f4")
        self.blur["u_first_light"].value = first
        self.blur["u_max_radius"].value = MAX_BLUR_RADIUS
        # Three box passes per axis, ping-ponging target <-> scratch: ends in target.
        src, dst = self.target, self.scratch
        for axis in ((1, 0), (0, 1)):
            self.blur["u_axis"].value = axis
            for _ in range(3):
                ctx.memory_barrier()
                src.bind_to_image(1, read=True, write=False)
                dst.bind_to_image(2, read=False, write=True)
                self.blur.run((self.size + 63) // 64, 1, count)
                src, dst = dst, src
        ctx.memory_barrier()

    def read(self) -> np.ndarray:
        """Blurred moments, float32 (n_lights, size, size, 2 x groups): group 0's (z, z^2), then group
        1's; row 0 is the bottom of light space."""
        return np.frombuffer(self.moments.read(), np.float32).reshape(self.n_lights, self.size, self.size,
                                                                       2 * self.groups)

    def release(self) -> None:
        for obj in {id(o): o for o in (self.fbo, self.target, self.moments, self.scratch, self.casters, self.still)
                    if o is not None}.values():
            obj.release()
        self.blur.release()
        if self.coverage is not None:
            self.coverage.release()
        self.copy.release()
