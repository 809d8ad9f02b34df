"""Operations: liveness and readiness (no token needed: a load balancer's probes), Prometheus metrics
and service statistics as JSON (token needed, like every other resource, when the service has one)."""

from __future__ import annotations

import os

from fastapi import APIRouter, Depends, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST

from ..deps import (
    EnvironmentsDep,
    FabricsDep,
    MeshesDep,
    MetricsDep,
    ScenesDep,
    ServicesDep,
    SettingsDep,
    WorkerDep,
    require_token,
)
from ..logs import process_label

router = APIRouter(tags=["health"])
stats_router = APIRouter(tags=["health"], dependencies=[Depends(require_token)])


@router.get("/health/live", summary="The process answers")
async def live() -> dict:
    return {"status": "ok"}


@router.get("/health/ready", summary="Ready for new work: the GL context is up, its thread runs, the queue has "
            "room and no job has held the thread beyond GARMENT_RENDER_READY_MAX_BUSY_S (else 503)",
            responses={503: {"description": "not ready; the body says why, with the current job and its age"}})
async def ready(worker: WorkerDep) -> JSONResponse:
    # The verdict first, then the job it reports: the job's age is read after the verdict was judged on
    # it, never before (an age read first could lie under the limit that the verdict found passed).
    busy = worker.overloaded() if worker.ready else None
    current = worker.current_job()
    state = {"queue_depth": worker.queue_depth,
             "current_job": None if current is None else {"what": current[0], "age_s": round(current[1], 3)}}
    if not worker.ready:
        reason = str(worker.startup_error) if worker.startup_error else "the render thread is not running"
        return JSONResponse({"status": "not ready", "detail": reason, **state}, status_code=503,
                            headers={"Retry-After": "5"})
    if busy is not None:
        return JSONResponse({"status": "busy", "detail": busy, "gl": worker.gl_info, **state}, status_code=503,
                            headers={"Retry-After": str(worker.retry_after_s())})
    return JSONResponse({"status": "ready", "gl": worker.gl_info, **state})


@stats_router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}})
async def metrics(m: MetricsDep) -> Response:
    return Response(m.render(), media_type=CONTENT_TYPE_LATEST)


@stats_router.get("/stats", summary="Queue, GL thread, PEM cache and registry statistics as JSON")
async def stats(worker: WorkerDep, settings: SettingsDep, envs: EnvironmentsDep, scenes: ScenesDep,
                meshes: MeshesDep, fabrics: FabricsDep, svc: ServicesDep) -> dict:
    w = worker.stats
    # Where this host keeps things, and the process's id on it, only to a caller with the service's
    # token: without one, anyone may ask (the label names the process: X-Render-Process).
    private = settings.token is not None

    def where(path) -> str | None:
        return None if path is None else str(path) if private else "(set; shown where the service has a token)"

    return {
        "state": None if svc.state is None else {
            "dir": where(svc.state.root), "stored_scenes": len(svc.state.scene_ids()),
            "restorations_pending": svc.restorations_pending, "temporaries_removed": svc.state.temporaries_removed},
        "ready": worker.ready, "gl": worker.gl_info, "process": {"label": process_label(), **({"pid": os.getpid()} if private else {})},
        "queue": {"depth": worker.queue_depth, "capacity": settings.queue_size, "busy": worker.busy,
                  "current_job": worker.current_job()},
        "jobs": {"done": w.jobs_done, "failed": w.jobs_failed, "rejected": w.jobs_rejected,
                 "abandoned": w.jobs_abandoned, "stopped": w.jobs_stopped,
                 "busy_ms_total": round(w.busy_ms_total, 1), "run_ms_ema": round(w.run_ms_ema, 2)},
        "pem_builds": {"ns_per_texel_light_measured": worker.pem_build_ns_per_texel_light,
                       "ns_per_texel_light_assumed": settings.pem_build_ns_per_texel_light,
                       "max_build_s": settings.max_pem_build_s, "max_build_bytes": settings.max_pem_build_bytes},
        "pem_cache": {"name": "pem-sets", "max_bytes": settings.pem_cache_bytes,
                      "disk_dir": where(settings.pem_cache_dir),
                      **worker.cache_stats().as_dict()},
        "counts": {"environments": len(envs), "scenes": len(scenes), "meshes": len(meshes.list()),
                   "fabrics": len(fabrics)},
        "environments": {"bytes": envs.nbytes, "max_bytes": settings.max_environment_bytes},
        "fabrics": {"bytes": fabrics.nbytes, "max_bytes": settings.max_fabric_bytes},
    }
