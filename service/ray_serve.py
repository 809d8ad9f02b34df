"""The service as Ray Serve replicas of one deployment, behind the same HTTP API (`pip install .[ray]`).

    garment-render serve --ray [--replicas N] [--address RAY_ADDRESS] [--gpus-per-replica 1]
    serve run deploy/serve.yaml                     (a cluster: `ray start --head`, then this)

Each render replica is one process with one GL context: the service's own FastAPI app (service.app),
driven in-process through its ASGI interface, with its lifespan (the GL thread) started on the
replica's first request. Serve's HTTP proxy hands every request to a small ingress deployment, which
sends it on to a render replica through a handle. What Ray adds:

- **Scene affinity** by a consistent-hash ring of the replicas, keyed by scene id (`Ingress`): every
  request of a scene, its registration first, reaches one replica while the replicas stay the same
  (the client sends the scene id as `serve_multiplexed_model_id` where the path does not hold it). A
  replica holds at most SCENES_PER_REPLICA scenes' GPU objects, the least recently used released first
  (Serve's multiplexing cache; the stored registration stays). A request that reaches another replica
  (the ring changed: a replica died or was added) re-creates the scene there from its stored
  registration.
- **A replica lost mid-request costs no answer.** The ingress sends a request whose replica died
  again, to the replica that restores its scene (a batch whole: none of its frames had been
  answered), and answers the service's JSON error where it cannot (`Ingress`).
- **The shared directories.** The state directory (environments, scenes) and the PEM disk cache are
  one folder for every replica (a shared file system on a cluster). A PEM set one replica built is read
  by the others, and any replica can restore any scene.
- **Backpressure and health** stay the service's: each replica's bounded queue answers 503 with
  Retry-After; `/health/ready` is the answering replica's; every answer names its replica (`X-Replica`).
- **Metrics of every replica** in one scrape: each replica reports its Prometheus metrics to one
  named Ray actor (MetricsBoard) every REPORT_EVERY_S, and `/metrics`, on whichever replica answers
  it, is every live replica's series, labelled `replica`, plus `garment_render_replicas_reporting`.
  A replica silent for STALE_AFTER_S has gone and drops out.
- **Two ingress replicas** (INGRESS_REPLICAS): Serve's proxy sends new requests to the one left when
  the other dies, so losing one costs the requests it held (Serve's proxy answers them with its own
  plain-text 500, which the client sends again: `garment_render_client`), not an outage while Serve
  starts another.
- **A local instance keeps to the loopback.** `garment-render serve --ray` without an address starts
  Ray with the node's address at 127.0.0.1 (RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, set before Ray is
  imported), so the GCS, the raylet, the workers and the agents listen there alone. Serve's proxy
  binds `--host`. Each Serve replica's inter-deployment gRPC server, which Ray Serve binds to every
  interface with no setting for it, binds the node's address instead, as Ray's own servers do
  (`_bind_replica_grpc_to_node`: the loopback for a local instance, the node's one address on a
  cluster).
- **GPUs**: with `--gpus-per-replica 1` each replica gets one GPU from Ray (GARMENT_RENDER_GPU), and
  renders on the EGL device that reports that GPU's CUDA ordinal (renderer/gpu/egl_devices.py), not on
  the first device nor on the EGL device of the GPU's number: EGL's order need not be CUDA's.
"""

from __future__ import annotations

import asyncio
import os
import re
import time
from contextlib import AsyncExitStack
from pathlib import Path

import httpx
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.parser import text_string_to_metric_families

try:
    import ray
    import ray.serve.exceptions
    from ray import serve
    from ray.serve.config import RequestRouterConfig
    from ray.serve.experimental.consistent_hash_router import ConsistentHashRouter
    from starlette.requests import Request
    from starlette.responses import Response
except ImportError as exc:   # pragma: no cover - the extra is not installed
    raise ImportError("Ray Serve is an optional extra: pip install 'garment-render[ray]' (or .[ray])") from exc

from .logs import ray_address_note

# /scenes/{id}... : the scene a request is for.
SCENE_PATH = re.compile(r"^/scenes/(scn_[0-9a-f]+)(?:/|$)")
# The client's header naming the scene a request is for (garment_render_client sends it; Serve's routing key).
MODEL_ID_HEADER = "serve_multiplexed_model_id"
# How long the ingress keeps sending a request whose replica went, and how many requests the ingress and
# a replica hold at once (a replica's own bounded queue answers 503 before Serve's limit is reached: the
# ring's strict affinity never sends a scene's request to another replica for being busy).
RETRY_FOR_S, INGRESS_MAX_ONGOING, REPLICA_MAX_ONGOING = 60.0, 1000, 256
# Ingress replicas: one left to take the requests while Serve replaces one that died.
INGRESS_REPLICAS = 2
# Scenes a replica holds for the router (each keeps its GPU buffers); the least recently used go first.
SCENES_PER_REPLICA = 16
# The replicas' metrics: one named actor they report to, how often, and when a silent one has gone.
METRICS_BOARD, METRICS_NAMESPACE = "garment-render-metrics", "serve"
REPORT_EVERY_S, STALE_AFTER_S = 1.0, 5.0

# Ray Serve's wait for its HTTP proxy to be ready (seconds, its default 5), for a local instance.
PROXY_READY_SWITCH, PROXY_READY_S = "RAY_SERVE_PROXY_READY_CHECK_TIMEOUT_S", 30.0


def _bind_replica_grpc_to_node() -> None:
    """Make each Serve replica of this process bind its inter-deployment gRPC server to the node's
    address, not to every interface: Ray Serve binds it to "[::]:0" (serve/_private/replica.py) with
    no setting for it. Runs where this module is imported, which a replica of this deployment does
    before Serve starts that server. A Ray without that helper is left as it is."""
    from ray.serve._private import replica as serve_replica

    bind = getattr(serve_replica, "add_port_to_grpc_server", None)
    if bind is None or getattr(bind, "binds_node_address", False):
        return

    def bind_node_address(server, address: str):
        if address.startswith("[::]:"):
            node = _node_address()
            address = (f"[{node}]" if ":" in node else node) + address[4:]
        return bind(server, address)

    bind_node_address.binds_node_address = True
    serve_replica.add_port_to_grpc_server = bind_node_address


def _node_address() -> str:
    """The address Ray knows this worker's node by (its raylet's), else the one Ray would pick."""
    try:
        return ray._private.worker.global_worker.node_ip_address
    except Exception:   # not connected to Ray (yet)
        return ray.util.get_node_ip_address()


_bind_replica_grpc_to_node()


@ray.remote(num_cpus=0)
class MetricsBoard:
    """The latest Prometheus text of each replica (one small actor for the deployment)."""

    def __init__(self):
        self.latest: dict[str, tuple[float, bytes]] = {}

    def report(self, replica: str, text: bytes) -> None:
        self.latest[replica] = (time.monotonic(), text)

    def leave(self, replica: str) -> None:
        self.latest.pop(replica, None)

    def collect(self, stale_after_s: float = STALE_AFTER_S) -> dict[str, bytes]:
        now = time.monotonic()
        self.latest = {r: (t, text) for r, (t, text) in self.latest.items() if now - t <= stale_after_s}
        return {r: text for r, (_, text) in self.latest.items()}


def merge_metrics(snapshots: dict[str, bytes]) -> bytes:
    """One Prometheus exposition from each replica's own: every sample labelled with its replica, each
    family written once, and the number of replicas reporting."""
    families: dict[str, object] = {}
    for replica, text in sorted(snapshots.items()):
        for family in text_string_to_metric_families(text.decode()):
            merged = families.setdefault(family.name, family)
            samples = [s._replace(labels={**s.labels, "replica": replica}) for s in family.samples]
            merged.samples = (merged.samples if merged is not family else []) + samples
    reporting = GaugeMetricFamily("garment_render_replicas_reporting", "Replicas whose metrics this answer holds")
    reporting.add_metric([], len(snapshots))

    class _Merged:
        def collect(self):
            yield reporting
            yield from families.values()

    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Merged())
    return generate_latest(registry)


class _HeldScene:
    """A scene this replica holds for Serve's multiplexing; letting it go releases its GPU objects."""

    def __init__(self, replica: RenderReplica, scene_id: str):
        self.replica, self.scene_id, self.loop = replica, scene_id, asyncio.get_running_loop()

    def __del__(self):
        replica, self.replica = self.__dict__.get("replica"), None
        if replica is not None and not self.loop.is_closed():
            # Called by Serve's LRU (in an executor thread) or by the garbage collector.
            asyncio.run_coroutine_threadsafe(replica.let_go(self.scene_id), self.loop)


@serve.deployment(name="garment-render", ray_actor_options={"num_cpus": 0}, max_ongoing_requests=REPLICA_MAX_ONGOING,
                  request_router_config=RequestRouterConfig(request_router_class=ConsistentHashRouter,
                                                            request_router_kwargs={"num_fallback_replicas": 0}))
class RenderReplica:
    def __init__(self, settings: dict | None = None):
        gpu_ids = _ray_gpu_ids()
        if gpu_ids:   # the GPU Ray gave this replica; its EGL device is found by its CUDA ordinal
            os.environ["GARMENT_RENDER_GPU"] = str(int(gpu_ids[0]))
        from .app import create_app
        from .settings import ServiceSettings

        self.settings = ServiceSettings(**(settings or {}))
        if self.settings.state_dir is None:
            raise ValueError("Ray replicas need a shared state directory (GARMENT_RENDER_STATE_DIR): it is how a "
                             "replica restores a scene another one registered")
        self.app = create_app(self.settings)
        self.app.state.scene_ids_assigned = True   # a new scene's id comes from the ingress (X-Assigned-Scene-Id)
        self.name = _replica_name()
        self._stack: AsyncExitStack | None = None
        self._started = asyncio.Lock()
        self.client: httpx.AsyncClient | None = None
        self._board = None
        self._reporter: asyncio.Task | None = None

    async def _start(self) -> None:
        async with self._started:
            if self.client is None:
                self._stack = AsyncExitStack()
                await self._stack.enter_async_context(self.app.router.lifespan_context(self.app))
                self.client = httpx.AsyncClient(transport=httpx.ASGITransport(app=self.app),
                                                base_url="http://replica", timeout=None)
                self._reporter = asyncio.get_running_loop().create_task(self._report_metrics())

    def board(self):
        """The deployment's metrics board, made by the first replica that asks (detached: it outlives any
        one replica; `run` removes it)."""
        if self._board is None:
            self._board = MetricsBoard.options(name=METRICS_BOARD, namespace=METRICS_NAMESPACE,
                                               get_if_exists=True, lifetime="detached").remote()
        return self._board

    async def _report_metrics(self) -> None:
        while True:
            try:
                await self.board().report.remote(self.name, self.app.state.metrics.render())
            except Exception:   # the board went (a node lost): made again on the next report
                self._board = None
            await asyncio.sleep(REPORT_EVERY_S)

    async def _all_metrics(self, own: bytes) -> bytes:
        """/metrics: every live replica's, this one's as of now."""
        try:
            board = self.board()
            await board.report.remote(self.name, own)
            return merge_metrics(await board.collect.remote())
        except Exception:   # no board: this replica's alone, still labelled
            self._board = None
            return merge_metrics({self.name: own})

    @serve.multiplexed(max_num_models_per_replica=SCENES_PER_REPLICA)
    async def scene(self, scene_id: str) -> _HeldScene:
        """Hold a scene here (Serve's multiplexing cache, for its LRU release): the scene itself is made or
        restored by the request."""
        return _HeldScene(self, scene_id)

    async def let_go(self, scene_id: str) -> None:
        """Release a scene's GPU objects here; its stored registration stays (another replica, or this
        one later, restores it)."""
        from .operations import release_scene_here

        await release_scene_here(self.app.state.services, scene_id)

    async def forward(self, method: str, url: str, headers: list[tuple[str, str]], body: bytes
                      ) -> tuple[int, dict[str, str], bytes]:
        """One HTTP request, sent by the ingress, answered by this replica's app: (status, headers, body)."""
        await self._start()
        path = url.split("?", 1)[0]
        match = SCENE_PATH.match(path)
        if match and method != "DELETE":   # the ring sent it here by this id
            await self.scene(match.group(1))
        r = await self.client.request(method, url, content=body, headers=headers)
        content = r.content
        if method == "POST" and path.rstrip("/") == "/scenes" and r.status_code == 201:
            await self.scene(r.json()["id"])   # the registering replica holds its scene
        elif method == "GET" and path == "/metrics" and r.status_code == 200:
            content = await self._all_metrics(content)
        # Serve's proxy answers with the request's id itself, the one it gave the request (the client's,
        # else its own), which the service took as the request's id: the service's copy would repeat it.
        out = {k: v for k, v in r.headers.items()
               if k.lower() not in ("content-length", "transfer-encoding", "x-request-id")}
        out["X-Replica"] = self.name
        return r.status_code, out, content

    def __del__(self):
        """Serve's graceful shutdown of the replica: its GL thread releases the scenes and the context
        (a replica whose app never started has none)."""
        if getattr(self, "client", None) is not None:
            self.app.state.worker.stop()
        if getattr(self, "_board", None) is not None:
            try:
                self._board.leave.remote(self.name)
            except Exception:   # pragma: no cover - Ray is going down too
                pass

    def check_health(self) -> None:
        """Serve's health check: the replica's GL thread must be up once it has started."""
        if self.client is not None and not self.app.state.worker.ready:
            raise RuntimeError(f"replica {self.name}: the GL thread is not running")


def _replica_lost(exc: BaseException) -> bool:
    """Ray's word that the replica went while it held the request (ActorDiedError, ActorUnavailableError,
    a replica Serve knows is gone, or a task error caused by one of them), not an error of the request."""
    if isinstance(exc, ray.exceptions.RayTaskError):
        exc = getattr(exc, "cause", None) or exc
    return isinstance(exc, (ray.exceptions.RayActorError, serve.exceptions.ReplicaUnavailableError))


@serve.deployment(name="garment-render-ingress", ray_actor_options={"num_cpus": 0},
                  max_ongoing_requests=INGRESS_MAX_ONGOING)
class Ingress:
    """What Serve's HTTP proxy calls. Each request goes on to a render replica through a handle, routed
    by its scene's id (the path's, else the client's `serve_multiplexed_model_id` header) on a
    consistent-hash ring of the replicas: every request of a scene reaches the same replica while the
    replicas stay the same. A scene's registration is routed by the id the ingress gives it here
    (X-Assigned-Scene-Id), so its first frame finds it where it was made.

    A replica that dies while it holds a request (killed, out of memory, its node lost) costs the
    request nothing but time: it is sent again, to the replica the ring names now (which restores the
    scene from its stored registration), for up to RETRY_FOR_S. A batch is sent again whole: none of
    its frames had been answered. A scene's registration is not sent again (it may have been stored:
    a second one would make a second scene); it, and a request still unanswered after RETRY_FOR_S, get
    the service's own JSON error (503 replica_lost, Retry-After), never the proxy's text."""

    def __init__(self, replicas):
        self.replicas = replicas

    async def __call__(self, request: Request) -> Response:
        from .errors import ReplicaLostError, response_for
        from .operations import ASSIGNED_SCENE_ID
        from .registry import SceneStore

        path, method = request.url.path, request.method
        registration = method == "POST" and path.rstrip("/") == "/scenes"
        headers = [(k, v) for k, v in request.headers.items()
                   if k.lower() not in ("host", "content-length", ASSIGNED_SCENE_ID)]
        match = SCENE_PATH.match(path)
        if registration:
            scene_id = SceneStore.new_id()
            headers.append((ASSIGNED_SCENE_ID, scene_id))
        else:
            scene_id = match.group(1) if match else request.headers.get(MODEL_ID_HEADER)
        handle = self.replicas.options(session_id=scene_id) if scene_id else self.replicas
        body = await request.body()
        url = path + (f"?{request.url.query}" if request.url.query else "")
        deadline, lost = time.monotonic() + RETRY_FOR_S, 0
        while True:
            try:
                status, out, content = await handle.forward.remote(method, url, headers, body)
                break
            except Exception as exc:
                if not _replica_lost(exc):   # the replica's own failure, answered as the service's error
                    return response_for(exc)
                lost += 1
                if registration or time.monotonic() > deadline:
                    what = ("the scene's registration is not sent again (it may have been stored): register it "
                            "again" if registration else f"no replica answered it within {RETRY_FOR_S:g} s; try again")
                    return response_for(ReplicaLostError(
                        f"the replica holding {method} {path} went before it answered ({type(exc).__name__}); {what}"))
                await asyncio.sleep(min(0.1 * 2 ** lost, 2.0))
        if lost:
            out["X-Replicas-Lost"] = str(lost)
        return Response(content, status_code=status, headers=out)

def _ray_gpu_ids() -> list:
    try:
        return ray.get_gpu_ids() if ray.is_initialized() else []
    except Exception:   # pragma: no cover - outside a Ray worker
        return []


def _replica_name() -> str:
    try:
        ctx = serve.get_replica_context()
        return getattr(ctx, "replica_tag", None) or str(ctx.replica_id.unique_id)
    except Exception:   # pragma: no cover - outside Serve
        return f"pid-{os.getpid()}"


def application(replicas: int = 2, settings: dict | None = None, gpus_per_replica: float = 0.0):
    """The Serve application: `replicas` copies of the service (settings: ServiceSettings fields)."""
    options = {"num_replicas": replicas, "ray_actor_options": {"num_cpus": 0, "num_gpus": gpus_per_replica}}
    return Ingress.options(num_replicas=INGRESS_REPLICAS).bind(RenderReplica.options(**options).bind(settings))


def app_builder(args: dict):
    """For `serve run deploy/serve.yaml`: its `args` (replicas, gpus_per_replica, settings)."""
    return application(int(args.get("replicas", 2)), args.get("settings"), float(args.get("gpus_per_replica", 0)))


def local_state_dir() -> Path:
    """Where a local `serve --ray` keeps its scenes without GARMENT_RENDER_STATE_DIR:
    $XDG_STATE_HOME/garment-render/state, else ~/.local/state/garment-render/state."""
    root = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(root) / "garment-render" / "state"


def run(host: str | None, port: int | None, replicas: int, address: str | None = None,
        gpus_per_replica: float = 0.0) -> None:
    """`garment-render serve --ray`: a local Ray instance (or the cluster at `address`), the
    deployment behind Serve's HTTP proxy on host:port (default: the service's settings); blocks until
    interrupted. The replicas read their settings from the same GARMENT_RENDER_* environment."""
    import signal
    import threading

    from .settings import ServiceSettings

    checked = ServiceSettings()   # refused here, not by every replica in turn
    if checked.state_dir is None:
        if address is not None or os.environ.get("RAY_ADDRESS"):
            raise ValueError("serve --ray on a cluster needs GARMENT_RENDER_STATE_DIR, a directory every replica "
                             "shares: it is how a replica restores a scene another one registered")
        # One machine: its replicas share a directory of this user's (they inherit the environment).
        state = local_state_dir()
        state.mkdir(parents=True, exist_ok=True)
        os.environ["GARMENT_RENDER_STATE_DIR"] = str(state)
        print(f"garment-render: GARMENT_RENDER_STATE_DIR is not set: the replicas on this machine share {state}",
              flush=True)
    host, port = host or checked.host, checked.port if port is None else port

    if address is None and not os.environ.get("RAY_ADDRESS"):
        # Serve's controller marks a proxy that is not ready within 5 s three times over (5, 10, 15 s)
        # unhealthy and kills it, and serve.start then fails: on a loaded two-core machine the proxy's
        # own imports take longer. A local instance's processes inherit this environment (a cluster's,
        # or a Ray instance already running here, are their own to set).
        os.environ.setdefault(PROXY_READY_SWITCH, str(PROXY_READY_S))
        from ray._private import services

        node = services.get_node_ip_address()
        if node not in ("127.0.0.1", "::1"):   # Ray was imported before `garment-render serve --ray` set it
            print(f"garment-render: Ray's own ports listen on every interface ({node}): start a local instance with "
                  "`garment-render serve --ray` (it sets RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 before Ray starts)",
                  flush=True)
    ray.init(address=address, include_dashboard=False, ignore_reinit_error=True)
    serve.start(http_options={"host": host, "port": port})
    serve.run(application(replicas, None, gpus_per_replica), name="garment-render", route_prefix="/")
    # The Ray instance's own address: `ray.init(address="auto")` elsewhere on this machine picks any
    # instance it finds running when none was started by `ray start`, so a process that must reach this
    # one sets RAY_ADDRESS to it.
    print(f"garment-render: {replicas} Ray Serve replicas on http://{host}:{port} "
          f"{ray_address_note(ray.get_runtime_context().gcs_address)}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(1.0):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        serve.shutdown()
        try:   # the metrics board is detached: it goes with the deployment
            ray.kill(ray.get_actor(METRICS_BOARD, namespace=METRICS_NAMESPACE))
        except ValueError:
            pass
        ray.shutdown()
