"""The viewer: the latest frame of each scene, with its timings, for people watching a simulation.

* `GET /view`: a small page (plain HTML + JS, `service/viewer.html`) that polls `GET /frames/latest`
  and shows each scene's latest image; a token goes in the address's fragment, `/view#token=...`
  (never sent to the server in the URL; the page sends it as a bearer header).
* `GET /frames/latest`: every scene of this process with its latest frame's metadata (or null).
* `GET /scenes/{id}/latest`: one scene's; `GET /scenes/{id}/latest.png`: its image, tone-mapped PNG.

The scene keeps its last frame's linear image in memory (`SceneRecord.latest`); a frame that was
asked for as PNG keeps those bytes, any other is encoded once, on the first request for its image.
"""

from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path

import anyio
from fastapi import APIRouter, Depends
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from renderer.presets import PRESET_NAMES
from renderer.shading.tonemap import DEFAULT_CURVE

from .. import operations
from ..codecs import encode_png
from ..deps import ScenesDep, ServicesDep, SettingsDep, require_token
from ..errors import NotFoundError
from ..registry import LatestFrame, SceneRecord

router = APIRouter(tags=["viewer"], dependencies=[Depends(require_token)])
page_router = APIRouter(tags=["viewer"])

_PAGE = Path(__file__).resolve().parents[1] / "viewer.html"


@lru_cache(maxsize=1)
def _page() -> str:
    return _PAGE.read_text(encoding="utf-8")


def latest_info(rec: SceneRecord) -> dict:
    frame = rec.latest
    info: dict = {"scene_id": rec.id, "name": rec.name, "frames_rendered": rec.count_frames(0), "frame": None,
                  # What the page's controls offer: the colourways to switch between, the map's turn.
                  "colourways": rec.gpu.n_variants if rec.gpu is not None else 1,
                  "environment_rotation": float(rec.output.get("environment_rotation", 0.0)),
                  "preset": rec.quality.get("preset"), "presets": list(PRESET_NAMES)}
    if frame is not None:
        h, w = frame.size
        rate = rec.frame_rate_hz()
        info["frame"] = {
            "frame_index": frame.frame_index, "sequence": frame.sequence, "width": w, "height": h,
            "exposure_ev": frame.exposure_ev, "timings_ms": frame.timings_ms, "received": frame.received,
            "age_s": round(max(0.0, time.time() - frame.received), 3),
            "frame_rate_hz": round(rate, 3) if rate is not None else None,
            "image_url": f"/scenes/{rec.id}/latest.png?sequence={frame.sequence}"}
    return info


@page_router.get("/", include_in_schema=False)
async def root() -> RedirectResponse:
    return RedirectResponse("/view")


@page_router.get("/view", response_class=HTMLResponse, summary="The viewer page (polls /frames/latest)")
async def view() -> HTMLResponse:
    return HTMLResponse(_page(), headers={"Cache-Control": "no-store"})


@router.get("/frames/latest", summary="Every scene with its latest frame's metadata and timings (or null)")
async def all_latest(scenes: ScenesDep) -> list[dict]:
    return [latest_info(rec) for rec in sorted(scenes.list(), key=lambda r: r.created)]


@router.get("/scenes/{scene_id}/latest", summary="A scene's latest frame: metadata and timings")
async def scene_latest(scene_id: str, svc: ServicesDep) -> dict:
    return latest_info(await operations.find_scene(svc, scene_id))


def _png_of(rec: SceneRecord, frame: LatestFrame, compress_level: int) -> bytes:
    if frame.png is None:
        ev = frame.exposure_ev if frame.exposure_ev is not None else rec.output.get("exposure_ev")
        frame.png, _ = encode_png(frame.image, ev, rec.output.get("tone", DEFAULT_CURVE.value),
                                  opaque=rec.output.get("background", "env") == "env", compress_level=compress_level)
    return frame.png


@router.get("/scenes/{scene_id}/latest.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 404: {"description": "no such scene, or no frame yet"}},
            summary="A scene's latest frame as a PNG (tone-mapped like the scene's PNG frames)")
async def scene_latest_png(scene_id: str, svc: ServicesDep, settings: SettingsDep) -> Response:
    rec = await operations.find_scene(svc, scene_id)
    frame = rec.latest
    if frame is None:
        raise NotFoundError(f"scene {scene_id} has no frame yet; post one to /scenes/{scene_id}/frames")
    png = frame.png if frame.png is not None else await anyio.to_thread.run_sync(
        _png_of, rec, frame, settings.png_compress_level)
    return Response(png, media_type="image/png", headers={
        "Cache-Control": "no-store", "X-Frame-Index": str(frame.frame_index),
        "X-Frame-Sequence": str(frame.sequence)})
