"""Scenes: a garment (and optionally a body) registered once (topology, UVs, materials, camera,
environment, quality, image size), then rendered frame after frame with new positions
(routes/frames.py). The GPU side lives on the GL thread; with a state directory a scene is restored
by id in any process (operations.find_scene)."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Depends, Request, Response, status

from renderer.errors import RenderError

from .. import operations
from ..deps import ScenesDep, ServicesDep, require_token
from ..errors import ConflictError, ServiceError
from ..registry import SceneRecord
from ..schemas import FabricRef, MaterialSpec, SceneCreate, SceneInfo, SceneMeshOut
from ..specs import camera_dict
from .environments import pem_set_info

log = logging.getLogger("service.scenes")
router = APIRouter(prefix="/scenes", tags=["scenes"], dependencies=[Depends(require_token)])


def scene_info(rec: SceneRecord) -> SceneInfo:
    pem = rec.environment.pem_sets.get(rec.pem_key)
    return SceneInfo(
        id=rec.id, name=rec.name, environment_id=rec.environment.id, up=rec.up,
        meshes=[SceneMeshOut(role=m.role, name=m.name, n_vertices=m.n_vertices, n_faces=m.n_faces, has_uvs=m.has_uvs,
                             frame_bytes=12 * m.n_vertices) for m in rec.meshes],
        quality=rec.quality, output=rec.output, camera=camera_dict(rec.camera),
        pem_set=pem_set_info(rec.environment, pem, with_lights=False) if pem else None,
        frames_rendered=rec.count_frames(0), created=rec.created,
        frame_memory=rec.frame_cost.as_dict() if rec.frame_cost is not None else None,
        fabrics=rec.fabric_ids, colourways=rec.gpu.n_variants - 1 if rec.gpu is not None else 0,
        material_notes=rec.material_notes)


@router.post("", response_model=SceneInfo, status_code=status.HTTP_201_CREATED,
             summary="Register a scene (JSON: meshes inline or by mesh_id, materials, camera, quality, size)")
async def create_scene(body: SceneCreate, svc: ServicesDep, request: Request) -> SceneInfo:
    """Positions given here (and in every frame) are in the scene's `up` axis; mesh files were rotated
    at upload. Without a camera, one framing the initial meshes from +Z is fixed for the scene's life."""
    return scene_info(await operations.create_scene(svc, body, new_id=operations.assigned_scene_id(request)))


@router.get("", response_model=list[SceneInfo],
            summary="List the scenes: this process's, and with a state directory every stored one (restored here)")
async def list_scenes(scenes: ScenesDep, svc: ServicesDep) -> list[SceneInfo]:
    """With GARMENT_RENDER_STATE_DIR, a scene stored by another process or before a restart is
    restored on the way (as a frame for it would), up to GARMENT_RENDER_MAX_SCENES; one that cannot
    be (its environment was deleted) is left out and logged."""
    if svc.state is not None:
        held = {s.id for s in scenes.list()}
        for scene_id in svc.state.scene_ids():
            if scene_id in held:
                continue
            try:
                await operations.find_scene(svc, scene_id)
            except ConflictError:   # GARMENT_RENDER_MAX_SCENES reached: the rest stay stored
                break
            except (RenderError, ServiceError) as exc:   # NotFoundError among them: its environment is gone
                log.warning("stored scene %s cannot be restored: %s", scene_id, exc)
    return [scene_info(s) for s in scenes.list()]


@router.get("/{scene_id}", response_model=SceneInfo)
async def get_scene(scene_id: str, svc: ServicesDep) -> SceneInfo:
    return scene_info(await operations.find_scene(svc, scene_id))


@router.post("/{scene_id}/colourways", response_model=SceneInfo, status_code=status.HTTP_201_CREATED,
             summary="Add a colourway to a registered scene: a material, or an uploaded fabric ({fabric_id, uv_scale})")
async def add_colourway(scene_id: str, body: MaterialSpec | FabricRef, svc: ServicesDep) -> SceneInfo:
    """The new colourway is the scene's last (`colourways` in the answer: its index for
    POST .../frames/views?colourway=). It keeps the garment's alpha (every colourway shares the shadow
    maps); a physically based one (every fabric is) needs a scene registered with one; a glossier one
    than the scene's materials makes finer levels of its PEM set, here."""
    await operations.add_colourway(svc, scene_id, body)
    return scene_info(await operations.find_scene(svc, scene_id))


@router.delete("/{scene_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Release a scene's GPU resources (and forget it in the state directory)")
async def delete_scene(scene_id: str, svc: ServicesDep) -> Response:
    await operations.delete_scene(svc, scene_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
