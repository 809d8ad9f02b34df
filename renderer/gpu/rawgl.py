"""The few raw OpenGL calls that moderngl does not wrap: cube-map-array textures, 2D textures whose
MIP levels are given (moderngl only generates them), clears of some
layers of a texture array (glClearTexSubImage: the shadow pass's moving casters, shadows/vsm.py), and
copies of whole images (glCopyImageSubData: the geometry pass's still meshes, renderer.py).

moderngl has no cube-map-array type (GL-NOTES). The PEM set is one GL_TEXTURE_CUBE_MAP_ARRAY
(layer = region) so that the shading pass reads every region with one sampler and hardware
trilinear filtering; it is created through GL 4.5 direct-state-access entry points looked up with
eglGetProcAddress on the current context. Samplers are bound with `layout(binding = N)` in GLSL.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ..errors import GLContextError

GL_TEXTURE_CUBE_MAP_ARRAY = 0x9009
GL_TEXTURE_2D_ARRAY = 0x8C1A
GL_RGBA16F = 0x881A
GL_RGBA32F = 0x8814
GL_RGB16F = 0x881B
GL_RGB = 0x1907
GL_RGBA = 0x1908
GL_RG = 0x8227
GL_FLOAT = 0x1406
GL_HALF_FLOAT = 0x140B
GL_WRITE_ONLY = 0x88B9
GL_READ_WRITE = 0x88BA
GL_TEXTURE_MIN_FILTER = 0x2801
GL_TEXTURE_MAG_FILTER = 0x2800
GL_LINEAR = 0x2601
GL_LINEAR_MIPMAP_LINEAR = 0x2703
GL_TEXTURE_MAX_LEVEL = 0x813D
GL_TEXTURE_2D = 0x0DE1
GL_TEXTURE_2D_MULTISAMPLE = 0x9100
GL_TEXTURE_WRAP_S = 0x2802
GL_TEXTURE_WRAP_T = 0x2803
GL_REPEAT = 0x2901
GL_CLAMP_TO_EDGE = 0x812F
GL_RENDERBUFFER = 0x8D41

_u = ctypes.c_uint
_i = ctypes.c_int


class RawGL:
    """Function pointers of the current context for cube-map arrays (names as in the GL spec)."""

    _SIGNATURES = {
        "glCreateTextures": (_u, _i, ctypes.POINTER(_u)),
        "glTextureStorage2D": (_u, _i, _u, _i, _i),
        "glTextureStorage3D": (_u, _i, _u, _i, _i, _i),
        "glTextureSubImage2D": (_u, _i, _i, _i, _i, _i, _u, _u, ctypes.c_void_p),
        "glTextureParameteri": (_u, _u, _i),
        "glBindImageTexture": (_u, _u, _i, ctypes.c_ubyte, _i, _u, _u),
        "glBindTextureUnit": (_u, _u),
        "glDeleteTextures": (_i, ctypes.POINTER(_u)),
        "glGetTextureImage": (_u, _i, _u, _u, _i, ctypes.c_void_p),
        "glGetTextureSubImage": (_u, _i, _i, _i, _i, _i, _i, _i, _u, _u, _i, ctypes.c_void_p),
        "glTextureSubImage3D": (_u, _i, _i, _i, _i, _i, _i, _i, _u, _u, ctypes.c_void_p),
        "glClearTexSubImage": (_u, _i, _i, _i, _i, _i, _i, _i, _u, _u, ctypes.c_void_p),
        "glCopyImageSubData": (_u, _u, _i, _i, _i, _i, _u, _u, _i, _i, _i, _i, _i, _i, _i),
        "glGetMultisamplefv": (_u, _u, ctypes.POINTER(ctypes.c_float)),
    }

    def __init__(self):
        try:
            egl = ctypes.CDLL("libEGL.so.1")
        except OSError as exc:
            raise GLContextError(f"libEGL.so.1 not found ({exc}); install libegl1 (scripts/setup.sh does)") from exc
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        for name, args in self._SIGNATURES.items():
            ptr = egl.eglGetProcAddress(name.encode())
            if not ptr:
                raise GLContextError(f"the OpenGL driver does not export {name} (GL 4.5 is required)")
            setattr(self, name, ctypes.CFUNCTYPE(None, *args)(ptr))


def clear_layers(gl: RawGL, glo: int, first: int, count: int, size: int, value: tuple[float, float]) -> None:
    """Level 0 of `count` layers of a size^2 RG32F 2D texture array set to `value` (glClearTexSubImage:
    a framebuffer's clear reaches every attached layer)."""
    data = (ctypes.c_float * 2)(*value)
    gl.glClearTexSubImage(glo, 0, 0, 0, first, size, size, count, GL_RG, GL_FLOAT, ctypes.cast(data, ctypes.c_void_p))


GL_SAMPLE_POSITION = 0x8E50


def sample_positions(gl: RawGL, samples: int) -> np.ndarray:
    """Where in its pixel each sample of the bound multisampled framebuffer lies: float32 (samples, 2),
    x right and y up from the pixel's lower left corner, in [0, 1) (the driver's pattern)."""
    out = np.zeros((samples, 2), np.float32)
    for i in range(samples):
        gl.glGetMultisamplefv(GL_SAMPLE_POSITION, i, out[i].ctypes.data_as(ctypes.POINTER(ctypes.c_float)))
    return out


def copy_image(gl: RawGL, src: int, dst: int, target: int, width: int, height: int) -> None:
    """Level 0 of image `src` into `dst` (GL names of one target, GL_TEXTURE_2D, GL_TEXTURE_2D_MULTISAMPLE
    or GL_RENDERBUFFER, and one format and sample count), texel for texel: no framebuffer, no filtering,
    no conversion."""
    gl.glCopyImageSubData(src, target, 0, 0, 0, 0, dst, target, 0, 0, 0, 0, width, height, 1)


class Texture2DLevels:
    """A GL_TEXTURE_2D with immutable storage whose MIP levels are uploaded, not generated: RGB16F,
    trilinear, repeated along s (or clamped) and clamped along t. llvmpipe compiles a blit program
    the first time a process generates a format's MIP chain (about 90 ms, not in Mesa's disk cache).
    Owned by whoever created it; `release()` frees it."""

    def __init__(self, gl: RawGL, levels: list[np.ndarray], repeat_s: bool):
        shapes = [lvl.shape for lvl in levels]
        h, w = shapes[0][:2]
        if any(sh != (max(1, h >> k), max(1, w >> k), 3) for k, sh in enumerate(shapes)):
            raise ValueError(f"MIP levels must halve (rounding down, to 1) from {(h, w, 3)}, got {shapes}")
        self.gl = gl
        name = _u(0)
        gl.glCreateTextures(GL_TEXTURE_2D, 1, ctypes.byref(name))
        self.glo = name.value
        gl.glTextureStorage2D(self.glo, len(levels), GL_RGB16F, w, h)
        for k, lvl in enumerate(levels):
            data = np.ascontiguousarray(lvl, np.float16)
            gl.glTextureSubImage2D(self.glo, k, 0, 0, data.shape[1], data.shape[0], GL_RGB, GL_HALF_FLOAT,
                                   data.ctypes.data)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_MAG_FILTER, GL_LINEAR)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_WRAP_S, GL_REPEAT if repeat_s else GL_CLAMP_TO_EDGE)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE)

    def use(self, location: int) -> None:
        if self.glo == 0:
            raise GLContextError("texture used after release()")
        self.gl.glBindTextureUnit(location, self.glo)

    def release(self) -> None:
        if self.glo:
            name = _u(self.glo)
            self.gl.glDeleteTextures(1, ctypes.byref(name))
            self.glo = 0


class CubeMapArray:
    """A GL_TEXTURE_CUBE_MAP_ARRAY with immutable storage: `layers` cubes of `size`^2 faces, `levels`
    MIP levels, RGBA16F or RGBA32F. Owned by whoever created it; `release()` frees GPU memory."""

    def __init__(self, gl: RawGL, size: int, layers: int, levels: int, internal_format: int = GL_RGBA16F):
        self.gl, self.size, self.layers, self.levels = gl, size, layers, levels
        self.internal_format = internal_format
        name = _u(0)
        gl.glCreateTextures(GL_TEXTURE_CUBE_MAP_ARRAY, 1, ctypes.byref(name))
        self.glo = name.value
        gl.glTextureStorage3D(self.glo, levels, internal_format, size, size, 6 * layers)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_MAG_FILTER, GL_LINEAR)
        gl.glTextureParameteri(self.glo, GL_TEXTURE_MAX_LEVEL, levels - 1)

    @property
    def bytes_per_texel(self) -> int:
        return 8 if self.internal_format == GL_RGBA16F else 16

    @property
    def nbytes(self) -> int:
        total = 0
        for lvl in range(self.levels):
            s = max(1, self.size >> lvl)
            total += 6 * self.layers * s * s * self.bytes_per_texel
        return total

    def bind_image(self, unit: int, level: int, access: int = GL_WRITE_ONLY) -> None:
        self._check()
        self.gl.glBindImageTexture(unit, self.glo, level, 1, 0, access, self.internal_format)

    def bind_sampler(self, unit: int) -> None:
        self._check()
        self.gl.glBindTextureUnit(unit, self.glo)

    def read_level(self, level: int, layers: slice | None = None) -> np.ndarray:
        """Read one MIP level back: float32 (layers, 6, s, s, 4) in the cube.py face/row/col order."""
        self._check()
        s = max(1, self.size >> level)
        first, count = 0, self.layers
        if layers is not None:
            first, stop, _ = layers.indices(self.layers)
            count = stop - first
        out = np.empty((count, 6, s, s, 4), np.float32)
        self.gl.glGetTextureSubImage(self.glo, level, 0, 0, 6 * first, s, s, 6 * count, GL_RGBA, GL_FLOAT,
                                     out.nbytes, out.ctypes.data)
        return out

    def write_level(self, level: int, data: np.ndarray) -> None:
        """Upload one whole MIP level: (layers, 6, s, s, 4), as `read_level` returns it; sent as half
        floats to an RGBA16F texture, as float32 to an RGBA32F one."""
        self._check()
        s = max(1, self.size >> level)
        half = self.internal_format == GL_RGBA16F
        data = np.ascontiguousarray(data, np.float16 if half else np.float32)
        if data.shape != (self.layers, 6, s, s, 4):
            raise ValueError(f"level {level} must have shape {(self.layers, 6, s, s, 4)}, got {data.shape}")
        self.gl.glTextureSubImage3D(self.glo, level, 0, 0, 0, s, s, 6 * self.layers, GL_RGBA,
                                    GL_HALF_FLOAT if half else GL_FLOAT, data.ctypes.data)

    def _check(self) -> None:
        if self.glo == 0:
            raise GLContextError("cube-map array used after release()")

    def release(self) -> None:
        if self.glo:
            name = _u(self.glo)
            self.gl.glDeleteTextures(1, ctypes.byref(name))
            self.glo = 0
