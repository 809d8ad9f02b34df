"""Typed errors of the renderer. Each message says what was wrong and what to do about it."""


class RenderError(Exception):
    """Base class of every error the renderer raises on purpose."""


class InvalidInputError(RenderError, ValueError):
    """An input (file, array, parameter) is malformed or out of range."""


class EnvironmentMapError(InvalidInputError):
    """An environment map cannot be read or contains unusable texels."""


class MeshError(InvalidInputError):
    """A mesh or a frame of vertex positions is unusable."""


class GLContextError(RenderError, RuntimeError):
    """No usable OpenGL 4.5 context, or a context used from the wrong thread."""


class ShaderError(RenderError, RuntimeError):
    """A shader failed to compile or link; the message names the file and line."""


class RenderStoppedError(RenderError):
    """A render of several images stopped between two of them because its caller asked it to
    (`Renderer.render_views`' `stop`): the request they were for is over."""


class MaterialError(InvalidInputError):
    """A material (a U3M fabric: its document, its archive or one of its images) cannot be read.
    `file` names the file (a member of an archive as `archive.u3ma:member`), `field` the JSON path of
    the field (`material.front.basecolor.texture.image.path`), `reason` what was wrong; the message
    joins them."""

    def __init__(self, reason: str, *, file: str | None = None, field: str | None = None):
        self.reason, self.file, self.field = reason, file, field
        super().__init__(": ".join(part for part in (file, field, reason) if part))
