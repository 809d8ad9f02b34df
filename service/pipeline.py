"""The path of a frame through the service, shared by the frame, batch and one-shot endpoints:

    body bytes -> decode + validate + normals (thread) -> queue -> GL thread: PEM set (cache), upload,
    shadow maps, blur, geometry, shading, readback -> tone map + PNG / EXR (thread) -> response + Server-Timing

Stage names in timings, Server-Timing and the Prometheus histogram: decode, normals, queue, the
renderer's own stages (upload, shadow_maps, blur, geometry, shading, readback; light_tables in the first
frame that needs a PEM set's glossy discs or SH coefficients), render (the renderer's frame wall
time), gl_job (the whole job on the GL thread), encode, and total (handler start to answer).
"""

from __future__ import annotations

import base64
import time
from dataclasses import dataclass, replace

import anyio
import numpy as np
from fastapi import Request
from fastapi.responses import JSONResponse, Response

from renderer.aovs import exr_channels
from renderer.renderer import Background, Frame
from renderer.shading.tonemap import DEFAULT_CURVE

from .codecs import FrameArrays, encode_exr, encode_png
from .errors import NotAcceptableError, NotFoundError
from .logs import process_label
from .registry import LatestFrame, SceneRecord
from .schemas import ImageFormat
from .worker import GLResources

MEDIA = {ImageFormat.PNG: "image/png", ImageFormat.EXR: "image/x-exr", ImageFormat.JSON: "application/json"}


def negotiate(fmt: ImageFormat | None, request: Request) -> ImageFormat:
    """`?format=` wins; else the Accept header (image/x-exr, application/json, image/png); PNG by default."""
    if fmt is not None:
        return fmt
    accept = request.headers.get("accept", "")
    if not accept.strip():
        return ImageFormat.PNG
    types = [part.split(";")[0].strip().lower() for part in accept.split(",")]
    for t in types:
        if t in ("image/x-exr", "image/exr", "image/aces"):
            return ImageFormat.EXR
        if t == "application/json":
            return ImageFormat.JSON
        if t in ("image/png", "image/*", "*/*"):
            return ImageFormat.PNG
    raise NotAcceptableError(f"cannot answer with {accept!r}; frames come as image/png, image/x-exr or "
                             "application/json (or choose with ?format=png|exr|json)")


def render_job(scene: SceneRecord, arrays: FrameArrays | None, rotation: float | None = None):
    """The GL-thread part of one frame of a registered scene (`rotation`: its environment's turn in
    degrees, None: the scene's)."""
    views = views_job(scene, arrays, [scene.camera], [0], rotation)

    def job(gl: GLResources) -> tuple[Frame, str]:
        frames, source = views(gl)
        return frames[0], source
    return job


def views_job(scene: SceneRecord, arrays: FrameArrays | None, cameras: list, variants: list[int],
              rotation: float | None = None, aovs: bool = True, quality: tuple | None = None):
    """The GL-thread part of one frame of a registered scene seen from several cameras in several
    colourways (Renderer.render_views: one upload and shadow pass for all); `aovs` False: without the
    scene's passes (a sheet of views has no place for them); `quality`: another preset's (cube, PEM
    settings, frame settings) in place of the scene's (operations.preset_views_quality)."""
    cube, pem_settings, settings = quality or (None, scene.pem_settings, scene.frame_settings)
    if rotation is not None:
        settings = replace(settings, environment_rotation_deg=float(rotation))
    if not aovs and settings.aovs:
        settings = replace(settings, aovs=())

    def job(gl: GLResources) -> tuple[list[Frame], str]:
        if scene.released or scene.gpu is None:
            raise NotFoundError(f"scene {scene.id} was deleted while this frame waited")
        env = scene.environment
        pems, source = gl.pem_set(env.content_hash, env.cubes[scene.face_size] if cube is None else cube,
                                  pem_settings)
        background = None
        if settings.background is Background.ENVIRONMENT:
            background = gl.background(env.content_hash, env.background_source())
        frames = gl.renderer.render_views(scene.gpu, pems, settings, cameras,
                                          positions=arrays.positions if arrays else None,
                                          normals=arrays.normals if arrays else None, background=background,
                                          variants=variants, stop=gl.stop_requested)
        return frames, source
    return job


@dataclass
class Encoded:
    content: bytes
    media_type: str
    exposure_ev: float | None
    encode_ms: float


def encode(frame: Frame, fmt: ImageFormat, output: dict, exposure_ev: float | None, compress_level: int,
           json_image: ImageFormat = ImageFormat.PNG) -> Encoded:
    """Tone map and encode (in a worker thread). JSON mode embeds `json_image` as base64 elsewhere."""
    t0 = time.perf_counter()
    kind = json_image if fmt is ImageFormat.JSON else fmt
    ev = None
    if kind is ImageFormat.EXR:
        content = encode_exr(frame.image, exr_channels(frame.aovs))
    else:
        ev_in = exposure_ev if exposure_ev is not None else output.get("exposure_ev")
        content, ev = encode_png(frame.image, ev_in, output.get("tone", DEFAULT_CURVE.value),
                                 opaque=output.get("background", "env") == "env", compress_level=compress_level)
    return Encoded(content, MEDIA[kind], ev, (time.perf_counter() - t0) * 1e3)


async def encode_async(frame, fmt, output, exposure_ev, compress_level, json_image=ImageFormat.PNG) -> Encoded:
    return await anyio.to_thread.run_sync(encode, frame, fmt, output, exposure_ev, compress_level, json_image)


def frame_timings(frame: Frame, decode_ms: float, normals_ms: float, queue_ms: float, job_ms: float,
                  encode_ms: float, t_start: float) -> dict[str, float]:
    t = {"decode": decode_ms, "normals": normals_ms, "queue": queue_ms}
    t.update(frame.timings["wall_ms"])
    t["render"] = float(frame.timings["frame_wall_ms"])
    t["gl_job"] = job_ms
    t["encode"] = encode_ms
    t["total"] = (time.perf_counter() - t_start) * 1e3
    return {k: round(float(v), 3) for k, v in t.items()}


def keep_latest(scene: SceneRecord, index: int, sequence: int, frame: Frame, enc: Encoded, timings: dict) -> None:
    """Hand the frame to the viewer (no copy; a PNG answer's bytes are kept as they are)."""
    png = enc.content if enc.media_type == "image/png" else None
    scene.keep_latest(LatestFrame(index, sequence, frame.image, timings, enc.exposure_ev, png=png))


def server_timing(timings: dict[str, float]) -> str:
    return ", ".join(f"{k};dur={v:.3f}" for k, v in timings.items())


def render_info(frame: Frame, source: str) -> dict:
    t = frame.timings
    return {"n_lights": t["n_lights"], "shadowed_lights": t["shadowed_lights"], "n_triangles": t["n_triangles"],
            "device": t["device"], "lighting_pass": t["lighting_pass"], "pem_source": source, "gpu_ms": t.get("gpu_ms", {}),
            # The shadow maps' bytes as the renderer's arrays hold them (ShadowMaps.nbytes).
            "shadow_bytes": frame.settings.get("shadow_bytes"),
            "settings": frame.settings.get("frame", {}), "pem_set": frame.settings.get("pems", {})}


def frame_payload(scene_id: str | None, index: int | None, frame: Frame, enc: Encoded, timings: dict,
                  source: str, quality: dict | None = None) -> dict:
    h, w = frame.image.shape[:2]
    return {"scene_id": scene_id, "frame_index": index, "width": w, "height": h, "exposure_ev": enc.exposure_ev,
            "timings_ms": timings, "render": {**render_info(frame, source), "quality": quality},
            "image": {"format": "exr" if enc.media_type == "image/x-exr" else "png", "media_type": enc.media_type,
                      "base64": base64.b64encode(enc.content).decode("ascii")},
            # The passes (output.aovs): little-endian float32, rows from the top.
            "aovs": {name: {"shape": list(a.shape), "dtype": "<f4",
                            "base64": base64.b64encode(np.ascontiguousarray(a, "<f4").tobytes()).decode("ascii")}
                     for name, a in frame.aovs.items()}}


def frame_response(fmt: ImageFormat, scene_id: str | None, index: int | None, frame: Frame, enc: Encoded,
                   timings: dict, source: str, quality: dict | None = None) -> Response:
    """The frame as an image (settings in headers) or as JSON; `quality` is the scene's resolved quality
    (the knobs and where they came from: a preset or a budget), reported with every frame."""
    headers = {"Server-Timing": server_timing(timings), "X-Render-Lights": str(frame.timings["n_lights"]),
               "X-PEM-Source": source, "X-Render-Process": process_label(), "Cache-Control": "no-store"}
    if quality is not None and quality.get("source"):
        headers["X-Quality-Source"] = quality["source"]
    if index is not None:
        headers["X-Frame-Index"] = str(index)
    if enc.exposure_ev is not None:
        headers["X-Exposure-EV"] = f"{enc.exposure_ev:.4f}"
    if fmt is ImageFormat.JSON:
        return JSONResponse(frame_payload(scene_id, index, frame, enc, timings, source, quality), headers=headers)
    return Response(enc.content, media_type=enc.media_type, headers=headers)
