"""The one place that creates OpenGL contexts, and the thread check that guards them.

A `GLContext` owns a headless moderngl context on EGL (Mesa llvmpipe on a CPU machine, the
vendor's driver on a GPU machine; the code path is the same). GL is used from the thread that
created the context only: every public entry point of the renderer calls `check_thread()`.
Scale by processes, not threads.
"""

from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import moderngl

from ..errors import GLContextError
from . import rawgl
from .egl_devices import cuda_visible, egl_devices, egl_index_for_gpu


@dataclass
class StageTimer:
    """Per-stage timings of one frame: wall clock after `ctx.finish()` and, where the driver's timer
    queries mean something (not on llvmpipe, see GL-NOTES), GPU time from GL_TIME_ELAPSED queries."""

    wall_ms: dict[str, float] = field(default_factory=dict)
    gpu_ms: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"wall_ms": dict(self.wall_ms), "gpu_ms": dict(self.gpu_ms),
                "total_wall_ms": float(sum(self.wall_ms.values()))}


def _env_index(name: str) -> int | None:
    """A device number from the environment (None when unset or empty)."""
    raw = os.environ.get(name, "").strip()
    if not raw:
        return None
    try:
        return int(raw)
    except ValueError:
        raise GLContextError(f"{name} must be a whole number (GARMENT_RENDER_EGL_DEVICE: an EGL device index as "
                             "`garment-render devices` lists them; GARMENT_RENDER_GPU: a GPU as CUDA_VISIBLE_DEVICES "
                             f"numbers it), got {raw!r}") from None


class GLContext:
    """Owner of one headless OpenGL 4.5 core context; not thread-safe by design (see module doc)."""

    def __init__(self, backend: str | None = "egl", device_index: int | None = None, gpu: int | None = None):
        """`device_index`: moderngl's EGL device index (or GARMENT_RENDER_EGL_DEVICE); else `gpu`
        (or GARMENT_RENDER_GPU): a GPU numbered as CUDA_VISIBLE_DEVICES and Ray number them, whose EGL
        device is found by its CUDA ordinal (egl_devices.py); else EGL's first device."""
        t0 = time.perf_counter()
        kwargs = {"require": 450}
        if backend:
            kwargs["backend"] = backend
        self.device_choice = "EGL's first device"
        if device_index is None:
            device_index = _env_index("GARMENT_RENDER_EGL_DEVICE")
        if device_index is not None:
            self.device_choice = f"EGL device {device_index}, as asked"
        else:
            if gpu is None:
                gpu = _env_index("GARMENT_RENDER_GPU")
            if gpu is not None and backend == "egl":
                device_index, how = egl_index_for_gpu(gpu, egl_devices(), cuda_visible())
                self.device_choice = f"EGL device {device_index} for GPU {gpu}: {how}"
        self.device_index = device_index
        if device_index is not None:
            kwargs["device_index"] = device_index
        try:
            self.ctx = moderngl.create_standalone_context(**kwargs)
        except Exception as exc:  # moderngl raises plain Exception subclasses here
            raise GLContextError(
                f"could not create an OpenGL 4.5 context through {backend or 'the default backend'}: {exc}. "
                "On Debian/Ubuntu install Mesa's EGL (libegl1 libegl-mesa0 libgl1-mesa-dri), "
                "e.g. by running scripts/setup.sh; on NVIDIA hosts the driver's EGL vendor file must be present."
            ) from exc
        self.create_ms = (time.perf_counter() - t0) * 1e3
        self._thread = threading.get_ident()
        self.gl = rawgl.RawGL()
        self.renderer_name = self.ctx.info.get("GL_RENDERER", "?")
        self.version = self.ctx.info.get("GL_VERSION", "?")
        # Timer queries report nonsense on llvmpipe (GL-NOTES); only trust them on real GPUs.
        self.gpu_timers_meaningful = "llvmpipe" not in self.renderer_name.lower()
        self._released = False
        self._cached: dict = {}

    # -- threading --------------------------------------------------------------------------
    def check_thread(self) -> None:
        if self._released:
            raise GLContextError("this GL context has been released; create a new Renderer")
        if threading.get_ident() != self._thread:
            raise GLContextError(
                "the GL context was used from a thread other than the one that created it; "
                "OpenGL contexts are bound to one thread: submit work to the render thread instead"
            )
        # Make this context current (about a microsecond): another context created on this thread
        # would otherwise receive our raw GL calls (cube-map arrays go through eglGetProcAddress).
        self.ctx.__enter__()

    # -- timing -----------------------------------------------------------------------------
    @contextmanager
    def stage(self, timer: StageTimer | None, name: str):
        """Time a stage: wall clock including a `finish()` so that queued GL work is counted."""
        if timer is None:
            yield
            return
        query = self.ctx.query(time=True) if self.gpu_timers_meaningful else None
        t0 = time.perf_counter()
        if query is not None:
            with query:
                yield
        else:
            yield
        self.ctx.finish()
        timer.wall_ms[name] = timer.wall_ms.get(name, 0.0) + (time.perf_counter() - t0) * 1e3
        if query is not None:
            timer.gpu_ms[name] = timer.gpu_ms.get(name, 0.0) + query.elapsed / 1e6

    def info(self) -> dict:
        return {"renderer": self.renderer_name, "version": self.version, "device": self.device_choice,
                "context_create_ms": round(self.create_ms, 2)}

    def cached(self, key: tuple, make):
        """A GL object made once per context by `make()` and kept until the context is released
        (the compute programs every PEM build uses, instead of compiling them anew for each build)."""
        self.check_thread()
        if key not in self._cached:
            self._cached[key] = make()
        return self._cached[key]

    def release(self) -> None:
        if not self._released:
            self.check_thread()
            for obj in self._cached.values():
                obj.release()
            self._cached.clear()
            self.ctx.release()
            self._released = True
