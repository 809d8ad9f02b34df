"""What a request of several images will cost, judged before its body is decoded or its job queued:
the host memory it holds at once and the GL thread's time. Either over its limit is a 413 that names
the limit (GARMENT_RENDER_MAX_REQUEST_BYTES, GARMENT_RENDER_MAX_REQUEST_S), the estimate and how it
was made.

Memory, bytes a pixel of each image (the renderer's readback is float32 RGBA: `READBACK_BPP`):
- views: every image's readback, which the encoding lets go one by one, making an 8-bit tile of each
  (a sheet: the tiles, the sheet of them, its labelled copy and its PNG's rows, 4 bytes a pixel each
  at most) or a PNG (a zip: at most 4): `SHEET_BPP`, `ZIP_VIEWS_BPP`;
- a batch: `BATCH_FRAMES_AHEAD` frames at a time, each its readback and the float temporaries its
  tone mapping makes (`ENCODING_BPP`), and every frame's encoded image kept for the answer, held twice
  in a zip (the archive and its bytes), in JSON three times over as base64 (the frames' payloads, the
  JSON text and its bytes).
  An encoded image's size is the scene's own: `ENCODED_MARGIN` x the median of its latest frames'
  bytes a pixel in that format; before it has any, the most it could be (an uncompressed PNG's 4 bytes
  a pixel, an EXR's 16).
Time: the images x the GL time of one image of this scene (the median of its latest frames), else
of this process's frames by their pixels, else GARMENT_RENDER_FRAME_NS_PER_PIXEL before it has timed
any (the worker's steps let other scenes' frames through meanwhile: a long request is bounded, not
starving).
"""

from __future__ import annotations

import statistics
import threading
from collections import deque
from dataclasses import dataclass

from .errors import PayloadTooLargeError
from .registry import SceneRecord
from .settings import ServiceSettings

READBACK_BPP = 16          # float32 RGBA
ENCODING_BPP = 32          # a frame's tone mapping: float32 RGB temporaries, measured (scripts/bench_service_bounds.py)
# The passes beside a frame (output.aovs): the geometry targets read back (four float32 RGBA) and at most
# eight float32 channels kept.
AOV_BPP = 4 * 16 + 8 * 4
SHEET_BPP = READBACK_BPP + 4 * 4
ZIP_VIEWS_BPP = READBACK_BPP + 4
ENCODED_BPP = {"png": 4, "exr": 16}   # the most an encoded image takes, a pixel
ENCODED_MARGIN = 1.25                  # over a scene's measured size: frames of a sequence differ a little
KEPT_COPIES = {"zip": 2, "json": 3 * 4 / 3}


@dataclass(frozen=True)
class RequestCost:
    what: str            # "8 views x 1 colourway of 4096 x 4096"
    images: int
    held_bytes: int      # host memory held at once, at most
    gl_s: float          # the GL thread's time, estimated
    rate_from: str       # where the time a pixel came from

    def header(self) -> str:
        """What the answer says of the estimate it was admitted on (`X-Request-Estimate`)."""
        return f"held_bytes={self.held_bytes}; gl_s={self.gl_s:.3f}"

    def check(self, settings: ServiceSettings) -> None:
        """413 naming the limit when this request is over one, before any of its work."""
        if self.held_bytes > settings.max_request_bytes:
            raise PayloadTooLargeError(
                f"{self.what} would hold up to {self.held_bytes / 2**20:.0f} MiB at once, over the limit "
                f"{settings.max_request_bytes / 2**20:.0f} MiB (GARMENT_RENDER_MAX_REQUEST_BYTES); send fewer images "
                "or smaller ones")
        if self.gl_s > settings.max_request_s:
            raise PayloadTooLargeError(
                f"{self.what} would take the render thread about {self.gl_s:.0f} s ({self.images} images at "
                f"{self.rate_from}), over the limit {settings.max_request_s:g} s (GARMENT_RENDER_MAX_REQUEST_S); "
                "send fewer images or smaller ones")


class FrameRates:
    """The GL time of this process's frames a pixel, the median of the latest `KEPT` (ns), for scenes
    not timed yet; each scene keeps its own (`SceneRecord.gl_ms_recent`). Medians, so that a first
    frame's one-time work (its PEM set's tables, shaders compiled) does not count as every frame's."""

    KEPT = 16

    def __init__(self) -> None:
        self._ns_per_pixel: deque[float] = deque(maxlen=self.KEPT)
        self._lock = threading.Lock()

    def note(self, scene: SceneRecord, run_ms: float, images: int) -> None:
        """A job of `images` images of `scene` took `run_ms` on the GL thread."""
        if images < 1 or run_ms <= 0:
            return
        per_image = run_ms / images
        with self._lock:
            scene.gl_ms_recent.append(per_image)
            self._ns_per_pixel.append(per_image * 1e6 / _pixels(scene))

    def note_encoded(self, scene: SceneRecord, nbytes: int, kind: str) -> None:
        """A frame of `scene` encoded as `kind` ("png" or "exr") took `nbytes`."""
        with self._lock:
            scene.encoded_bpp_recent.setdefault(kind, deque(maxlen=8)).append(nbytes / _pixels(scene))

    def encoded_bpp(self, scene: SceneRecord, kind: str) -> float:
        """The bytes a pixel an encoded frame of `scene` is estimated to take (module doc)."""
        with self._lock:
            seen = list(scene.encoded_bpp_recent.get(kind, ()))
        return min(ENCODED_BPP[kind], ENCODED_MARGIN * statistics.median(seen)) if seen else ENCODED_BPP[kind]

    def image_s(self, scene: SceneRecord, settings: ServiceSettings) -> tuple[float, str]:
        """The GL seconds one image of `scene` takes and where that figure came from."""
        with self._lock:
            own, everyone = list(scene.gl_ms_recent), list(self._ns_per_pixel)
        if own:
            ms = statistics.median(own)
            return ms / 1e3, f"{ms:.0f} ms each, this scene's frames so far"
        if everyone:
            ns = statistics.median(everyone)
            s = ns * _pixels(scene) / 1e9
            return s, f"{s * 1e3:.0f} ms each, from this process's frames ({ns:.0f} ns a pixel)"
        s = settings.frame_ns_per_pixel * _pixels(scene) / 1e9
        return s, (f"{s * 1e3:.0f} ms each, assumed before any frame was timed (GARMENT_RENDER_FRAME_NS_PER_PIXEL "
                   f"= {settings.frame_ns_per_pixel:g}; a frame sent first gives a measured estimate)")


def _pixels(scene: SceneRecord) -> int:
    return scene.frame_settings.width * scene.frame_settings.height


def _size(scene: SceneRecord) -> str:
    return f"{scene.frame_settings.width} x {scene.frame_settings.height}"


def views_cost(scene: SceneRecord, n_views: int, n_colourways: int, sheet: bool, rates: FrameRates,
               settings: ServiceSettings) -> RequestCost:
    images = n_views * n_colourways
    each_s, rate_from = rates.image_s(scene, settings)
    return RequestCost(f"{n_views} views x {n_colourways} colourways of {_size(scene)}", images,
                       images * _pixels(scene) * (SHEET_BPP if sheet else ZIP_VIEWS_BPP), images * each_s, rate_from)


def batch_cost(scene: SceneRecord, n_frames: int, answer: str, image: str, frames_ahead: int, rates: FrameRates,
               settings: ServiceSettings) -> RequestCost:
    """answer: "zip" or "json"; image: "png" or "exr"."""
    px = _pixels(scene)
    kept = n_frames * px * rates.encoded_bpp(scene, image) * KEPT_COPIES[answer]
    aovs = AOV_BPP if scene.frame_settings.aovs else 0
    in_flight = min(frames_ahead, n_frames) * px * (READBACK_BPP + ENCODING_BPP + aovs)
    each_s, rate_from = rates.image_s(scene, settings)
    return RequestCost(f"a batch of {n_frames} frames of {_size(scene)}", n_frames, int(kept + in_flight),
                       n_frames * each_s, rate_from)
