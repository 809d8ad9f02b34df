"""The render worker: the one thread per process that owns the GL context.

It creates the `Renderer` and the `PEMCache` on its own thread (a context is bound to the thread that
made it; the renderer checks this on every call) and then runs jobs from a bounded queue, one at a
time. A job is a function of `GLResources`; its result comes back through a future. Everything that
does not need GL (decoding request bodies, validating meshes, normals, tone mapping and PNG/EXR
encoding) happens in the request handlers, off this thread, so the GL thread only uploads, renders
and reads back.

A full queue raises `QueueFullError` (503 + Retry-After) instead of waiting: a simulator retries, and
the service never holds an unbounded backlog. Scale by processes (uvicorn --workers N), each with its
own worker.

A long job (a batch) is a generator: the GL thread runs it a step (a frame) at a time and, between two
steps, the job queued next, so that one scene's long job does not starve another's frames (turns
alternate between the jobs in steps and those waiting to start). A job asked to stop (`Job.stop`: its
request timed out or its client left) stops at its next step, or, for one that checks
`GLResources.stop_requested` itself (the views of a frame), at its next image.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import math
import queue
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Generator
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, TypeVar

from renderer.cache import CacheStats, PEMCache
from renderer.errors import GLContextError, RenderStoppedError
from renderer.lighting.pem import PEMSet
from renderer.lighting.pem_plan import PEMSettings, pem_cost
from renderer.renderer import Renderer
from renderer.shading.background import BackgroundMap

from .budgets import FrameRates
from .errors import ClientGoneError, NotReadyError, QueueFullError, RenderTimeoutError
from .settings import ServiceSettings

log = logging.getLogger("service.worker")

T = TypeVar("T")


def NEVER_STOP() -> bool:   # noqa: N802 - a constant function: what no job between jobs is asked
    return False


# Background maps kept on the GL thread (least recently used first out): one per environment in use.
BACKGROUND_MAPS_KEPT = 4


@dataclass
class GLResources:
    """What a job may use; only ever touched on the worker's thread."""

    renderer: Renderer
    cache: PEMCache
    backgrounds: OrderedDict = field(default_factory=OrderedDict)
    # The measured time of this device's PEM builds per texel and light (pem_cost), a moving average
    # over builds of 10^6 texel-lights and more (None: none yet): what GARMENT_RENDER_PEM_BUILD_NS_PER_TEXEL_LIGHT
    # estimates.
    pem_build_ns_per_texel_light: float | None = None
    # Whether the job now running was asked to stop (`Job.stop`): a job that takes long checks it
    # between its parts and raises `JobStoppedError`.
    stop_requested: Callable[[], bool] = NEVER_STOP

    def background(self, content_hash: str, source) -> BackgroundMap:
        """The background map of an environment (`renderer.shading.background`), made on first use
        from `source` (a lat-long image, or a cube of another layout) and kept for the next frames."""
        bg = self.backgrounds.pop(content_hash, None)
        if bg is None:
            bg = self.renderer.background_map(source)
            while len(self.backgrounds) >= BACKGROUND_MAPS_KEPT:
                self.backgrounds.popitem(last=False)[1].release()
        self.backgrounds[content_hash] = bg
        return bg

    def release_backgrounds(self) -> None:
        for bg in self.backgrounds.values():
            bg.release()
        self.backgrounds.clear()

    def pem_set(self, content_hash: str, cube, settings: PEMSettings) -> tuple[PEMSet, str]:
        """The PEM set from the cache and where it came from: "memory", "disk" or "built".

        Fetched again for every frame rather than held by a scene: the cache may have evicted (and
        released) it for another map since the last frame."""
        before = self.cache.stats.as_dict()
        pems = self.cache.get(content_hash, cube, settings)
        after = self.cache.stats
        if after.hits > before["hits"]:
            return pems, "memory"
        if after.disk_hits > before["disk_hits"]:
            return pems, "disk"
        work = pem_cost(cube.shape[1], settings).texel_lights
        if work >= 1e6:
            rate = pems.build_ms * 1e6 / work
            old = self.pem_build_ns_per_texel_light
            self.pem_build_ns_per_texel_light = rate if old is None else 0.8 * old + 0.2 * rate
        return pems, "built"


class JobStoppedError(RenderTimeoutError):
    """A job stopped before its end because its request was over (timed out, or its client gone)."""


@dataclass
class Job:
    """A submitted job: its future and when it was queued, started and finished (perf_counter s)."""

    fn: Callable[[GLResources], Any]
    future: Future
    enqueued: float
    what: str = "job"   # what it does, for readiness and logs ("frame of scene_...", "PEM set ...")
    started: float = 0.0
    finished: float = 0.0
    # Set when the request is over: the job stops at its next step (or part, `stop_requested`).
    stop: threading.Event = field(default_factory=threading.Event)
    steps: Generator | None = None   # a job in steps, once started: its generator

    @property
    def queue_ms(self) -> float:
        return (self.started - self.enqueued) * 1e3 if self.started else 0.0


@dataclass
class JobResult:
    value: Any
    queue_ms: float
    run_ms: float


@dataclass
class WorkerStats:
    jobs_done: int = 0
    jobs_failed: int = 0
    jobs_rejected: int = 0
    jobs_abandoned: int = 0   # dropped from the queue because their client went away
    jobs_stopped: int = 0     # stopped before their end: their request timed out or its client went away
    busy_ms_total: float = 0.0
    run_ms_ema: float = 0.0  # exponential moving average of a job's run time (Retry-After estimate)
    cache: dict = field(default_factory=dict)


class RenderWorker:
    """Start with `start()` (blocks until the GL context is up or failed), stop with `stop()`."""

    def __init__(self, settings: ServiceSettings):
        self.settings = settings
        self._queue: queue.Queue[Job | None] = queue.Queue(maxsize=settings.queue_size)
        self._thread = threading.Thread(target=self._run, name="gl-render", daemon=True)
        self._ready = threading.Event()
        self._stopping = threading.Event()
        self._gl: GLResources | None = None
        self.startup_error: Exception | None = None
        self.gl_info: dict = {}
        # Where a frame's missing normals are made: by the renderer's compute pass on the GL thread
        # when it has one (a GPU), else by numpy with the decoding, off the GL thread.
        self.normals_on_gpu = False
        self.stats = WorkerStats()
        self.rates = FrameRates()   # the GL time of frames, for requests' estimates (budgets.py)
        self._running_since: float | None = None
        self._running: Job | None = None
        self._stepping: deque[Job] = deque()   # jobs in steps between two of their steps (GL thread only)
        self._cleanup: list[Callable[[GLResources], None]] = []

    # -- lifecycle (called from the app's lifespan) ---------------------------------------------
    def start(self) -> None:
        self._thread.start()
        if not self._ready.wait(self.settings.startup_timeout_s):
            self.startup_error = GLContextError(
                f"the GL context was not up within {self.settings.startup_timeout_s} s")
        if self.startup_error is not None:
            log.error("render worker not ready: %s", self.startup_error)

    def stop(self, timeout: float = 30.0) -> None:
        """Fail the jobs still queued, let the running one finish, release every GL object."""
        self._stopping.set()
        while True:
            try:
                job = self._queue.get_nowait()
            except queue.Empty:
                break
            if job is not None and job.future.set_running_or_notify_cancel():
                job.future.set_exception(NotReadyError("the service is shutting down"))
        try:
            self._queue.put(None, timeout=timeout)
        except queue.Full:  # pragma: no cover - the thread is wedged; it is a daemon
            pass
        if self._thread.is_alive():
            self._thread.join(timeout)

    def on_shutdown(self, fn: Callable[[GLResources], None]) -> None:
        """Run `fn` on the GL thread before the context goes (release scenes the app still holds)."""
        self._cleanup.append(fn)

    @property
    def ready(self) -> bool:
        return self._ready.is_set() and self.startup_error is None and self._thread.is_alive() \
            and not self._stopping.is_set()

    @property
    def queue_depth(self) -> int:
        return self._queue.qsize()

    @property
    def busy(self) -> bool:
        return self._running_since is not None

    def current_job(self) -> tuple[str, float] | None:
        """What the GL thread runs now and for how many seconds (None: idle)."""
        job, since = self._running, self._running_since
        if job is None or since is None:
            return None
        return job.what, time.perf_counter() - since

    def overloaded(self) -> str | None:
        """Why this process should get no new work now (None: it should): its queue is full, or
        the GL thread has been on one job longer than GARMENT_RENDER_READY_MAX_BUSY_S."""
        if self._queue.qsize() >= self.settings.queue_size:
            return f"the render queue is full ({self.settings.queue_size} jobs waiting)"
        current = self.current_job()
        if current is not None and current[1] > self.settings.ready_max_busy_s:
            return (f"the render thread has been busy for {current[1]:.1f} s with {current[0]}, over "
                    f"GARMENT_RENDER_READY_MAX_BUSY_S = {self.settings.ready_max_busy_s:g} s")
        return None

    @property
    def pem_build_ns_per_texel_light(self) -> float | None:
        """The measured rate of this device's PEM builds (GLResources), None before the first."""
        gl = self._gl
        return gl.pem_build_ns_per_texel_light if gl is not None else None

    def cache_stats(self) -> CacheStats:
        """A copy of the PEM cache statistics (ints read without a lock: a snapshot, possibly one job stale)."""
        return CacheStats(**self._gl.cache.stats.as_dict()) if self._gl is not None else CacheStats()

    # -- submitting ------------------------------------------------------------------------------
    def submit(self, fn: Callable[[GLResources], T], what: str = "job") -> Job:
        """Queue `fn` for the GL thread; QueueFullError (503) when the queue is full."""
        if not self.ready:
            reason = self.startup_error or "the render worker is not running"
            raise NotReadyError(f"the renderer is not ready: {reason}")
        job = Job(fn, Future(), time.perf_counter(), what)
        try:
            self._queue.put_nowait(job)
        except queue.Full:
            self.stats.jobs_rejected += 1
            raise QueueFullError(
                f"the render queue is full ({self.settings.queue_size} jobs waiting for the GL thread); "
                f"retry after the Retry-After delay, or run more service processes", self.retry_after_s()) from None
        return job

    def retry_after_s(self) -> int:
        """Seconds until the work ahead is likely done: the queued jobs at the moving average of a
        job's run time, plus what the current job has left of it (at least 1)."""
        ema_s = self.stats.run_ms_ema / 1e3
        ahead = self._queue.qsize() * ema_s
        current = self.current_job()
        if current is not None:
            ahead += max(ema_s - current[1], 0.0)
        return max(1, math.ceil(ahead))

    async def call(self, fn: Callable[[GLResources], T], timeout: float | None = None, what: str = "job",
                   abandoned: asyncio.Future | None = None) -> JobResult:
        """Run `fn` on the GL thread and await it; a job still queued at the timeout, or when
        `abandoned` completes first (its client went away: `deps.client_gone`), is dropped."""
        job = self.submit(fn, what)
        fut = job.future
        timeout = self.settings.request_timeout_s if timeout is None else timeout
        result = asyncio.wrap_future(fut)
        waits = {result} | ({abandoned} if abandoned is not None else set())
        done, _ = await asyncio.wait(waits, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        if result not in done:
            if not fut.cancel():   # running: it stops at its next step or part (a single frame finishes)
                job.stop.set()
            if abandoned is not None and abandoned in done:
                self.stats.jobs_abandoned += 1
                raise ClientGoneError(f"the client went away before its {what} ran; dropped")
            raise RenderTimeoutError(
                f"no answer from the GL thread within {timeout:g} s (queue depth {self.queue_depth}); "
                "lower the quality or the image size, or raise GARMENT_RENDER_REQUEST_TIMEOUT_S")
        value = result.result()
        return JobResult(value, job.queue_ms, (job.finished - job.started) * 1e3)

    # -- the GL thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            renderer = Renderer()
            cache = PEMCache(renderer.gl, self.settings.pem_cache_bytes, self.settings.pem_cache_dir,
                             name="pem-sets", disk_max_bytes=self.settings.pem_cache_disk_bytes)
        except Exception as exc:  # GLContextError, or an unwritable cache dir
            self.startup_error = exc
            self._ready.set()
            return
        self._gl = GLResources(renderer, cache)
        self.gl_info = renderer.gl.info()
        self.normals_on_gpu = renderer.normals == "gpu"
        self._ready.set()
        try:
            new_first = True
            while True:
                # Turns alternate between a job waiting to start and the next step of one in steps.
                if self._stepping and (not new_first or self._queue.empty()):
                    job, new_first = self._stepping.popleft(), True
                else:
                    job, new_first = self._queue.get(), False
                if job is None:
                    while self._stepping:   # shutting down: the jobs in steps finish (a batch is answered whole)
                        self._turn(self._stepping.popleft())
                    break
                self._turn(job)
        finally:
            for fn in self._cleanup:
                try:
                    fn(self._gl)
                except Exception:  # pragma: no cover
                    log.exception("cleanup on the GL thread failed")
            cache.clear()
            self._gl.release_backgrounds()
            renderer.release()
            self._gl = None

    def _turn(self, job: Job) -> None:
        """Run `job` (or its next step) on the GL thread; a job in steps that has more goes back in line."""
        if job.steps is None:
            if not job.future.set_running_or_notify_cancel():
                return  # timed out, or its client left, while queued
            job.started = time.perf_counter()
        t0 = time.perf_counter()
        self._running, self._running_since = job, job.started
        self._gl.stop_requested = job.stop.is_set
        done, result = True, None
        try:
            if job.stop.is_set():
                raise JobStoppedError(f"{job.what} stopped: its request is over")
            if job.steps is None:
                result = job.fn(self._gl)
                if inspect.isgenerator(result):
                    job.steps, result = result, None
            if job.steps is not None:
                try:
                    next(job.steps)
                    done = False
                except StopIteration as end:
                    result = end.value
        except BaseException as exc:  # noqa: BLE001 - every failure goes back to its request
            if job.steps is not None:
                job.steps.close()
            job.finished = time.perf_counter()
            if isinstance(exc, (JobStoppedError, RenderStoppedError)):
                self.stats.jobs_stopped += 1
            else:
                self.stats.jobs_failed += 1
            job.future.set_exception(exc)
        else:
            if done:
                job.finished = time.perf_counter()
                self.stats.jobs_done += 1
                job.future.set_result(result)
            else:
                self._stepping.append(job)
        finally:
            self._running, self._running_since = None, None
            self._gl.stop_requested = NEVER_STOP
        run_ms = (time.perf_counter() - t0) * 1e3
        self.stats.busy_ms_total += run_ms
        ema = self.stats.run_ms_ema
        self.stats.run_ms_ema = run_ms if ema == 0.0 else 0.8 * ema + 0.2 * run_ms

