"""Environment maps: upload (EXR/HDR bytes, layout and quality in the query), list, details with the
lights of each PEM set, a preview of the regions, delete.

An upload is identified by the SHA-256 of its bytes (plus layout and repair): the same file again
costs one hash and a cache lookup. A decoded map is identified by the renderer's content hash
(pixels + layout), so the same image from another file gets the same id. PEM sets are built on the
GL thread through the PEM cache (memory LRU + disk), keyed by content hash, face size and every PEM
setting."""

from __future__ import annotations

from typing import Annotated

import anyio
import numpy as np
from fastapi import APIRouter, Depends, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from renderer import config

from .. import operations
from ..deps import OCTET_STREAM, EnvironmentsDep, ScenesDep, ServicesDep, raw_body, require_token
from ..errors import NotFoundError
from ..operations import add_environment, ensure_pem_set, find_environment
from ..previews import region_preview_png
from ..registry import EnvironmentRecord, PemInfo
from ..schemas import MAX_LEVELS, EnvironmentInfo, FilterName, LayoutName, LightInfo, PemSetInfo, Preset, QualitySpec

# The registry's defaults (renderer/config.py, OPTIONS).
DEFAULT_LAYOUT = LayoutName(config.OPTION["layout"].default)
DEFAULT_FILTER = FilterName(config.OPTION["filter"].default)

router = APIRouter(prefix="/environments", tags=["environments"], dependencies=[Depends(require_token)])

ENV_MEDIA_TYPES = (OCTET_STREAM, "image/x-exr", "image/aces", "application/x-exr", "image/vnd.radiance",
                   "image/x-hdr", "image/x-radiance", "image/vnd.radiance-hdr")

_BINARY_BODY = {"requestBody": {"required": True, "content": {
    t: {"schema": {"type": "string", "format": "binary"}} for t in (OCTET_STREAM, "image/x-exr", "image/vnd.radiance")}}}


def _enum_of(name: str) -> dict:
    """The values a query parameter of the quality registry takes, for the schema (as QualitySpec's)."""
    return {"enum": QualitySpec.model_json_schema()["properties"][name]["anyOf"][0]["enum"]}


def pem_set_info(env: EnvironmentRecord, info: PemInfo, with_lights: bool) -> PemSetInfo:
    s = info.summary
    lights = None
    if with_lights:
        lum = info.energy_rgb @ np.array([0.2126, 0.7152, 0.0722])
        total = max(float(lum.sum()), 1e-30)
        lights = [LightInfo(direction=tuple(float(c) for c in d), energy_rgb=tuple(float(c) for c in e),
                            energy_share=float(y / total), solid_angle_sr=float(sa))
                  for d, e, y, sa in zip(info.directions, info.energy_rgb, lum, info.solid_angle_sr)]
    return PemSetInfo(key=info.key, face_size=info.face_size, n_lights=info.settings.lights,
                      filter=info.settings.filter.value, levels=s["levels"], base_level=s["base_level"],
                      whole_sources=info.settings.whole_sources, lights_from=s.get("lights_from", "median-cut"),
                      lights_from_used=s.get("lights_from_used", "median-cut"), area_lights=s.get("area_lights"),
                      ambient_share=s.get("ambient_share"), source=info.source,
                      build_ms=s["build_ms"], median_cut_ms=s["median_cut_ms"], bytes=s["bytes"], lights=lights,
                      preview_url=f"/environments/{env.id}/preview.png?pem={info.key}")


def environment_info(env: EnvironmentRecord, scene_ids: list[str], with_lights: bool,
                     cached: bool = False) -> EnvironmentInfo:
    h, w = env.source_shape[:2]
    return EnvironmentInfo(
        id=env.id, name=env.name, layout=env.layout.value, width=w, height=h, content_hash=env.content_hash,
        file_sha256=env.file_sha256, repair=env.repair,
        texel_report=env.texel_report.as_dict() if env.texel_report else None, decode_ms=round(env.decode_ms, 2),
        created=env.created, pem_sets=[pem_set_info(env, p, with_lights) for p in list(env.pem_sets.values())],
        scenes=scene_ids, cached=cached)


@router.post("", response_model=EnvironmentInfo, status_code=status.HTTP_201_CREATED, openapi_extra=_BINARY_BODY,
             summary="Upload an EXR/HDR environment map and build its PEM set",
             responses={200: {"description": "the same map was uploaded before: nothing rebuilt"}})
async def upload_environment(
    request: Request, response: Response, svc: ServicesDep,
    layout: LayoutName = DEFAULT_LAYOUT,
    repair: Annotated[bool, Query(description="replace NaN/Inf/negative texels instead of refusing the map")] = False,
    name: Annotated[str | None, Query(max_length=200)] = None,
    preset: Preset | None = None,
    lights: Annotated[int | None, Query(ge=int(config.BY_NAME["lights"].minimum),
                                        le=int(config.BY_NAME["lights"].maximum))] = None,
    face_size: Annotated[int | None, Query(ge=int(config.BY_NAME["face_size"].minimum),
                                           le=int(config.BY_NAME["face_size"].maximum),
                                           json_schema_extra=_enum_of("face_size"))] = None,
    filter: FilterName = DEFAULT_FILTER,
    levels: Annotated[int | None, Query(ge=1, le=MAX_LEVELS)] = None,
) -> EnvironmentInfo:
    """The body is the file's bytes as they are (Content-Type application/octet-stream, image/x-exr or
    image/vnd.radiance). The query's quality knobs choose the PEM set built now (default: the service's
    default preset); scenes may ask for other sets later. Judged by that set's cost alone, as a scene's
    set is (one answer for a face size); an upload makes no frame."""
    data = await raw_body(request, ENV_MEDIA_TYPES, "an environment map")
    try:
        spec = QualitySpec(preset=preset, lights=lights, face_size=face_size, filter=filter, levels=levels)
    except ValidationError as exc:   # the registry's rules (lights from 6, power-of-two faces): a 422 naming them
        raise RequestValidationError(exc.errors()) from None
    quality = svc.quality(spec)
    env, cached = await add_environment(svc, data, layout.value, repair, name, quality.face_size)
    await ensure_pem_set(svc.worker, env, quality.face_size, quality.pem)
    if cached:
        response.status_code = status.HTTP_200_OK
    return environment_info(env, svc.scenes.using_environment(env.id), with_lights=False, cached=cached)


@router.get("", response_model=list[EnvironmentInfo], summary="List the uploaded environment maps")
async def list_environments(envs: EnvironmentsDep, scenes: ScenesDep) -> list[EnvironmentInfo]:
    return [environment_info(e, scenes.using_environment(e.id), with_lights=False) for e in envs.list()]


@router.get("/{env_id}", response_model=EnvironmentInfo,
            summary="Details: PEM sets with their lights (directions, energies), build times, preview links")
async def get_environment(env_id: str, svc: ServicesDep) -> EnvironmentInfo:
    env = await find_environment(svc, env_id)
    return environment_info(env, svc.scenes.using_environment(env.id), with_lights=True)


@router.get("/{env_id}/preview.png", response_class=Response, summary="PNG of the median-cut regions and lights",
            responses={200: {"content": {"image/png": {}}}})
async def environment_preview(env_id: str, svc: ServicesDep,
                              pem: Annotated[str | None, Query(description="PEM set key (default: the first)")] = None,
                              width: Annotated[int, Query(ge=32, le=4096)] = 512) -> Response:
    """Lat-long (top +Y, centre -Z): each region in its own colour, shaded by the map's brightness,
    borders dark, each light a white circle whose area follows its share of the energy."""
    env = await find_environment(svc, env_id)
    if not env.pem_sets:
        raise NotFoundError(f"environment {env_id} has no PEM set yet")
    if pem is None:
        info = next(iter(env.pem_sets.values()))
    elif pem in env.pem_sets:
        info = env.pem_sets[pem]
    else:
        raise NotFoundError(f"environment {env_id} has no PEM set {pem!r}; its sets are {sorted(env.pem_sets)}")
    cube = await anyio.to_thread.run_sync(env.cube, info.face_size)
    png = await anyio.to_thread.run_sync(region_preview_png, cube, info.labels, info.directions, info.energy_rgb,
                                         width)
    return Response(png, media_type="image/png")


@router.delete("/{env_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Forget an environment map (its PEM sets stay in the cache until evicted)")
async def delete_environment(env_id: str, svc: ServicesDep) -> Response:
    await operations.delete_environment(svc, env_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
