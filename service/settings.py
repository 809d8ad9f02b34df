"""Service settings, read from the environment (prefix GARMENT_RENDER_) by pydantic-settings.

The app factory takes a `ServiceSettings` and stores it on the app; handlers get it injected
(`deps.SettingsDep`). There is no module-level instance: tests build apps with their own settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from renderer.presets import PRESET_NAMES


class ServiceSettings(BaseSettings):
    """Every limit of the service. Sizes in bytes, times in seconds."""

    model_config = SettingsConfigDict(env_prefix="GARMENT_RENDER_", extra="ignore")

    host: str = Field("127.0.0.1", description="the address the service listens on")
    port: int = Field(8000, ge=0, le=65535, description="the port it listens on")

    # Request bodies (environment maps, mesh files, frames, batches, scene JSON): checked against the
    # Content-Length header and against the bytes actually streamed.
    max_upload_bytes: int = Field(256 << 20, ge=1024, description="largest request body (a map, a mesh file, a "
                                  "frame, a batch, a scene's JSON), judged on Content-Length and on what streams")
    max_vertices: int = Field(2_000_000, ge=3, description="per mesh")
    max_faces: int = Field(4_000_000, ge=1, description="per mesh")
    max_image_side: int = Field(4096, ge=16, le=8192, description="largest rendered width or height, pixels")
    max_shadow_map_bytes: int = Field(4 << 30, ge=1 << 20, description="largest shadow-map memory a scene's frame "
                                      "may allocate: its main and sharp maps' arrays as its light plan lays them out "
                                      "on the scene's PEM set (renderer.costs.frame_cost: 8 bytes a texel and shadow "
                                      "group, twice with a blur); judged when the scene is registered (a request no "
                                      "map could fit before its PEM set is built), never on an upload")
    max_env_pixels: int = Field(16 << 20, ge=64, description="largest uploaded environment map, width x height, "
                                "read from the file's header before it is decoded (16 Mi: a 4k lat-long map and "
                                "more; decoding one of 64 Mi took 20 s and 3.4 GB)")
    max_environment_bytes: int = Field(2 << 30, ge=1 << 20, description="memory the environment maps may keep "
                                       "together (each one's decoded source and cubes); an upload or a cube "
                                       "beyond it is refused (409) before it is decoded or made")
    max_batch_frames: int = Field(1000, ge=1, description="most frames in one POST .../frames/batch")
    max_views: int = Field(64, ge=1, le=1024, description="most images one POST .../frames/views renders: "
                           "views x colourways (each is a geometry pass, a lighting pass and an image)")
    max_request_bytes: int = Field(2 << 30, ge=1 << 20, description="host memory one request of several images (a "
                                   "batch, a frame's views) may hold at once, estimated from its images' count "
                                   "and size before its body is decoded (service/budgets.py); beyond it: 413")
    max_request_s: float = Field(300.0, gt=0, description="longest estimated render-thread time of one request of "
                                 "several images: their count x the measured time of one of the scene's (else "
                                 "of this process's frames by pixels, else frame_ns_per_pixel); beyond it: 413")
    frame_ns_per_pixel: float = Field(2000.0, gt=0, description="a frame's render-thread time a pixel, assumed for "
                                      "that estimate before this process has timed a frame (a CPU rasteriser's "
                                      "order; a GPU's is far less, and measured from its first frame)")
    max_scenes: int = Field(64, ge=1, description="scenes held by one process (idle ones give way, see below)")
    scene_idle_timeout_s: float = Field(600.0, gt=0, description="a scene with no frame nor lookup for this long "
                                        "is released when a new scene needs its slot (with a state directory it "
                                        "is restored on its next use; without one its id answers 404 saying so)")
    max_environments: int = Field(32, ge=1, description="environment maps held by one process")
    max_meshes: int = Field(32, ge=1, description="uploaded mesh files kept for scene registration")
    max_fabrics: int = Field(32, ge=1, description="U3M fabrics held by one process (POST /fabrics); beyond it: 409")
    max_fabric_pixels: int = Field(4 * 4096 * 4096, ge=64, description="pixels of one fabric's images together "
                                   "(each image once a use; one image at most this and 8192^2), read from their "
                                   "headers before any is decoded (renderer.u3m.U3MLimits); beyond it: 422")
    max_fabric_bytes: int = Field(1 << 30, ge=1 << 20, description="memory the fabrics may keep together (their "
                                  "decoded images, float32); an upload is judged before it is decoded at 12 bytes "
                                  "a pixel of its images' headers, and refused (409) where that would pass it")

    queue_size: int = Field(8, ge=1, description="jobs waiting for the GL thread; beyond it: 503 + Retry-After")
    request_timeout_s: float = Field(120.0, gt=0, description="wait for the GL thread (queue + render), then 504")
    ready_max_busy_s: float = Field(30.0, gt=0, description="/health/ready answers 503 while the GL thread has "
                                    "been on one job (a PEM build, a batch) longer than this, or the queue is "
                                    "full, so that a load balancer routes new work elsewhere")

    pem_cache_bytes: int = Field(1 << 30, ge=0, description="GPU memory of PEM sets kept resident (LRU); a set "
                                 "larger than this is refused before it is built")
    max_pem_build_bytes: int = Field(2 << 30, ge=1 << 20, description="most memory one PEM set's build may hold at "
                                     "once, GPU and host together (renderer.lighting.pem_plan.pem_cost), the copy for "
                                     "the disk cache included")
    max_pem_build_s: float = Field(30.0, gt=0, description="longest estimated build of one PEM set (its texels x "
                                   "lights x pem_build_ns_per_texel_light), during which no frame renders")
    pem_build_ns_per_texel_light: float = Field(
        150.0, gt=0, description="the PEM build's time per texel and light, for that estimate: measured 57-127 ns "
                                 "on 2-core llvmpipe for sets of 10^7 texel-lights and more; /stats reports the "
                                 "rate of this device's builds so far")
    pem_cache_dir: Path | None = Field(None, description="PEM sets persisted here; None: memory only")
    pem_cache_disk_bytes: int = Field(4 << 30, ge=0, description="bytes of PEM sets kept in pem_cache_dir "
                                                                  "(least recently used deleted first)")

    state_dir: Path | None = Field(
        None, description="environments and scenes kept here, so every worker process (and a restarted service) "
                          "can restore them by id; None: in the memory of the process that made them")

    token: SecretStr | None = Field(None, description="bearer token required on every endpoint but health")

    @field_validator("token")
    @classmethod
    def _empty_token_is_no_token(cls, v: SecretStr | None) -> SecretStr | None:
        # GARMENT_RENDER_TOKEN="" (compose passes an unset variable as empty) means no token, not a
        # required empty one that no client sends.
        return None if v is None or not v.get_secret_value() else v

    default_preset: Literal[PRESET_NAMES] = Field("balanced", description="the preset of a request that names none")
    png_compress_level: int = Field(1, ge=0, le=9, description="zlib level of served PNGs (1: ~3x faster than 6)")
    startup_timeout_s: float = Field(60.0, gt=0, description="wait for the GL context at startup")
    header_timeout_s: float = Field(10.0, gt=0, description="a connection that does not complete a request's "
                                    "line and headers this long after it opened (or after its last answer) is "
                                    "closed (service/protocol.py)")
    shutdown_timeout_s: float = Field(30.0, gt=0, description="on SIGTERM/SIGINT: new connections are refused and "
                                      "requests in flight get this long to finish before they are cut")
    log_format: Literal["text", "json"] = Field("text", description="log lines as text or one JSON object each; "
                                                "both carry the request id")


def reference_table() -> str:
    """docs/service-settings.md: every setting of the service, its variable, default and meaning."""
    lines = ["# Service settings", "",
             "Every limit and setting of the render service, read from the environment by pydantic-settings",
             "(`service/settings.py`; generated by `service.settings.reference_table()`, checked by",
             "tests/test_service_limits.py). Sizes in bytes, times in seconds.", "",
             "| variable | default | what it does |", "|---|---|---|"]
    for name, field in ServiceSettings.model_fields.items():
        default = field.default
        if isinstance(default, int) and not isinstance(default, bool) and default >= 1 << 20 and default % (1 << 20) == 0:
            shown = f"{default} ({default >> 20} MiB)" if default < 1 << 30 else f"{default} ({default >> 30} GiB)" \
                if default % (1 << 30) == 0 else f"{default} ({default >> 20} MiB)"
        else:
            shown = "none" if default is None else str(default).lower() if isinstance(default, bool) else str(default)
        lines.append(f"| `GARMENT_RENDER_{name.upper()}` | {shown} | {(field.description or '').replace('|', '/')} |")
    return "\n".join(lines) + "\n"
