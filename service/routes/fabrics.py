"""U3M fabrics: upload (a `.u3ma` archive's bytes), list, details (every field of every face: a
constant, or a texture with its size in millimetres and pixels), delete. A scene names one by id on a
mesh (`fabric_id`, `uv_scale`) or as a colourway (service/fabrics.py reads, bounds and places them)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response, status

from renderer.u3m import FIELDS, ColorConstant, NormalConstant, ScalarConstant, Texture, Visualisation

from .. import operations as ops
from ..deps import OCTET_STREAM, FabricsDep, ScenesDep, ServicesDep, raw_body, require_token
from ..fabrics import FabricRecord
from ..schemas import FabricFaceOut, FabricFieldOut, FabricInfo, FabricTextureOut

router = APIRouter(prefix="/fabrics", tags=["fabrics"], dependencies=[Depends(require_token)])

FABRIC_MEDIA_TYPES = (OCTET_STREAM, "application/zip", "application/x-zip-compressed")

_BINARY_BODY = {"requestBody": {"required": True, "content": {
    t: {"schema": {"type": "string", "format": "binary"}} for t in FABRIC_MEDIA_TYPES}}}


def _value(constant) -> float | list[float]:
    if isinstance(constant, ScalarConstant):
        return float(constant.value)
    if isinstance(constant, ColorConstant):
        return [float(c) for c in constant.rgb]
    if isinstance(constant, NormalConstant):
        return [float(c) for c in constant.xyz]
    raise TypeError(f"not a U3M constant: {constant!r}")   # pragma: no cover - the reader's types


def _field(name: str, value) -> FabricFieldOut:
    if not isinstance(value, Texture):
        return FabricFieldOut(name=name, kind="constant", value=_value(value))
    w, h = value.size_px
    return FabricFieldOut(name=name, kind="texture", value=_value(value.constant), texture=FabricTextureOut(
        path=value.path, width_mm=value.width_mm, height_mm=value.height_mm, width_px=w, height_px=h,
        rotation_deg=value.rotation_deg, repeat=value.repeat.value))


def _face(face: str, vis: Visualisation) -> FabricFaceOut:
    return FabricFaceOut(face=face, fields=[_field(name, getattr(vis, name)) for name in FIELDS])


def fabric_info(rec: FabricRecord, scene_ids: list[str], cached: bool = False) -> FabricInfo:
    m = rec.material
    faces = [_face(face, getattr(m, face)) for face in ("front", "back", "side") if getattr(m, face) is not None]
    return FabricInfo(id=rec.id, name=rec.name, material_name=m.name, version=m.version, file_sha256=rec.file_sha256,
                      archive_bytes=rec.archive_bytes, bytes=rec.nbytes, decode_ms=round(rec.decode_ms, 2),
                      created=rec.created, faces=faces, thickness_mm=m.thickness_mm, weight_g_m2=m.weight_g_m2,
                      scenes=scene_ids, cached=cached)


@router.post("", response_model=FabricInfo, status_code=status.HTTP_201_CREATED, openapi_extra=_BINARY_BODY,
             summary="Upload a U3M fabric (.u3ma) for scenes to name by id",
             responses={200: {"description": "the same file was uploaded before: nothing read again"}})
async def upload_fabric(request: Request, response: Response, svc: ServicesDep,
                        name: Annotated[str | None, Query(max_length=200)] = None) -> FabricInfo:
    """The body is the `.u3ma` archive's bytes as they are (a `.u3m` document alone can name no image).
    It is read within the service's bounds, judged before any image is decoded: the images' pixels
    (GARMENT_RENDER_MAX_FABRIC_PIXELS) and what is left of the fabrics' memory
    (GARMENT_RENDER_MAX_FABRIC_BYTES: a 409). A bad file is a 422 naming the file and the field."""
    data = await raw_body(request, FABRIC_MEDIA_TYPES, "a U3M fabric")
    rec, cached = await ops.add_fabric(svc, data, name)
    if cached:
        response.status_code = status.HTTP_200_OK
    return fabric_info(rec, svc.scenes.using_fabric(rec.id), cached=cached)


@router.get("", response_model=list[FabricInfo], summary="List the uploaded fabrics")
async def list_fabrics(fabrics: FabricsDep, scenes: ScenesDep) -> list[FabricInfo]:
    return [fabric_info(r, scenes.using_fabric(r.id)) for r in fabrics.list()]


@router.get("/{fabric_id}", response_model=FabricInfo,
            summary="Details: every field of every face, a constant or a texture (size in mm and px)")
async def get_fabric(fabric_id: str, svc: ServicesDep) -> FabricInfo:
    rec = await ops.find_fabric(svc, fabric_id)
    return fabric_info(rec, svc.scenes.using_fabric(rec.id))


@router.delete("/{fabric_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Forget a fabric (409 while a scene uses it)")
async def delete_fabric(fabric_id: str, svc: ServicesDep) -> Response:
    await ops.delete_fabric(svc, fabric_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)

