"""Frames: new vertex positions in, an image and per-stage timings out.

* `POST /scenes/{id}/frames`: body = raw little-endian float32, `application/octet-stream`, laid out
  as `X-Frame-Layout` (or `?layout=`) says (codecs.py: positions[,normals][,body_positions][,body_normals];
  default: the garment's positions, V x 3). Answer: PNG (default), EXR (`Accept: image/x-exr` or
  `?format=exr`) or JSON (`?format=json`: timings + base64 image), with `Server-Timing`.
  `X-Frame-Index` (any integer) is echoed back; the server's own count is in `X-Frame-Sequence`.
* `POST /scenes/{id}/frames/batch`: F frames back to back (F x the frame's bytes); the GL thread
  renders them in one job while finished frames are encoded in parallel. Answer: JSON (default,
  `{"frames": [{timings_ms, image: {base64}}, ...]}`) or a zip (`?format=zip`: frame_00000.png ...
  + timings.json); `?image=exr` for EXR images in either.
* `POST /scenes/{id}/frames/views?turntable=N` (or `?views=front,back`): one frame's positions, seen
  from N cameras (the scene's turned about its target, or named views) in the scene's colourways, the
  shadow maps drawn once for all. Answer: one contact-sheet PNG (`?format=sheet`, default: a row per
  view, a column per colourway) or a zip (`?format=zip`: view_00_c0.png ... + timings.json).
* `POST /render`: stateless one-shot, the whole scene (SceneCreate JSON, positions inline) in the
  request; nothing stays on the GPU afterwards.
"""

from __future__ import annotations

import asyncio
import io
import json
import threading
import time
import zipfile
from typing import Annotated

import anyio
import numpy as np
from fastapi import APIRouter, Depends, Header, Query, Request, Response

from renderer.cache import cache_key
from renderer.errors import InvalidInputError
from renderer.renderer import Frame
from renderer.shading.tonemap import DEFAULT_CURVE
from renderer.views import MAX_VIEWS, VIEW_NAMES, contact_sheet, label_tiles, named_views, sheet_columns, view_labels
from renderer.views import orbit as orbit_camera
from renderer.views import turntable as turntable_cameras

from ..budgets import batch_cost, views_cost
from ..codecs import (
    FrameArrays,
    check_frame_size,
    decode_frame,
    encode_pixels,
    encode_png,
    frame_exposure_ev,
    frame_nbytes,
    parse_layout,
    png_bytes,
)
from ..deps import OCTET_STREAM, MetricsDep, ServicesDep, SettingsDep, WorkerDep, client_gone, raw_body, require_token
from ..errors import ClientGoneError, InvalidRequestError, PayloadTooLargeError, RenderTimeoutError
from ..operations import find_environment, find_scene, preset_views_quality, scene_fabrics
from ..pipeline import (
    encode_async,
    frame_payload,
    frame_response,
    frame_timings,
    keep_latest,
    negotiate,
    render_job,
    server_timing,
    views_job,
)
from ..registry import LatestFrame
from ..schemas import BatchFormat, EmbeddedImageFormat, ImageFormat, Preset, SceneCreate, ViewsFormat
from ..specs import prepare_scene
from ..worker import GLResources

router = APIRouter(tags=["frames"], dependencies=[Depends(require_token)])

_FRAME_BODY = {"requestBody": {"required": True, "content": {
    OCTET_STREAM: {"schema": {"type": "string", "format": "binary",
                              "description": "V x 3 little-endian float32 per block of X-Frame-Layout"}}}}}
_IMAGE_RESPONSES = {200: {"content": {"image/png": {}, "image/x-exr": {}, "application/json": {}},
                          "description": "the frame; per-stage timings (ms) in Server-Timing"}}

FormatQuery = Annotated[ImageFormat | None, Query(description="png | exr | json (default: from Accept, else png)")]
ExposureQuery = Annotated[float | None, Query(ge=-64, le=64, description="EV; overrides the scene's exposure")]
RotationQuery = Annotated[float | None, Query(ge=-360, le=360, description="degrees the environment turns about "
                                              "the up axis, counter-clockwise seen from above; overrides the "
                                              "scene's output.environment_rotation (nothing is built again)")]
JsonImageQuery = Annotated[EmbeddedImageFormat, Query(description="image format inside JSON answers: png | exr")]
LayoutHeader = Annotated[str | None, Header(alias="X-Frame-Layout", description="blocks of the body")]
LayoutQuery = Annotated[str | None, Query(description="same as X-Frame-Layout")]
FrameIndexHeader = Annotated[int | None, Header(alias="X-Frame-Index", description="echoed back (any integer)")]


def _json_image(image: EmbeddedImageFormat) -> ImageFormat:
    return ImageFormat(image.value)


@router.post("/scenes/{scene_id}/frames", response_class=Response, openapi_extra=_FRAME_BODY,
             responses=_IMAGE_RESPONSES, summary="Render a frame of a registered scene from raw float32 positions")
async def post_frame(
    scene_id: str, request: Request, svc: ServicesDep, worker: WorkerDep, settings: SettingsDep,
    metrics: MetricsDep, format: FormatQuery = None, exposure: ExposureQuery = None,
    image: JsonImageQuery = EmbeddedImageFormat.PNG,
    environment_rotation: RotationQuery = None,
    layout: LayoutQuery = None,
    x_frame_layout: LayoutHeader = None,
    x_frame_index: FrameIndexHeader = None,
) -> Response:
    t_start = time.perf_counter()
    scene = await find_scene(svc, scene_id)
    fmt = negotiate(format, request)
    json_image = _json_image(image)
    arrays = await read_frame(request, x_frame_layout or layout, scene, worker)
    async with client_gone(request) as gone:
        result = await worker.call(render_job(scene, arrays, environment_rotation), what=f"a frame of {scene.id}",
                                   abandoned=gone)
    frame, source = result.value
    worker.rates.note(scene, result.run_ms, 1)
    sequence = scene.count_frames()
    enc = await encode_async(frame, fmt, scene.output, exposure, settings.png_compress_level, json_image)
    worker.rates.note_encoded(scene, len(enc.content), "exr" if enc.media_type == "image/x-exr" else "png")
    timings = frame_timings(frame, arrays.decode_ms, arrays.normals_ms, result.queue_ms, result.run_ms,
                            enc.encode_ms, t_start)
    metrics.observe_frame("frames", fmt.value, timings)
    index = x_frame_index if x_frame_index is not None else sequence - 1
    keep_latest(scene, index, sequence, frame, enc, timings)
    response = frame_response(fmt, scene.id, index, frame, enc, timings, source, scene.quality)
    response.headers["X-Frame-Sequence"] = str(sequence)
    return response


# Frames a batch's GL job renders ahead of the handler that encodes them: one being encoded, one ready.
BATCH_FRAMES_AHEAD = 2



async def read_frame(request: Request, layout: str | None, scene, worker) -> FrameArrays:
    """One frame's vertex positions from the request's body in `layout` (the frame and views routes),
    decoded off the event loop."""
    blocks = parse_layout(layout, scene)
    body = await raw_body(request, (OCTET_STREAM,), "a frame of vertex positions")
    return await anyio.to_thread.run_sync(decode_frame, body, blocks, scene, not worker.normals_on_gpu)

@router.post("/scenes/{scene_id}/frames/batch", response_class=Response, openapi_extra=_FRAME_BODY,
             responses={200: {"content": {"application/json": {}, "application/zip": {}}}},
             summary="Render a sequence of frames (F x the frame's bytes) in one request")
async def post_batch(
    scene_id: str, request: Request, svc: ServicesDep, worker: WorkerDep, settings: SettingsDep,
    metrics: MetricsDep,
    format: Annotated[BatchFormat | None, Query(description="json (default) | zip")] = None,
    image: JsonImageQuery = EmbeddedImageFormat.PNG, exposure: ExposureQuery = None,
    environment_rotation: RotationQuery = None,
    layout: LayoutQuery = None,
    x_frame_layout: LayoutHeader = None,
) -> Response:
    t_start = time.perf_counter()
    scene = await find_scene(svc, scene_id)
    if format is None:
        format = BatchFormat.ZIP if "application/zip" in request.headers.get("accept", "") else BatchFormat.JSON
    json_image = _json_image(image)
    blocks = parse_layout(x_frame_layout or layout, scene)
    body = await raw_body(request, (OCTET_STREAM,), "a batch of frames")
    per_frame = frame_nbytes(blocks, scene)
    if len(body) % per_frame:
        raise InvalidRequestError(
            f"batch body has {len(body)} bytes, not a whole number of frames of {per_frame} bytes (layout "
            f"'{','.join(blocks)}', {scene.mesh('garment').n_vertices} garment vertices, float32): "
            f"{len(body) / per_frame:.3f} frames")
    n_frames = len(body) // per_frame
    if n_frames > settings.max_batch_frames:
        raise PayloadTooLargeError(f"batch of {n_frames} frames exceeds the limit {settings.max_batch_frames} "
                                   "(GARMENT_RENDER_MAX_BATCH_FRAMES); split it")
    cost = batch_cost(scene, n_frames, format.value, json_image.value, BATCH_FRAMES_AHEAD, worker.rates, settings)
    cost.check(settings)
    view = memoryview(body)

    def decode_all() -> list[FrameArrays]:
        out = []
        for i in range(n_frames):
            chunk = view[i * per_frame:(i + 1) * per_frame]
            check_frame_size(len(chunk), blocks, scene)
            try:
                out.append(decode_frame(chunk, blocks, scene, not worker.normals_on_gpu))
            except ValueError as e:  # MeshError / InvalidInputError: say which frame
                raise type(e)(f"batch frame {i}: {e}") from None
        return out

    frames_in = await anyio.to_thread.run_sync(decode_all)

    # One GL job renders every frame, a frame a step (the GL thread serves other jobs between two
    # steps: worker.py); each finished frame is handed to the event loop and encoded in a worker thread
    # while the GL thread renders the next.
    loop = asyncio.get_running_loop()
    ready: asyncio.Queue = asyncio.Queue()
    # The GL thread renders at most BATCH_FRAMES_AHEAD frames ahead of their encoding, so that a batch
    # holds a few images at a time, not all of them (a slow encoder, a slow client).
    credits = threading.Semaphore(BATCH_FRAMES_AHEAD)

    def job(gl: GLResources):
        for i, arrays in enumerate(frames_in):
            if i:
                yield   # between two frames: another job's turn, if one waits
            while not credits.acquire(timeout=0.05):
                yield   # the encoder is behind: the turn goes to another job, if one waits
            t0 = time.perf_counter()
            try:
                out = render_job(scene, arrays, environment_rotation)(gl)
            except BaseException as exc:  # noqa: BLE001 - reported to the request
                loop.call_soon_threadsafe(ready.put_nowait, (i, exc, 0.0))
                return
            loop.call_soon_threadsafe(ready.put_nowait, (i, out, (time.perf_counter() - t0) * 1e3))

    submitted = worker.submit(job, what=f"a batch of {n_frames} frames of {scene.id}")
    results: list[dict] = []
    zip_buf = io.BytesIO()
    zf = zipfile.ZipFile(zip_buf, "w", zipfile.ZIP_STORED) if format is BatchFormat.ZIP else None
    totals: dict[str, float] = {}
    # A client that leaves stops the batch between two frames (the worker checks the job's `stop`), or
    # drops it while queued: no frame nobody receives is rendered, and no sequence number is spent on one.
    try:
        async with client_gone(request) as gone:
            for k in range(n_frames):
                getter = asyncio.ensure_future(ready.get())
                done, _ = await asyncio.wait({getter, gone}, timeout=settings.request_timeout_s,
                                             return_when=asyncio.FIRST_COMPLETED)
                if gone.done() or getter not in done:   # a client gone wins over a frame ready (the GL thread runs ahead)
                    getter.cancel()
                    submitted.future.cancel()
                    if gone.done():
                        worker.stats.jobs_abandoned += 1
                        raise ClientGoneError(f"the client left a batch of {n_frames} frames after {k}; the rest dropped")
                    raise RenderTimeoutError(f"batch frame {k} took longer than {settings.request_timeout_s:g} s")
                i, out, job_ms = getter.result()
                if isinstance(out, BaseException):
                    raise out
                worker.rates.note(scene, job_ms, 1)
                frame, source = out
                queue_ms = submitted.queue_ms if k == 0 else 0.0
                t_frame = time.perf_counter()
                enc = await encode_async(frame, ImageFormat.JSON if zf is None else json_image, scene.output,
                                         exposure, settings.png_compress_level, json_image)
                worker.rates.note_encoded(scene, len(enc.content), "exr" if enc.media_type == "image/x-exr" else "png")
                arrays = frames_in[i]
                timings = frame_timings(frame, arrays.decode_ms, arrays.normals_ms, max(queue_ms, 0.0), job_ms,
                                        enc.encode_ms, t_frame)
                for key, v in timings.items():
                    totals[key] = totals.get(key, 0.0) + v
                metrics.observe_frame("batch", format.value, timings)
                sequence = scene.count_frames()
                keep_latest(scene, i, sequence, frame, enc, timings)
                if zf is not None:
                    ext = "exr" if enc.media_type == "image/x-exr" else "png"
                    zf.writestr(f"frame_{i:05d}.{ext}", enc.content)
                    results.append({"frame_index": i, "sequence": sequence, "exposure_ev": enc.exposure_ev,
                                    "timings_ms": timings})
                else:
                    results.append(frame_payload(scene.id, i, frame, enc, timings, source, scene.quality))
                frames_in[i] = None  # free the decoded arrays as we go
                credits.release()
    finally:
        submitted.stop.set()
    totals["total"] = (time.perf_counter() - t_start) * 1e3
    totals = {k: round(v, 3) for k, v in totals.items()}
    headers = {"Server-Timing": server_timing(totals), "X-Frame-Count": str(n_frames), "Cache-Control": "no-store",
               "X-Request-Estimate": cost.header()}
    if zf is not None:
        zf.writestr("timings.json", json.dumps({"scene_id": scene.id, "frames": results, "timings_ms": totals}))
        zf.close()
        return Response(zip_buf.getvalue(), media_type="application/zip", headers=headers)
    payload = {"scene_id": scene.id, "n_frames": n_frames, "timings_ms": totals, "frames": results}
    return Response(json.dumps(payload), media_type="application/json", headers=headers)


@router.post("/scenes/{scene_id}/frames/views", response_class=Response, openapi_extra=_FRAME_BODY,
             responses={200: {"content": {"image/png": {}, "application/zip": {}}}},
             summary="Render one frame from several cameras and in the scene's colourways, one shadow pass for all")
async def post_views(
    scene_id: str, request: Request, svc: ServicesDep, worker: WorkerDep, settings: SettingsDep,
    metrics: MetricsDep,
    turntable: Annotated[int | None, Query(ge=1, le=MAX_VIEWS, description="N views: the scene's camera turned "
                                           "about its target in equal steps")] = None,
    views: Annotated[str | None, Query(description="named views, comma-separated: " + ", ".join(VIEW_NAMES))] = None,
    orbit: Annotated[str | None, Query(description="AZ,EL: one view, the scene's camera turned AZ degrees about the "
                                       "up axis through its target and raised EL degrees (the viewer's orbit)")] = None,
    colourways: Annotated[bool, Query(description="also every colourway the scene was registered with")] = True,
    colourway: Annotated[int | None, Query(ge=0, description="only this colourway (0: the garment's own "
                                           "material)")] = None,
    preset: Annotated[Preset | None, Query(description="another preset's quality for these views (the viewer's "
                                           "switch); its PEM set made once and cached")] = None,
    format: Annotated[ViewsFormat, Query(description="sheet (one PNG: a row per view, a column per colourway) "
                                         "| zip (view_00_c0.png ... and timings.json)")] = ViewsFormat.SHEET,
    exposure: ExposureQuery = None,
    environment_rotation: RotationQuery = None,
    layout: LayoutQuery = None,
    x_frame_layout: LayoutHeader = None,
    x_frame_index: FrameIndexHeader = None,
) -> Response:
    t_start = time.perf_counter()
    scene = await find_scene(svc, scene_id)
    if sum(x is not None for x in (turntable, views, orbit)) != 1:
        raise InvalidRequestError("give ?turntable=N, ?views=front,back,... or ?orbit=AZ,EL: one of the three")
    names = [v.strip() for v in views.split(",") if v.strip()] if views is not None else None
    try:
        if orbit is not None:
            angles = [float(x) for x in orbit.split(",")]
            if len(angles) != 2:
                raise InvalidInputError(f"orbit is AZ,EL in degrees, got {orbit!r}")
            cameras = [orbit_camera(scene.camera, *angles)]
            names = [f"orbit {angles[0]:g}, {angles[1]:g} deg"]
        else:
            cameras = turntable_cameras(scene.camera, turntable) if names is None else named_views(scene.camera, names)
    except ValueError as e:   # InvalidInputError is a ValueError; so is float('x')
        raise InvalidRequestError(f"orbit {orbit!r}: {e}" if orbit is not None else str(e)) from None
    registered = scene.gpu.n_variants if scene.gpu is not None else 1
    if colourway is not None and colourway >= registered:
        raise InvalidRequestError(f"colourway {colourway} is not in the scene: it has {registered} (0 to "
                                  f"{registered - 1})")
    variants = [colourway] if colourway is not None else list(range(registered if colourways else 1))
    n_variants = len(variants)
    if len(cameras) * n_variants > settings.max_views:
        raise PayloadTooLargeError(f"{len(cameras)} views x {n_variants} colourways = {len(cameras) * n_variants} "
                                   f"images exceeds the limit {settings.max_views} (GARMENT_RENDER_MAX_VIEWS)")
    cost = views_cost(scene, len(cameras), n_variants, format is ViewsFormat.SHEET, worker.rates, settings)
    cost.check(settings)
    quality = None
    if preset is not None and preset.value != scene.quality.get("preset"):
        quality = await preset_views_quality(svc, scene, preset.value)
    if (x_frame_layout or layout or "").strip().lower() == "none":
        # No positions: the scene's current pose again (the viewer's orbit and light).
        if await request.body():
            raise InvalidRequestError("layout none renders the scene's current pose again: send no body")
        arrays = None
    else:
        arrays = await read_frame(request, x_frame_layout or layout, scene, worker)
    async with client_gone(request) as gone:
        result = await worker.call(views_job(scene, arrays, cameras, variants, environment_rotation, aovs=False,
                                             quality=quality),
                                   what=f"{len(cameras)} views of {scene.id}", abandoned=gone)
    frames, source = result.value
    worker.rates.note(scene, result.run_ms, len(frames))
    sequence = scene.count_frames()
    # Each image is let go once encoded (encode_all): a request holds its readbacks, not copies of them.
    images: list[np.ndarray | None] = [f.image for f in frames]
    tile_hw = images[0].shape[:2]
    frames = [Frame(None, f.timings, f.settings) for f in frames]

    columns = sheet_columns(len(frames), n_variants)
    opaque = scene.output.get("background", "env") == "env"
    tone = scene.output.get("tone", DEFAULT_CURVE.value)

    def encoded_one_by_one(ev: float, encode):
        for k in range(len(images)):
            image, images[k] = images[k], None
            yield encode(image, ev)

    def encode_all() -> tuple[bytes, float, tuple[int, int] | None]:
        # One exposure for every image (the first view's, when the scene names none): views compare.
        ev = exposure if exposure is not None else scene.output.get("exposure_ev")
        ev = frame_exposure_ev(images[0]) if ev is None else float(ev)
        meta = [{"view": k // n_variants, "colourway": variants[k % n_variants], "camera": f.settings["camera"],
                 "timings_ms": {k2: round(float(v), 3) for k2, v in f.timings["wall_ms"].items()}}
                for k, f in enumerate(frames)]
        if format is ViewsFormat.SHEET:   # 8-bit tiles into an 8-bit sheet: no sheet of floats
            tiles = list(encoded_one_by_one(ev, lambda im, ev: encode_pixels(im, ev, tone, opaque)))
            sheet = contact_sheet(tiles, columns)
            del tiles
            labels = view_labels(len(cameras), names, [f"colourway {k}" if k else "garment" for k in variants])
            pixels = label_tiles(sheet, labels, tile_hw, columns)
            del sheet
            return png_bytes(pixels, settings.png_compress_level), ev, pixels.shape[:2]
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
            pngs = encoded_one_by_one(ev, lambda im, ev: encode_png(im, ev, tone, opaque, settings.png_compress_level)[0])
            for m, png in zip(meta, pngs):
                zf.writestr(f"view_{m['view']:02d}_c{m['colourway']}.png", png)
            zf.writestr("timings.json", json.dumps({"scene_id": scene.id, "exposure_ev": ev, "images": meta}))
        return buf.getvalue(), ev, None

    t_enc = time.perf_counter()
    content, ev, sheet_size = await anyio.to_thread.run_sync(encode_all)
    encode_ms = (time.perf_counter() - t_enc) * 1e3
    timings = frame_timings(frames[0], arrays.decode_ms if arrays else 0.0, arrays.normals_ms if arrays else 0.0,
                            result.queue_ms, result.run_ms, encode_ms, t_start)
    timings["render"] = round(sum(float(f.timings["frame_wall_ms"]) for f in frames), 3)
    metrics.observe_frame("views", format.value, timings)
    index = x_frame_index if x_frame_index is not None else sequence - 1
    media = "image/png" if format is ViewsFormat.SHEET else "application/zip"
    if sheet_size is not None:   # the viewer shows the sheet (its PNG: the views side by side)
        scene.keep_latest(LatestFrame(index, sequence, None, timings, ev, png=content, size=sheet_size))
    headers = {"Server-Timing": server_timing(timings), "X-Frame-Index": str(index), "X-Frame-Sequence": str(sequence),
               "X-Views": str(len(cameras)), "X-Colourways": str(n_variants), "X-PEM-Source": source,
               "X-Request-Estimate": cost.header(),
               "Cache-Control": "no-store"}
    return Response(content, media_type=media, headers=headers)


@router.post("/render", response_class=Response, responses=_IMAGE_RESPONSES,
             summary="Stateless one-shot render: the whole scene, positions inline, in the request")
async def render_once(
    body: SceneCreate, request: Request, settings: SettingsDep, worker: WorkerDep, svc: ServicesDep,
    metrics: MetricsDep, format: FormatQuery = None,
    exposure: ExposureQuery = None, image: JsonImageQuery = EmbeddedImageFormat.PNG,
) -> Response:
    t_start = time.perf_counter()
    fmt = negotiate(format, request)
    json_image = _json_image(image)
    env = await find_environment(svc, body.environment_id)
    fabrics = await scene_fabrics(svc, body)
    t0 = time.perf_counter()
    prepared = await anyio.to_thread.run_sync(prepare_scene, body, svc.presets, svc.measured, svc.meshes,
                                              settings, svc.device, fabrics)
    decode_ms = (time.perf_counter() - t0) * 1e3
    q = prepared.quality
    cube = await anyio.to_thread.run_sync(env.cube, q.face_size)
    pem = q.pem
    key = cache_key(env.content_hash, q.face_size, pem)

    def job(gl: GLResources):
        pems, source = gl.pem_set(env.content_hash, cube, pem)
        env.note_pem_set(key, q.face_size, pem, pems, source)
        prepared.exact_frame_cost(pems.regions, settings)   # the frame's memory on this set's light plan
        scene = gl.renderer.create_scene(prepared.meshes, prepared.materials, casters=prepared.casters,
                                         proxies=prepared.proxies)
        try:
            return gl.renderer.render(scene, pems, q.frame, prepared.camera), source
        finally:
            scene.release()

    async with client_gone(request) as gone:
        result = await worker.call(job, what="a one-shot render", abandoned=gone)
    frame, source = result.value
    enc = await encode_async(frame, fmt, body.output.model_dump(), exposure, settings.png_compress_level, json_image)
    timings = frame_timings(frame, decode_ms, 0.0, result.queue_ms, result.run_ms, enc.encode_ms, t_start)
    metrics.observe_frame("render", fmt.value, timings)
    return frame_response(fmt, None, None, frame, enc, timings, source, q.info)

