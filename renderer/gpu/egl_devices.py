"""EGL devices, and which one is a given GPU.

moderngl's `device_index` is a position in `eglQueryDevicesEXT`'s list, and that list's order is
EGL's own: on a machine with several NVIDIA GPUs it need not be CUDA's (or nvidia-smi's, or Ray's),
and CUDA_VISIBLE_DEVICES hides GPUs from CUDA but not from EGL. So a process told to render on one
GPU (a Ray replica given GPU 3) finds its EGL device by asking each device which CUDA device it is
(EGL_NV_device_cuda's EGL_CUDA_DEVICE_NV), not by taking the GPU's number as an index.

Read through ctypes from the same libEGL (glvnd) that moderngl's context is created with, so the
indices are the ones moderngl uses.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from dataclasses import dataclass
from functools import lru_cache

from ..errors import GLContextError

EGL_EXTENSIONS = 0x3055
EGL_DRM_DEVICE_FILE_EXT = 0x3233
EGL_CUDA_DEVICE_NV = 0x323A
EGL_DRM_RENDER_NODE_FILE_EXT = 0x3377
MAX_DEVICES = 64


@dataclass(frozen=True)
class EGLDevice:
    index: int                  # moderngl's device_index
    extensions: tuple[str, ...]
    cuda_device: int | None     # the CUDA ordinal EGL_NV_device_cuda reports (in this process's numbering)
    drm_node: str | None        # /dev/dri/renderD* or card*, where the driver says

    @property
    def kind(self) -> str:
        if "EGL_NV_device_cuda" in self.extensions:
            return "nvidia"
        if "EGL_MESA_device_software" in self.extensions:
            return "software"
        return "other"

    def describe(self) -> str:
        cuda = f", CUDA device {self.cuda_device}" if self.cuda_device is not None else ""
        node = f", {self.drm_node}" if self.drm_node else ""
        return f"EGL device {self.index} ({self.kind}{cuda}{node})"


@lru_cache(maxsize=1)
def _egl():
    name = ctypes.util.find_library("EGL") or "libEGL.so.1"
    try:
        lib = ctypes.CDLL(name)
    except OSError as exc:
        raise GLContextError(f"could not load libEGL ({name}): {exc}; install libegl1 (scripts/setup.sh)") from exc
    lib.eglGetProcAddress.restype = ctypes.c_void_p
    lib.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    lib.eglQueryString.restype = ctypes.c_char_p
    lib.eglQueryString.argtypes = [ctypes.c_void_p, ctypes.c_int]
    client = (lib.eglQueryString(None, EGL_EXTENSIONS) or b"").decode().split()
    if "EGL_EXT_device_enumeration" not in client and "EGL_EXT_device_base" not in client:
        raise GLContextError("this libEGL cannot list its devices (no EGL_EXT_device_enumeration)")

    def proc(fname: str, restype, *argtypes):
        address = lib.eglGetProcAddress(fname.encode())
        if not address:
            raise GLContextError(f"libEGL has no {fname}")
        return ctypes.CFUNCTYPE(restype, *argtypes)(address)

    query_devices = proc("eglQueryDevicesEXT", ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                         ctypes.POINTER(ctypes.c_int))
    query_string = proc("eglQueryDeviceStringEXT", ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)
    query_attrib = proc("eglQueryDeviceAttribEXT", ctypes.c_uint, ctypes.c_void_p, ctypes.c_int,
                        ctypes.POINTER(ctypes.c_ssize_t))
    return query_devices, query_string, query_attrib


def egl_devices() -> list[EGLDevice]:
    """Every EGL device in moderngl's order (what `garment-render devices` prints)."""
    query_devices, query_string, query_attrib = _egl()
    handles = (ctypes.c_void_p * MAX_DEVICES)()
    count = ctypes.c_int(0)
    if not query_devices(MAX_DEVICES, handles, ctypes.byref(count)):
        raise GLContextError("eglQueryDevicesEXT failed")
    out = []
    for i in range(count.value):
        extensions = tuple((query_string(handles[i], EGL_EXTENSIONS) or b"").decode().split())
        cuda = None
        if "EGL_NV_device_cuda" in extensions:
            value = ctypes.c_ssize_t(-1)
            if query_attrib(handles[i], EGL_CUDA_DEVICE_NV, ctypes.byref(value)) and value.value >= 0:
                cuda = int(value.value)
        node = None
        for ext, name in (("EGL_EXT_device_drm_render_node", EGL_DRM_RENDER_NODE_FILE_EXT),
                          ("EGL_EXT_device_drm", EGL_DRM_DEVICE_FILE_EXT)):
            if ext in extensions and node is None:
                raw = query_string(handles[i], name)
                node = raw.decode() if raw else None
        out.append(EGLDevice(i, extensions, cuda, node))
    return out


_ADVICE = ("Name the EGL device directly with GARMENT_RENDER_EGL_DEVICE (an index from `garment-render devices`), "
           "or, on an NVIDIA host, check that the driver's EGL vendor file (10_nvidia.json) is installed.")


def cuda_visible() -> list[str] | None:
    """CUDA_VISIBLE_DEVICES as a list, or None when it is not set."""
    raw = os.environ.get("CUDA_VISIBLE_DEVICES")
    if raw is None:
        return None
    return [s.strip() for s in raw.split(",") if s.strip()]


def egl_index_for_gpu(gpu: int, devices: list[EGLDevice], visible: list[str] | None) -> tuple[int, str]:
    """(moderngl device_index, how it was found) for the GPU numbered `gpu` the way CUDA_VISIBLE_DEVICES
    and Ray number them (a physical GPU id).

    In this process CUDA sees that GPU as its position in CUDA_VISIBLE_DEVICES (Ray sets it to the
    replica's GPUs), and EGL_CUDA_DEVICE_NV reports that ordinal. A driver that reports more CUDA
    devices than are visible numbers them without the mask, so the physical id is matched instead.
    Where no device reports a CUDA ordinal (Mesa, or an EGL without EGL_NV_device_cuda) the GPU's
    number is taken as the EGL index, as a single-vendor machine lists its GPUs in order."""
    reporting = {d.cuda_device: d for d in devices if d.cuda_device is not None}
    if not reporting:
        if not 0 <= gpu < len(devices):
            raise GLContextError(f"GPU {gpu} was asked for, but EGL lists {len(devices)} device(s) and none "
                                 f"reports a CUDA device: {'; '.join(d.describe() for d in devices) or 'none'}. "
                                 f"{_ADVICE}")
        return gpu, "by index: no EGL device reports a CUDA device (EGL_NV_device_cuda)"
    ordinal, numbering = gpu, "physical"
    if visible is not None and str(gpu) in visible and len(reporting) <= len(visible):
        ordinal, numbering = visible.index(str(gpu)), "CUDA_VISIBLE_DEVICES"
    if ordinal not in reporting:
        raise GLContextError(
            f"GPU {gpu} (CUDA device {ordinal}, {numbering} numbering) matches no EGL device: "
            f"{'; '.join(d.describe() for d in devices)}; CUDA_VISIBLE_DEVICES={os.environ.get('CUDA_VISIBLE_DEVICES')!r}. "
            f"{_ADVICE}")
    return reporting[ordinal].index, f"CUDA device {ordinal} ({numbering} numbering) by EGL_NV_device_cuda"
