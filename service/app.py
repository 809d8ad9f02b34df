"""The app factory and its lifespan.

    uvicorn service.app:create_app --factory --host 127.0.0.1 --port 8000   (settings from GARMENT_RENDER_*)
    python -m service.main --host 127.0.0.1 --port 8000

The lifespan starts the render worker (the one GL thread of this process), creates the registries and
the metrics, and releases everything on shutdown. With `uvicorn --workers N` each process has its own
worker, GL context and memory cache; the disk cache (GARMENT_RENDER_PEM_CACHE_DIR) is shared, and
with GARMENT_RENDER_STATE_DIR so are environments and scenes (a process restores one on first use).
"""

from __future__ import annotations

import ctypes
import logging
import os
from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI

from renderer.presets import presets as renderer_presets
from renderer.presets.budget import load_table

from .errors import install_error_handlers
from .fabrics import FabricStore
from .limits import RequestGate
from .logs import process_label
from .metrics import ServiceMetrics
from .openapi import install_openapi
from .operations import Services
from .registry import EnvironmentStore, MeshStore, SceneStore
from .routes import environments, fabrics, frames, health, meshes, scenes, viewer
from .settings import ServiceSettings
from .state import StateDir
from .worker import GLResources, RenderWorker


def limit_malloc_arenas(n: int = 2) -> None:
    """Cap glibc's malloc arenas (unless MALLOC_ARENA_MAX is set). glibc gives threads their own arenas
    (up to 8 per core), and each keeps its peak: the few-MiB arrays of every frame (decoded positions,
    tone-mapping temporaries), allocated by whichever request thread runs the codec, made the resident
    set creep up in steps (+9 % over 2,000 frames after a burst of concurrent clients), while the
    same frames on one thread stayed flat. Two arenas keep it flat. No-op off glibc."""
    if os.environ.get("MALLOC_ARENA_MAX"):
        return
    try:
        ctypes.CDLL("libc.so.6").mallopt(-8, n)  # M_ARENA_MAX (malloc.h)
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


@asynccontextmanager
async def lifespan(app: FastAPI):
    settings: ServiceSettings = app.state.settings
    limit_malloc_arenas()
    # The measured table is read once: every budget request chooses from the same one (a table stored
    # while the service runs applies after a restart). The presets are the package's files.
    measured = load_table()
    app.state.presets, app.state.presets_source = renderer_presets()
    app.state.environments = EnvironmentStore(settings.max_environments, settings.max_environment_bytes)
    app.state.scenes = SceneStore(settings.max_scenes)
    app.state.meshes = MeshStore(settings.max_meshes)
    app.state.fabrics = FabricStore(settings.max_fabrics, settings.max_fabric_bytes)
    worker = RenderWorker(settings)
    app.state.worker = worker

    def release_scenes(gl: GLResources) -> None:
        for rec in app.state.scenes.list():
            rec.released = True
            rec.release_gpu()

    worker.on_shutdown(release_scenes)
    app.state.metrics = ServiceMetrics(worker, lambda: {
        "scenes": len(app.state.scenes), "environments": len(app.state.environments),
        "meshes": len(app.state.meshes.list()), "fabrics": len(app.state.fabrics)})
    state = StateDir(settings.state_dir) if settings.state_dir else None
    app.state.services = Services(settings, worker, app.state.environments, app.state.scenes, app.state.meshes,
                                  app.state.presets, measured, state, app.state.fabrics)
    await anyio.to_thread.run_sync(worker.start)  # not ready (503s) rather than dead when GL fails
    # Answers name this process by its label alone (X-Render-Process): the log ties it to the host's id.
    logging.getLogger("service").info("process %s is pid %d", process_label(), os.getpid())
    try:
        yield
    finally:
        await anyio.to_thread.run_sync(worker.stop)


def create_app(settings: ServiceSettings | None = None) -> FastAPI:
    """The service. Without `settings`, they come from the environment (GARMENT_RENDER_*)."""
    settings = settings or ServiceSettings()
    app = FastAPI(
        title="garment-render",
        version="0.1.0",
        summary="Per-frame cloth meshes over HTTP: image-based lighting with self-shadowing (PEM + VSM), "
                "PNG/EXR images with per-stage timings",
        lifespan=lifespan,
    )
    app.state.settings = settings
    install_error_handlers(app)
    install_openapi(app, token_set=settings.token is not None)
    token = settings.token.get_secret_value() if settings.token is not None else None
    media_types = (*environments.ENV_MEDIA_TYPES, *meshes.MESH_MEDIA_TYPES, *fabrics.FABRIC_MEDIA_TYPES,
                   "application/json")
    app.add_middleware(RequestGate, max_bytes=settings.max_upload_bytes, token=token, media_types=media_types)
    app.include_router(health.router)
    app.include_router(health.stats_router)
    app.include_router(environments.router)
    app.include_router(meshes.router)
    app.include_router(fabrics.router)
    app.include_router(scenes.router)
    app.include_router(frames.router)
    app.include_router(viewer.router)
    app.include_router(viewer.page_router)
    return app
