"""Dependencies as `Annotated` aliases: the settings and the long-lived objects the lifespan created,
the bearer-token check, and raw request bodies with a content-type check."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .errors import InvalidRequestError, UnauthorizedError, UnsupportedMediaTypeError
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


def get_metrics(request: Request) -> ServiceMetrics:
    return request.app.state.metrics


def get_services(request: Request) -> Services:
    return request.app.state.services


SettingsDep = Annotated[ServiceSettings, Depends(get_settings)]
WorkerDep = Annotated[RenderWorker, Depends(get_worker)]
EnvironmentsDep = Annotated[EnvironmentStore, Depends(get_environments)]
ScenesDep = Annotated[SceneStore, Depends(get_scenes)]
MeshesDep = Annotated[MeshStore, Depends(get_meshes)]
MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]
ServicesDep = Annotated[Services, Depends(get_services)]

_bearer = HTTPBearer(auto_error=False, description="GARMENT_RENDER_TOKEN, when the service sets one")


def require_token(settings: SettingsDep,
                  credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    """Every router but health depends on this; a no-op when no token is configured."""
    if settings.token is None:
        return
    if credentials is None:
        raise UnauthorizedError("this service needs a bearer token: send 'Authorization: Bearer <token>'")
    expected = settings.token.get_secret_value().encode()
    if not secrets.compare_digest(credentials.credentials.encode(), expected):
        raise UnauthorizedError("wrong bearer token")


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


def client_gone(request: Request):
    """A future done when the client of `request` closes its connection (its body already read);
    cancel it when the answer is sent."""
    import asyncio

    return asyncio.ensure_future(_until_disconnected(request))
