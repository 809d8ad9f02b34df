"""What the routes do, without HTTP: add an environment map or a fabric, make sure a PEM set exists,
register a scene, and find an environment, a fabric or a scene by id (in memory, else restored from the state directory,
which is how several worker processes, or a restarted service, share them)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import logging
import re
import time
from dataclasses import dataclass, field, replace

import anyio
import numpy as np

from renderer.cache import cache_key
from renderer.envmap import environment_from_array
from renderer.errors import MaterialError
from renderer.lighting.pem_plan import PEMSettings
from renderer.presets import pem_settings as resolved_pem_settings
from renderer.settings import Background
from renderer.u3m import load_u3m

from .codecs import decode_hdr, sniff_hdr_kind
from .errors import ConflictError, InvalidRequestError, NotFoundError, PayloadTooLargeError, QueueFullError
from .fabrics import (
    BYTES_PER_PIXEL,
    FabricRecord,
    FabricStore,
    fabric_limits,
    fabric_material,
    in_service_terms,
    unknown_fabric,
)
from .registry import EnvironmentRecord, EnvironmentStore, MeshStore, PemInfo, SceneMeshInfo, SceneRecord, SceneStore
from .schemas import MAX_COLOURWAYS, FabricRef, MaterialSpec, MeshSpec, OutputSpec, QualitySpec, SceneCreate
from .settings import ServiceSettings
from .specs import (
    SHADOW_FLOOR,
    RequestQuality,
    build_material,
    check_frame_cost,
    check_pem_set,
    prepare_scene,
    resolve_quality,
)
from .state import StateDir
from .worker import GLResources, RenderWorker

log = logging.getLogger("service.scenes")


@dataclass
class Services:
    """The long-lived objects of one app (made in the lifespan), passed to the operations."""

    settings: ServiceSettings
    worker: RenderWorker
    environments: EnvironmentStore
    scenes: SceneStore
    meshes: MeshStore
    presets: dict
    measured: dict | None   # the measured table read at start-up (None: none stored)
    state: StateDir | None = None
    fabrics: FabricStore | None = None
    _restoring: dict[str, tuple[asyncio.Lock, int]] = field(default_factory=dict)

    def quality(self, spec: QualitySpec) -> RequestQuality:
        """The quality of an upload's PEM set, judged as a scene's is (`check_pem_set`): an upload makes
        no frame, so no frame's limit applies to it."""
        from .schemas import OutputSpec

        q = resolve_quality(spec, OutputSpec(width=16, height=16), self.presets, self.measured,
                            self.settings, self.device)
        check_pem_set(q, self.settings)
        return q

    @property
    def device(self) -> str | None:
        """The GL renderer the budgets are checked against (None until the GL thread runs)."""
        return self.worker.gl_info.get("renderer")

    @contextlib.asynccontextmanager
    async def _lock(self, key: str):
        """One restoration of `key` at a time; the lock goes when its last user leaves (a lookup of
        an unknown id leaves nothing behind). The event loop is one thread: no lock guards the dict."""
        lock, users = self._restoring.get(key, (None, 0))
        lock = lock or asyncio.Lock()
        self._restoring[key] = (lock, users + 1)
        try:
            async with lock:
                yield
        finally:
            lock, users = self._restoring[key]
            if users <= 1:
                del self._restoring[key]
            else:
                self._restoring[key] = (lock, users - 1)

    @property
    def restorations_pending(self) -> int:
        return len(self._restoring)


# -- environments ----------------------------------------------------------------------------------


async def add_environment(svc: Services, data: bytes, layout: str, repair: bool, name: str | None,
                          face_size: int, env_id: str | None = None) -> tuple[EnvironmentRecord, bool]:
    """Register an uploaded map, decoded once per distinct file (the first cube resampled at `face_size`
    checks layout and texels). Returns (record, cached): cached when the same file or image came before."""
    file_sha = await anyio.to_thread.run_sync(lambda: hashlib.sha256(data).hexdigest())
    env = svc.environments.find_file(file_sha, layout, repair)
    cached = env is not None
    if env is None:
        kind = sniff_hdr_kind(data)
        label = name or f"upload-{file_sha[:8]}.{kind}"
        t0 = time.perf_counter()
        pixels = await anyio.to_thread.run_sync(decode_hdr, data, kind, label, svc.settings.max_env_pixels,
                                                svc.environments.check_room)
        if pixels.shape[0] * pixels.shape[1] > svc.settings.max_env_pixels:
            raise PayloadTooLargeError(
                f"environment map {label!r} has {pixels.shape[1]}x{pixels.shape[0]} pixels, more than the limit "
                f"{svc.settings.max_env_pixels} (GARMENT_RENDER_MAX_ENV_PIXELS)")
        decode_ms = (time.perf_counter() - t0) * 1e3
        pixels.setflags(write=False)
        first = await anyio.to_thread.run_sync(
            lambda: environment_from_array(pixels, layout, face_size, name=label, repair=repair))
        record = EnvironmentRecord(id=env_id or "env_" + first.content_hash[:16], name=label, layout=first.layout,
                                   content_hash=first.content_hash, file_sha256=file_sha,
                                   source_shape=tuple(pixels.shape), texel_report=first.texel_report, repair=repair,
                                   pixels=pixels, decode_ms=decode_ms)
        record.cubes[face_size] = first.cube
        env, created = svc.environments.add(record, layout)
        cached = not created
        if created and svc.state is not None and env_id is None:
            meta = {"kind": kind, "layout": layout, "repair": repair, "name": label, "file_sha256": file_sha}
            await anyio.to_thread.run_sync(svc.state.save_environment, env.id, data, meta)
    return env, cached


async def ensure_pem_set(worker: RenderWorker, env: EnvironmentRecord, face_size: int,
                         pem_settings: PEMSettings) -> PemInfo:
    """The PEM set through the cache on the GL thread (a hit when resident); the first time, remember
    what the service shows of it (lights, build time, regions for the preview)."""
    cube = await anyio.to_thread.run_sync(env.cube, face_size)
    key = cache_key(env.content_hash, face_size, pem_settings)

    def job(gl: GLResources) -> None:
        pems, source = gl.pem_set(env.content_hash, cube, pem_settings)
        env.note_pem_set(key, face_size, pem_settings, pems, source)

    await worker.call(job, what=f"the PEM set of {env.id} at {face_size}^2 x {pem_settings.lights} lights")
    return env.pem_sets[key]


async def find_environment(svc: Services, env_id: str) -> EnvironmentRecord:
    try:
        return svc.environments.get(env_id)
    except NotFoundError:
        if svc.state is None:
            raise
    async with svc._lock(env_id):
        try:
            return svc.environments.get(env_id)
        except NotFoundError:
            pass
        stored = await anyio.to_thread.run_sync(svc.state.load_environment, env_id)
        if stored is None:
            raise NotFoundError(f"unknown environment id {env_id!r}; upload the map with POST /environments "
                                "(ids are listed by GET /environments)")
        data, meta = stored
        face_size = svc.quality(QualitySpec()).face_size
        env, _ = await add_environment(svc, data, meta["layout"], meta["repair"], meta["name"], face_size,
                                       env_id=env_id)
        return env


# -- fabrics (service/fabrics.py: the store, the reader's bounds, the material on a mesh) ---------------

async def add_fabric(svc: Services, data: bytes, name: str | None, store: bool = True) -> tuple[FabricRecord, bool]:
    """Read and keep an uploaded fabric, once per distinct file; written to the state directory where
    there is one (unless `store` is false: a restoration). Returns (record, cached)."""
    file_sha = await anyio.to_thread.run_sync(lambda: hashlib.sha256(data).hexdigest())
    fabric_id = "fab_" + file_sha[:16]
    existing = svc.fabrics.find(fabric_id)
    if existing is not None:
        return existing, True
    svc.fabrics.check_count()   # before any of it is read
    settings = svc.settings
    label = name or f"fabric-{file_sha[:8]}.u3ma"
    with svc.fabrics.reserve(settings.max_fabric_pixels * BYTES_PER_PIXEL) as room:
        limits = fabric_limits(settings, room)
        t0 = time.perf_counter()
        try:
            material = await anyio.to_thread.run_sync(functools.partial(load_u3m, data, name=label, limits=limits))
        except MaterialError as exc:
            raise in_service_terms(exc, settings, limits, room, svc.fabrics) from None
        record = FabricRecord(id=fabric_id, name=name or material.name, label=label, material=material,
                              file_sha256=file_sha, archive_bytes=len(data),
                              decode_ms=(time.perf_counter() - t0) * 1e3)
        rec, created = svc.fabrics.add(record)
    if created and store and svc.state is not None:
        await anyio.to_thread.run_sync(svc.state.save_fabric, rec.id, data, {"name": name})
    return rec, not created


async def find_fabric(svc: Services, fabric_id: str) -> FabricRecord:
    """The fabric in this process, else restored from the state directory (read again from its bytes)."""
    rec = svc.fabrics.find(fabric_id)
    if rec is not None:
        return rec
    if svc.state is None:
        raise unknown_fabric(fabric_id)
    async with svc._lock(fabric_id):
        rec = svc.fabrics.find(fabric_id)
        if rec is not None:
            return rec
        stored = await anyio.to_thread.run_sync(svc.state.load_fabric, fabric_id)
        if stored is None:
            raise unknown_fabric(fabric_id)
        data, meta = stored
        rec, _ = await add_fabric(svc, data, meta.get("name"), store=False)
        return rec


async def scene_fabrics(svc: Services, body: SceneCreate) -> dict[str, FabricRecord]:
    """Every fabric a scene names, by id (NotFoundError for one that neither this process nor the
    state directory has)."""
    return {fabric_id: await find_fabric(svc, fabric_id) for fabric_id in body.fabric_ids()}


def _delete_unused(svc: Services, kind: str, item_id: str, users: list, registry) -> None:
    """Deletes a fabric or an environment (`kind`) that no scene uses, from this process's `registry`
    and the state directory (where it may be alone: a restart's, not loaded yet); 409 while scenes use it."""
    if users:
        raise ConflictError(f"{kind} {item_id} is used by scenes {users}; delete them first")
    state = svc.state
    try:
        registry.remove(item_id)
    except NotFoundError:
        if state is None or getattr(state, f"load_{kind}")(item_id) is None:
            raise
    if state is not None:
        getattr(state, f"delete_{kind}")(item_id)


async def delete_fabric(svc: Services, fabric_id: str) -> None:
    _delete_unused(svc, "fabric", fabric_id, svc.scenes.using_fabric(fabric_id), svc.fabrics)


# -- scenes ----------------------------------------------------------------------------------------


def _to_scene_up(positions: np.ndarray, up: str) -> list:
    """Inverse of z_up_to_y_up for the stored scene body: (x, y, z) Y-up -> (x, -z, y) Z-up (exact)."""
    p = np.asarray(positions, np.float64)
    if up == "z":
        p = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)
    return p.tolist()


async def release_idle_scenes(svc: Services) -> int:
    """Release the scenes idle beyond GARMENT_RENDER_SCENE_IDLE_TIMEOUT_S from this process (their
    stored copy, with a state directory, stays: the next frame restores them). Returns how many."""
    idle_s = svc.settings.scene_idle_timeout_s
    released = 0
    for rec in svc.scenes.idle(idle_s):
        try:
            svc.scenes.pop(rec.id)
        except NotFoundError:
            continue
        rec.released = True
        svc.scenes.note_expired(rec.id, idle_s)
        await svc.worker.call(lambda gl, rec=rec: rec.release_gpu(), what=f"the release of idle scene {rec.id}")
        released += 1
    return released


async def release_scene_here(svc: Services, scene_id: str) -> bool:
    """Release one scene's GPU objects from this process, keeping its stored registration (a Ray
    replica letting a scene go: the next request for it restores it, here or elsewhere). False: it
    was not here."""
    try:
        rec = svc.scenes.pop(scene_id)
    except NotFoundError:
        return False
    rec.released = True
    await svc.worker.call(lambda gl, rec=rec: rec.release_gpu(), what=f"the release of scene {rec.id}")
    return True


# Scale-out (service/ray_serve.py): the ingress names a new scene's id before it is registered, so that
# the registration and every frame of the scene are routed by it to one replica. Honoured only by an
# app that a replica runs (app.state.scene_ids_assigned); the ingress drops the header from a client's.
ASSIGNED_SCENE_ID = "x-assigned-scene-id"
SCENE_ID = re.compile(r"^scn_[0-9a-f]{16}$")


def assigned_scene_id(request) -> str | None:
    """The id the ingress chose for the scene this request registers, or None (the registry chooses)."""
    if not getattr(request.app.state, "scene_ids_assigned", False):
        return None
    value = request.headers.get(ASSIGNED_SCENE_ID)
    if value is not None and not SCENE_ID.match(value):
        raise InvalidRequestError(f"{ASSIGNED_SCENE_ID} {value!r} is not a scene id (scn_ and 16 hex digits)")
    return value


async def create_scene(svc: Services, body: SceneCreate, scene_id: str | None = None,
                       new_id: str | None = None) -> SceneRecord:
    """Register `body` under a new id (`new_id`, else the registry's), stored where there is a state
    directory; or restore the stored scene `scene_id` (not stored again)."""
    if len(svc.scenes) >= svc.scenes.max_scenes:
        await release_idle_scenes(svc)
    svc.scenes.check_room()
    env = await find_environment(svc, body.environment_id)
    fabrics = await scene_fabrics(svc, body)
    prepared = await anyio.to_thread.run_sync(prepare_scene, body, svc.presets, svc.measured, svc.meshes,
                                              svc.settings, svc.device, fabrics)
    q = prepared.quality
    pem = q.pem
    cube = await anyio.to_thread.run_sync(env.cube, q.face_size)
    if q.frame.background is Background.ENVIRONMENT:   # resampled here, off the GL thread, once per map
        await anyio.to_thread.run_sync(env.background_source)
    key = cache_key(env.content_hash, q.face_size, pem)
    record = SceneRecord(
        id=scene_id or new_id or svc.scenes.new_id(), name=body.name, environment=env, face_size=q.face_size,
        pem_settings=pem, frame_settings=q.frame, camera=prepared.camera, up=body.up,
        meshes=[SceneMeshInfo(role, m.name, m.n_vertices, m.n_faces, m.uvs is not None, m.faces)
                for role, m in zip(prepared.roles, prepared.meshes)],
        quality=q.info, output=body.output.model_dump(), pem_key=key, fabric_ids=list(fabrics),
        material_notes=prepared.material_notes)
    if record.material_notes:
        log.warning("scene %s: what the renderer does not carry of its fabrics: %s", record.id,
                    "; ".join(record.material_notes))
    if svc.state is not None:   # one frame sequence for every process that renders the scene
        record.frame_counter = functools.partial(svc.state.count_frames, record.id)

    def job(gl: GLResources) -> None:
        gl.renderer.check_device(q.frame.aa_samples)   # refused here, not at every frame
        pems, source = gl.pem_set(env.content_hash, cube, pem)
        env.note_pem_set(key, q.face_size, pem, pems, source)
        # The frame's memory on the light plan of this set's regions, before the scene's GPU objects.
        record.frame_cost = prepared.exact_frame_cost(pems.regions, svc.settings)
        variants = [[c] + [None] * (len(prepared.meshes) - 1) for c in prepared.colourways]
        record.gpu = gl.renderer.create_scene(prepared.meshes, prepared.materials, casters=prepared.casters,
                                              proxies=prepared.proxies, variants=variants, catcher=prepared.catcher)
        svc.scenes.add(record)  # here, so a scene made just before a request timeout is still listed (and freed)

    await svc.worker.call(job, what=f"the registration of scene {record.id}")
    if svc.state is not None and scene_id is None:
        # Stored with every mesh inline (an uploaded file may be unknown to the process that restores it).
        inline = {}
        for role, mesh, material in zip(prepared.roles, prepared.meshes, prepared.material_specs):
            if role == SHADOW_FLOOR:
                continue   # made again from the scene's output when it is restored
            spec: MeshSpec = getattr(body, role)
            if spec.mesh_id is not None:
                # A fabric stays named by its id: its bytes are in the state directory (add_fabric).
                shading = {"material": material} if material is not None else {"fabric_id": spec.fabric_id,
                                                                                "uv_scale": spec.uv_scale}
                inline[role] = MeshSpec(name=mesh.name, positions=_to_scene_up(mesh.positions, body.up),
                                        faces=mesh.faces.tolist(),
                                        uvs=None if mesh.uvs is None else mesh.uvs.tolist(), **shading,
                                        **{k: spec.cast_shadows for k in ("cast_shadows",)
                                           if k in spec.model_fields_set})
        stored = body.model_copy(update=inline)
        # Only what the request named: a restored scene resolves its preset again, and a knob it
        # left to the preset must stay the preset's (a full dump would pin every schema default).
        await anyio.to_thread.run_sync(svc.state.save_scene, record.id, stored.model_dump_json(exclude_unset=True))
    return record


async def add_colourway(svc: Services, scene_id: str, spec: MaterialSpec | FabricRef) -> int:
    """One more garment material or fabric for a registered scene (the viewer's fabric choice): judged
    as a registration judges its colourways, made on the GL thread beside the others (they share the
    shadow maps), kept in the state directory with the scene. Returns its index (the views route's
    `colourway`). A glossier one than the scene's materials deepens its PEM set, made here. One add
    at a time per scene: the bound, the PEM settings and the stored scene are read and written whole."""
    rec = await find_scene(svc, scene_id)
    async with svc._lock(f"colourway of {scene_id}"):
        return await _add_colourway(svc, rec, scene_id, spec)


async def _add_colourway(svc: Services, rec: SceneRecord, scene_id: str, spec: MaterialSpec | FabricRef) -> int:
    scene = rec.gpu
    if scene is None:
        raise NotFoundError(f"scene {scene_id} was deleted")
    if scene.n_variants - 1 >= MAX_COLOURWAYS:
        raise ConflictError(f"scene {scene_id} has {MAX_COLOURWAYS} colourways, the most a scene holds: register "
                            "another scene for more")
    role = f"colourway {scene.n_variants}"
    garment = scene.meshes[0].mesh
    notes: list[str] = []
    if isinstance(spec, FabricRef):
        fabric = await find_fabric(svc, spec.fabric_id)
        material, notes = await anyio.to_thread.run_sync(
            fabric_material, {fabric.id: fabric}, fabric.id, spec.uv_scale, garment, role)
    else:
        material = await anyio.to_thread.run_sync(build_material, spec, garment, role)
    if material.is_pbr and not scene.has_pbr:
        raise InvalidRequestError(f"{role}: a physically based material (every fabric is) needs a scene registered "
                                  "with one, and this scene's materials are all Phong: register the scene with it "
                                  "among its colourways")
    # The scene's PEM set keeps the levels its glossiest lookup reads: a glossier colourway needs finer ones.
    pem = rec.pem_settings
    needed = pem.for_materials(rec.face_size, [material]).base_level
    if needed < pem.base_level:
        pem = replace(pem, base_level=needed)
    env = rec.environment
    key = cache_key(env.content_hash, rec.face_size, pem)

    def job(gl: GLResources) -> int:
        if rec.released or rec.gpu is None:
            raise NotFoundError(f"scene {scene_id} was deleted while its colourway waited")
        if pem != rec.pem_settings:
            pems, source = gl.pem_set(env.content_hash, env.cubes[rec.face_size], pem)
            env.note_pem_set(key, rec.face_size, pem, pems, source)
        index = rec.gpu.add_variant([material] + [None] * (len(rec.gpu.meshes) - 1))   # MeshError: 422
        rec.pem_settings, rec.pem_key = pem, key
        return index

    if pem != rec.pem_settings:   # the finer levels' calibration, off the GL thread (as a registration's)
        await anyio.to_thread.run_sync(env.cube, rec.face_size)
    index = await svc.worker.call(job, what=f"a colourway of scene {scene_id}")
    if isinstance(spec, FabricRef) and spec.fabric_id not in rec.fabric_ids:
        rec.fabric_ids.append(spec.fabric_id)
    rec.material_notes.extend(notes)
    if svc.state is not None:   # a restored scene has it too (create_scene reads the stored body)
        text = await anyio.to_thread.run_sync(svc.state.load_scene, scene_id)
        if text is not None:
            stored = SceneCreate.model_validate_json(text)
            stored = stored.model_copy(update={"colourways": [*stored.colourways, spec]})
            await anyio.to_thread.run_sync(svc.state.save_scene, scene_id, stored.model_dump_json(exclude_unset=True))
    return index


async def find_scene(svc: Services, scene_id: str) -> SceneRecord:
    try:
        return svc.scenes.get(scene_id)
    except NotFoundError:
        if svc.state is None:
            raise
    async with svc._lock(scene_id):
        try:
            return svc.scenes.get(scene_id)
        except NotFoundError:
            pass
        text = await anyio.to_thread.run_sync(svc.state.load_scene, scene_id)
        if text is None:
            raise NotFoundError(f"unknown scene id {scene_id!r}; register the scene with POST /scenes")
        return await create_scene(svc, SceneCreate.model_validate_json(text), scene_id=scene_id)


async def delete_environment(svc: Services, env_id: str) -> None:
    _delete_unused(svc, "environment", env_id, list(svc.scenes.using_environment(env_id)), svc.environments)


async def delete_scene(svc: Services, scene_id: str) -> None:
    try:
        rec = svc.scenes.pop(scene_id)
    except NotFoundError:
        if svc.state is None or svc.state.load_scene(scene_id) is None:
            raise
        svc.state.delete_scene(scene_id)
        return
    rec.released = True  # frames still queued for it answer 404
    try:
        await svc.worker.call(lambda gl: rec.release_gpu(), what=f"the release of scene {scene_id}")
    except QueueFullError:  # keep it registered: the client retries the delete
        rec.released = False
        svc.scenes.add(rec)
        raise
    if svc.state is not None:
        svc.state.delete_scene(scene_id)


async def preset_views_quality(svc: Services, scene: SceneRecord, preset: str) -> tuple:
    """(the cube, PEM settings, frame settings) of `scene` at another preset's quality, its output kept
    (the viewer's preset switch: frames/views?preset=): judged as a registration is (the frame's
    memory), the cube made here, off the GL thread; the PEM set is the GL thread's cache's."""
    q = await anyio.to_thread.run_sync(resolve_quality, QualitySpec(preset=preset), OutputSpec(**scene.output),
                                       svc.presets, svc.measured, svc.settings, svc.device)
    meshes = scene.gpu.meshes if scene.gpu is not None else []
    materials = [sm.material for sm in meshes]
    check_pem_set(q, svc.settings)
    check_frame_cost(q, [sm.caster for sm in meshes], materials, svc.settings)
    pem = resolved_pem_settings(q.knobs, q.pem.filter, q.pem.levels, materials)
    cube = await anyio.to_thread.run_sync(scene.environment.cube, q.face_size)
    return cube, pem, q.frame
