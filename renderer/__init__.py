"""garment-render: a garment shaded under an HDR environment map with its self-shadowing (Knuth et al.
2014), frame by frame as its cloth simulation runs.

The public API, the few calls a program needs; `import renderer` loads no GL (moderngl comes in when a
Renderer opens its context):

    import renderer as gr

    quality = gr.quality("balanced")        # a preset, or frame_budget_ms= / error_budget=, with overrides
    env = gr.load_environment("studio.exr", face_size=quality.face_size)
    garment = gr.load_mesh("shirt.obj", up="y", scale=0.01)
    materials = [gr.Material((0.8, 0.2, 0.2), specular=0.5, glossiness=0.8)]   # or gr.load_u3m(...)
    with gr.Renderer() as r:                # one GL context, used from this thread only
        pems = r.pem_set(env, quality.pems(materials=materials))   # kept in the user's cache folder
        scene = r.create_scene([garment], materials)
        frame = r.render(scene, pems, quality.frame(512, 512), positions=[positions])
        frame.image, frame.timings          # (H, W, 4) float32 linear HDR, premultiplied; stage timings

The command line (renderer/cli.py), the service and the simulation's preview are built on the same
calls. Everything else in the package is reachable by its module; these names are the ones kept stable.
"""

from __future__ import annotations

import importlib

# name -> (module, attribute): imported on first use, so that naming the API costs no GL.
_API = {
    "quality": ("renderer.presets", "resolve"),
    "Quality": ("renderer.presets", "Quality"),
    "PRESET_NAMES": ("renderer.presets", "PRESET_NAMES"),
    "FrameSettings": ("renderer.settings", "FrameSettings"),
    "Background": ("renderer.settings", "Background"),
    "PEMSettings": ("renderer.lighting.pem_plan", "PEMSettings"),
    "load_environment": ("renderer.envmap", "load_environment"),
    "environment_from_array": ("renderer.envmap", "environment_from_array"),
    "EnvironmentMap": ("renderer.envmap", "EnvironmentMap"),
    "load_mesh": ("renderer.mesh", "load_mesh"),
    "Mesh": ("renderer.mesh", "Mesh"),
    "Material": ("renderer.shading.material", "Material"),
    "load_u3m": ("renderer.u3m", "load_u3m"),
    "material_from_u3m": ("renderer.u3m", "material_from_u3m"),
    "Camera": ("renderer.camera", "Camera"),
    "default_camera": ("renderer.camera", "default_camera"),
    "frame_cost": ("renderer.costs", "frame_cost"),
    "Renderer": ("renderer.renderer", "Renderer"),
    "Frame": ("renderer.renderer", "Frame"),
    "render_reference": ("renderer.reference", "render_reference"),
    "write_png": ("renderer.shading.tonemap", "write_png"),
    "write_exr": ("renderer.envmap", "write_exr"),
    "RenderError": ("renderer.errors", "RenderError"),
}
__all__ = sorted(_API)


def __getattr__(name: str):
    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'renderer' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value   # once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
