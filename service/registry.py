"""What the service holds between requests: uploaded environment maps, uploaded mesh files and
registered scenes (uploaded fabrics: service/fabrics.py). Plain Python objects guarded by locks,
readable from any thread; the GPU side of a scene (`SceneRecord.gpu`) is only touched by jobs on the
GL thread."""

from __future__ import annotations

import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from renderer.camera import Camera
from renderer.costs import FrameCost
from renderer.envmap import EnvironmentMap, Layout, environment_from_array
from renderer.envmap.io import TexelReport, check_texels
from renderer.lighting.pem_plan import PEMSettings
from renderer.mesh import Mesh
from renderer.settings import FrameSettings
from renderer.shading.background import background_face_size

if TYPE_CHECKING:   # the GL side's type: the registry holds a scene, never makes one
    from renderer.scene import Scene

from .errors import ConflictError, NotFoundError

# -- environments --------------------------------------------------------------------------------


@dataclass
class PemInfo:
    """What the service knows of one PEM set of an environment (the set itself lives in the cache)."""

    key: str
    face_size: int
    settings: PEMSettings
    source: str  # where the first request found it: "built", "disk" or "memory"
    summary: dict
    directions: np.ndarray  # (N, 3) unit, towards the light, world Y-up
    energy_rgb: np.ndarray  # (N, 3)
    solid_angle_sr: np.ndarray  # (N,)
    labels: np.ndarray  # (6, F, F) region id per cube texel (for previews)
    created: float = field(default_factory=time.time)


@dataclass
class EnvironmentRecord:
    id: str
    name: str
    layout: Layout
    content_hash: str
    file_sha256: str
    source_shape: tuple
    texel_report: TexelReport | None
    repair: bool
    pixels: np.ndarray  # (H, W, 3) float32 as decoded (before repair), read-only: resampled per face size
    decode_ms: float
    created: float = field(default_factory=time.time)
    cubes: dict[int, np.ndarray] = field(default_factory=dict)
    pem_sets: dict[str, PemInfo] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _repaired: np.ndarray | None = field(default=None, repr=False)   # a lat-long's pixels repaired (background_source)

    # The store whose memory budget this record's cubes count against (set by EnvironmentStore.add).
    store: EnvironmentStore | None = field(default=None, repr=False)

    @property
    def nbytes(self) -> int:
        """The memory this map keeps: its decoded source, its repaired copy and every cube made of it."""
        repaired = self._repaired
        extra = repaired.nbytes if repaired is not None and repaired is not self.pixels else 0
        return int(self.pixels.nbytes + extra + sum(c.nbytes for c in list(self.cubes.values())))

    def cube(self, face_size: int) -> np.ndarray:
        """The cube map at `face_size` (resampled once, then kept, within the store's memory budget:
        ConflictError beyond it); call off the GL thread."""
        with self._lock:
            cube = self.cubes.get(face_size)
            if cube is None:
                if self.store is not None:
                    self.store.check_room(6 * face_size * face_size * 12, f"a {face_size}^2 cube of {self.id}")
                env = self._resample(face_size)
                cube = self.cubes[face_size] = env.cube
            return cube

    @property
    def background_face(self) -> int:
        """The face size of the cube another layout's background is drawn from (twice the source's density)."""
        return background_face_size(self.source_shape, self.layout)

    def background_source(self) -> np.ndarray:
        """What the background is drawn from (renderer.shading.background): a lat-long's pixels
        themselves (repaired as its cubes are), another layout's cube at background_face; made once,
        then kept. Call off the GL thread the first time."""
        if self.layout is not Layout.LATLONG:
            return self.cube(self.background_face)
        with self._lock:
            if self._repaired is None:
                repaired = check_texels(self.pixels, repair=self.repair, name=self.name)[0]
                if repaired is not self.pixels and self.store is not None:
                    self.store.check_room(repaired.nbytes, f"the repaired background of {self.id}")
                repaired.setflags(write=False)
                self._repaired = repaired
            return self._repaired

    def note_pem_set(self, key: str, face_size: int, settings: PEMSettings, pems, source: str) -> None:
        """Remember what the service shows of a PEM set (on the GL thread, where `pems` may be read)."""
        if key in self.pem_sets:
            return
        r = pems.regions
        self.pem_sets.setdefault(key, PemInfo(
            key=key, face_size=face_size, settings=settings, source=source, summary=pems.summary(),
            directions=np.array(r.directions), energy_rgb=np.array(r.energy_rgb),
            solid_angle_sr=np.array(r.solid_angle_sr), labels=np.array(r.labels)))

    def _resample(self, face_size: int) -> EnvironmentMap:
        env = environment_from_array(self.pixels, self.layout, face_size, name=self.name, repair=self.repair)
        if env.content_hash != self.content_hash:  # pragma: no cover - the pixels are read-only
            raise RuntimeError("environment pixels changed after upload")
        return env


class EnvironmentStore:
    """The environment maps of this process, at most `max_environments` of them keeping at most
    `max_bytes` of memory together (their decoded sources and cubes, `EnvironmentRecord.nbytes`)."""

    def __init__(self, max_environments: int, max_bytes: int | None = None):
        self.max_environments = max_environments
        self.max_bytes = max_bytes
        self._by_id: OrderedDict[str, EnvironmentRecord] = OrderedDict()
        self._by_file: dict[tuple, str] = {}
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        return sum(r.nbytes for r in self.list())

    def check_room(self, more_bytes: int, what: str) -> None:
        """ConflictError (409) when `more_bytes` more would pass the memory budget, before they are made."""
        if self.max_bytes is None:
            return
        held = self.nbytes
        if held + more_bytes > self.max_bytes:
            raise ConflictError(
                f"{what} needs {more_bytes / 2**20:.0f} MiB, and the environment maps held take "
                f"{held / 2**20:.0f} of the {self.max_bytes / 2**20:.0f} MiB they may keep "
                "(GARMENT_RENDER_MAX_ENVIRONMENT_BYTES); delete one with DELETE /environments/{id}, or send a smaller map")

    def find_file(self, file_sha256: str, layout: str, repair: bool) -> EnvironmentRecord | None:
        with self._lock:
            env_id = self._by_file.get((file_sha256, layout, repair))
            return self._by_id.get(env_id) if env_id else None

    def add(self, record: EnvironmentRecord, requested_layout: str) -> tuple[EnvironmentRecord, bool]:
        """Register a decoded map; an identical image (same pixels and layout) keeps its first record.
        Returns (record, created)."""
        with self._lock:
            existing = self._by_id.get(record.id)
            if existing is None and len(self._by_id) >= self.max_environments:
                raise ConflictError(
                    f"the service holds {self.max_environments} environment maps already (the limit, "
                    "GARMENT_RENDER_MAX_ENVIRONMENTS); delete one with DELETE /environments/{id}")
            self._by_file[(record.file_sha256, requested_layout, record.repair)] = record.id
            if existing is not None:
                return existing, False
            self._by_id[record.id] = record
            record.store = self
            return record, True

    def get(self, env_id: str) -> EnvironmentRecord:
        with self._lock:
            rec = self._by_id.get(env_id)
        if rec is None:
            raise NotFoundError(f"unknown environment id {env_id!r}; upload the map with POST /environments "
                                "(ids are listed by GET /environments)")
        return rec

    def list(self) -> list[EnvironmentRecord]:
        with self._lock:
            return list(self._by_id.values())

    def remove(self, env_id: str) -> EnvironmentRecord:
        with self._lock:
            rec = self._by_id.pop(env_id, None)
            if rec is None:
                raise NotFoundError(f"unknown environment id {env_id!r}")
            for k in [k for k, v in self._by_file.items() if v == env_id]:
                del self._by_file[k]
            return rec

    def __len__(self) -> int:
        return len(self._by_id)


# -- uploaded mesh files -------------------------------------------------------------------------


@dataclass
class MeshRecord:
    id: str
    mesh: Mesh
    file_sha256: str
    format: str
    up: str
    scale: float
    created: float = field(default_factory=time.time)
    material: object | None = None   # a glTF/GLB file's own Material (renderer/shading/gltf.py)
    material_notes: str | None = None


class MeshStore:
    """Uploaded mesh files, kept until a scene is made from them (bounded; the oldest goes first)."""

    def __init__(self, max_meshes: int):
        self.max_meshes = max_meshes
        self._by_id: OrderedDict[str, MeshRecord] = OrderedDict()
        self._lock = threading.Lock()

    def add(self, record: MeshRecord) -> MeshRecord:
        with self._lock:
            existing = self._by_id.get(record.id)
            if existing is not None:
                self._by_id.move_to_end(record.id)
                return existing
            self._by_id[record.id] = record
            while len(self._by_id) > self.max_meshes:
                self._by_id.popitem(last=False)
            return record

    def get(self, mesh_id: str) -> MeshRecord:
        with self._lock:
            rec = self._by_id.get(mesh_id)
        if rec is None:
            raise NotFoundError(f"unknown mesh id {mesh_id!r}; upload the file with POST /meshes first "
                                f"(at most {self.max_meshes} uploads are kept)")
        return rec

    def remove(self, mesh_id: str) -> None:
        with self._lock:
            if self._by_id.pop(mesh_id, None) is None:
                raise NotFoundError(f"unknown mesh id {mesh_id!r}")

    def list(self) -> list[MeshRecord]:
        with self._lock:
            return list(self._by_id.values())


# -- scenes --------------------------------------------------------------------------------------


@dataclass
class SceneMeshInfo:
    role: str  # "garment", "body" or "floor"
    name: str
    n_vertices: int
    n_faces: int
    has_uvs: bool
    faces: np.ndarray  # (F, 3) int32, for normals computed off the GL thread


@dataclass
class LatestFrame:
    """The last frame of a scene, kept for the viewer (GET /scenes/{id}/latest.png, /view).

    image: the linear render, float32 (H, W, 4), not copied (a frame's array is not written after
    it is rendered), or None where its PNG is all there is (a sheet of views); png: its PNG when the
    frame was asked for as PNG, else made on the first request for it and kept, so a frame is encoded
    for the viewer at most once, and only when someone looks. size: (height, width)."""

    frame_index: int
    sequence: int
    image: np.ndarray | None
    timings_ms: dict
    exposure_ev: float | None
    received: float = field(default_factory=time.time)
    png: bytes | None = None
    size: tuple[int, int] = (0, 0)

    def __post_init__(self):
        if self.image is not None:
            self.size = tuple(self.image.shape[:2])
        elif self.png is None:
            raise ValueError("a latest frame needs its image or its PNG")


@dataclass
class SceneRecord:
    """A registered scene. `gpu` is created, used and released on the GL thread only."""

    id: str
    name: str
    environment: EnvironmentRecord
    face_size: int
    pem_settings: PEMSettings
    frame_settings: FrameSettings
    camera: Camera
    up: str
    meshes: list[SceneMeshInfo]
    quality: dict
    output: dict
    pem_key: str = ""
    # What one frame allocates (renderer.costs.frame_cost on the PEM set's regions), known at registration.
    frame_cost: FrameCost | None = None
    gpu: Scene | None = None
    released: bool = False
    frames_rendered: int = 0
    # The GL time (ms) of one image of this scene in its latest frames (budgets.FrameRates).
    gl_ms_recent: deque = field(default_factory=lambda: deque(maxlen=8), repr=False)
    # The bytes a pixel of its latest encoded frames, by format ("png", "exr"; budgets.FrameRates).
    encoded_bpp_recent: dict = field(default_factory=dict, repr=False)
    # The count of every process that renders this scene (StateDir.count_frames), where there is one.
    frame_counter: Callable[[int], int] | None = field(default=None, repr=False)
    created: float = field(default_factory=time.time)
    last_used: float = field(default_factory=time.monotonic)   # its last frame or lookup (monotonic s)
    latest: LatestFrame | None = None
    fabric_ids: list[str] = field(default_factory=list)        # the fabrics its meshes and colourways name
    material_notes: list[str] = field(default_factory=list)    # what of them the renderer does not carry
    _arrivals: deque = field(default_factory=lambda: deque(maxlen=30), repr=False)  # time.monotonic() of frames
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def release_gpu(self) -> None:
        """Free the scene's GPU objects (on the GL thread only; again is a no-op)."""
        if self.gpu is not None:
            self.gpu.release()
            self.gpu = None

    def count_frames(self, n: int = 1) -> int:
        """The scene's frame sequence after `n` more frames: this process's count, or every process's
        where the scene has a shared counter (replicas behind Ray, uvicorn's workers)."""
        with self._lock:
            self.frames_rendered = (self.frames_rendered + n if self.frame_counter is None
                                    else self.frame_counter(n))
            return self.frames_rendered

    def keep_latest(self, frame: LatestFrame) -> None:
        """Keep `frame` unless a later one (by the service's sequence) is kept already: with several
        clients, answers can finish out of order."""
        with self._lock:
            self._arrivals.append(time.monotonic())
            if self.latest is None or frame.sequence > self.latest.sequence:
                self.latest = frame

    def frame_rate_hz(self) -> float | None:
        """Frames per second over the last (up to) 30 frames; None before two frames."""
        with self._lock:
            if len(self._arrivals) < 2 or self._arrivals[-1] <= self._arrivals[0]:
                return None
            return (len(self._arrivals) - 1) / (self._arrivals[-1] - self._arrivals[0])

    def mesh(self, role: str) -> SceneMeshInfo | None:
        return next((m for m in self.meshes if m.role == role), None)


class SceneStore:
    # Ids of scenes released for idleness remembered (the most recent), so that their 404 says so.
    EXPIRED_REMEMBERED = 4096

    def __init__(self, max_scenes: int):
        self.max_scenes = max_scenes
        self._by_id: dict[str, SceneRecord] = {}
        self._expired: OrderedDict[str, float] = OrderedDict()
        self._lock = threading.Lock()

    def idle(self, idle_s: float) -> list[SceneRecord]:
        """The scenes unused (no frame, no lookup) for more than `idle_s` seconds, longest idle first."""
        now = time.monotonic()
        with self._lock:
            return sorted((r for r in self._by_id.values() if now - r.last_used > idle_s), key=lambda r: r.last_used)

    def note_expired(self, scene_id: str, idle_s: float) -> None:
        with self._lock:
            self._expired[scene_id] = idle_s
            while len(self._expired) > self.EXPIRED_REMEMBERED:
                self._expired.popitem(last=False)

    @staticmethod
    def new_id() -> str:
        return "scn_" + secrets.token_hex(8)

    def check_room(self) -> None:
        with self._lock:
            if len(self._by_id) >= self.max_scenes:
                raise ConflictError(
                    f"the service holds {self.max_scenes} scenes already (the limit, GARMENT_RENDER_MAX_SCENES); "
                    "delete one with DELETE /scenes/{id}")

    def add(self, record: SceneRecord) -> None:
        with self._lock:
            self._by_id[record.id] = record

    def get(self, scene_id: str) -> SceneRecord:
        with self._lock:
            rec = self._by_id.get(scene_id)
        if rec is None or rec.released:
            idle = self._expired.get(scene_id)
            if idle is not None:
                raise NotFoundError(f"scene {scene_id!r} was released after {idle:.0f} s without a frame "
                                    "(GARMENT_RENDER_SCENE_IDLE_TIMEOUT_S); register it again with POST /scenes")
            raise NotFoundError(f"unknown scene id {scene_id!r}; register the scene with POST /scenes "
                                "(without a state directory, scenes do not survive a restart of the service)")
        rec.last_used = time.monotonic()
        return rec

    def pop(self, scene_id: str) -> SceneRecord:
        with self._lock:
            rec = self._by_id.pop(scene_id, None)
        if rec is None:
            raise NotFoundError(f"unknown scene id {scene_id!r}")
        return rec

    def list(self) -> list[SceneRecord]:
        with self._lock:
            return list(self._by_id.values())

    def using_environment(self, env_id: str) -> list[str]:
        with self._lock:
            return [s.id for s in self._by_id.values() if s.environment.id == env_id]

    def using_fabric(self, fabric_id: str) -> list[str]:
        with self._lock:
            return [s.id for s in self._by_id.values() if fabric_id in s.fabric_ids]

    def __len__(self) -> int:
        return len(self._by_id)
