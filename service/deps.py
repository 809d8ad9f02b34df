"""Dependencies as `Annotated` aliases: the settings and the long-lived objects the lifespan created,
the bearer-token check, and raw request bodies with a content-type check."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .errors import InvalidRequestError, UnsupportedMediaTypeError
from .fabrics import FabricStore
from .limits import bearer_refusal
from .metrics import ServiceMetrics
from .operations import Services
from .registry import EnvironmentStore, MeshStore, SceneStore
from .settings import ServiceSettings
from .worker import RenderWorker


def get_settings(request: Request) -> ServiceSettings:
    return request.app.state.settings


def get_worker(request: Request) -> RenderWorker:
    return request.app.state.worker


def get_environments(request: Request) -> EnvironmentStore:
    return request.app.state.environments


def get_scenes(request: Request) -> SceneStore:
    return request.app.state.scenes


def get_meshes(request: Request) -> MeshStore:
    return request.app.state.meshes


def get_fabrics(request: Request) -> FabricStore:
    return request.app.state.fabrics


def get_metrics(request: Request) -> ServiceMetrics:
    return request.app.state.metrics


def get_services(request: Request) -> Services:
    return request.app.state.services


SettingsDep = Annotated[ServiceSettings, Depends(get_settings)]
WorkerDep = Annotated[RenderWorker, Depends(get_worker)]
EnvironmentsDep = Annotated[EnvironmentStore, Depends(get_environments)]
ScenesDep = Annotated[SceneStore, Depends(get_scenes)]
MeshesDep = Annotated[MeshStore, Depends(get_meshes)]
FabricsDep = Annotated[FabricStore, Depends(get_fabrics)]
MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]
ServicesDep = Annotated[Services, Depends(get_services)]

_bearer = HTTPBearer(auto_error=False, description="GARMENT_RENDER_TOKEN, when the service sets one")


def require_token(request: Request, settings: SettingsDep,
                  _: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    """Every router but health depends on this (which also declares the bearer scheme in the OpenAPI
    document); the request gate has checked the same on the headers already, by the same rule
    (`limits.bearer_refusal`). A no-op when no token is configured."""
    if settings.token is None:
        return
    refusal = bearer_refusal(request.headers.get("authorization", "").encode("latin-1"),
                             settings.token.get_secret_value().encode())
    if refusal is not None:
        raise refusal


def media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def raw_body(request: Request, accepted: tuple[str, ...], what: str) -> bytes:
    """The request body (already size-checked by the body-limit middleware) if its Content-Type is accepted."""
    mt = media_type(request)
    if mt not in accepted:
        raise UnsupportedMediaTypeError(
            f"{what} must be sent as {' or '.join(accepted)}; got Content-Type {mt or '(none)'!r}")
    body = await request.body()
    if not body:
        raise InvalidRequestError(f"{what}: the request body is empty")
    return body


OCTET_STREAM = "application/octet-stream"


async def _until_disconnected(request: Request) -> None:
    while (await request.receive())["type"] != "http.disconnect":
        pass


@contextlib.asynccontextmanager
async def client_gone(request: Request):
    """A future done when the client of `request` closes its connection (its body already read),
    watched while the block runs."""
    gone = asyncio.ensure_future(_until_disconnected(request))
    try:
        yield gone
    finally:
        gone.cancel()
