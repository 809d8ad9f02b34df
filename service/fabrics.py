"""U3M fabrics uploaded once (POST /fabrics) and named by id from scenes and colourways.

An upload is read by `renderer.u3m.load_u3m` in a worker thread, within bounds the service's settings
give it before anything is decoded: the archive's size (GARMENT_RENDER_MAX_UPLOAD_BYTES), its images'
pixels together (GARMENT_RENDER_MAX_FABRIC_PIXELS) and what is left of the fabrics' memory budget
(GARMENT_RENDER_MAX_FABRIC_BYTES), read from the images' headers. The budget's share is reserved for
the read's duration, so that concurrent uploads cannot each take the same room. The same bytes give
the same id (`fab_` and their SHA-256), and cost a hash. With a state directory the bytes as uploaded
are kept there, and another process restores the fabric by id on first use. A scene's mesh gets the
renderer's Material through `material_from_u3m` (its physical size measured on the mesh), with what
the renderer does not carry of it said in notes.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from renderer.errors import MaterialError
from renderer.mesh import Mesh
from renderer.shading.material import Material
from renderer.u3m import DEFAULT_LIMITS, U3MLimits, U3MMaterial, material_from_u3m

from .errors import ConflictError, NotFoundError

if TYPE_CHECKING:
    from .settings import ServiceSettings

# The most a decoded pixel keeps: a colour or a normal image's three float32 (a scalar's one).
BYTES_PER_PIXEL = 12


@dataclass
class FabricRecord:
    id: str
    name: str            # the upload's ?name=, else the document's material name
    label: str           # the file as messages name it
    material: U3MMaterial
    file_sha256: str
    archive_bytes: int
    decode_ms: float
    created: float = field(default_factory=time.time)

    @property
    def nbytes(self) -> int:
        """The memory the fabric keeps: its decoded images (U3MMaterial.nbytes)."""
        return self.material.nbytes


class FabricStore:
    """The fabrics of this process: at most `max_fabrics`, keeping at most `max_bytes` of decoded
    images together, reads in progress counted by what they reserved."""

    def __init__(self, max_fabrics: int, max_bytes: int):
        self.max_fabrics = max_fabrics
        self.max_bytes = max_bytes
        self._by_id: OrderedDict[str, FabricRecord] = OrderedDict()
        self._reserved = 0
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        return sum(r.nbytes for r in self.list())

    def check_count(self) -> None:
        if len(self._by_id) >= self.max_fabrics:
            raise ConflictError(f"the service holds {self.max_fabrics} fabrics already (the limit, "
                                "GARMENT_RENDER_MAX_FABRICS); delete one with DELETE /fabrics/{id}")

    @contextlib.contextmanager
    def reserve(self, want_bytes: int):
        """Reserve up to `want_bytes` of the budget for a read (all that is left where less is); yields
        the bytes granted, released when the block ends."""
        with self._lock:
            held = sum(r.nbytes for r in self._by_id.values())
            granted = max(0, min(want_bytes, self.max_bytes - held - self._reserved))
            self._reserved += granted
        try:
            yield granted
        finally:
            with self._lock:
                self._reserved -= granted

    def add(self, record: FabricRecord) -> tuple[FabricRecord, bool]:
        """(the record kept, created): the same id again keeps its first record."""
        with self._lock:
            existing = self._by_id.get(record.id)
            if existing is not None:
                return existing, False
            self.check_count()
            self._by_id[record.id] = record
            return record, True

    def find(self, fabric_id: str) -> FabricRecord | None:
        with self._lock:
            return self._by_id.get(fabric_id)

    def list(self) -> list[FabricRecord]:
        with self._lock:
            return list(self._by_id.values())

    def remove(self, fabric_id: str) -> FabricRecord:
        with self._lock:
            rec = self._by_id.pop(fabric_id, None)
        if rec is None:
            raise NotFoundError(f"unknown fabric id {fabric_id!r}")
        return rec

    def __len__(self) -> int:
        return len(self._by_id)


def unknown_fabric(fabric_id: str) -> NotFoundError:
    return NotFoundError(f"unknown fabric id {fabric_id!r}; upload the fabric with POST /fabrics (ids are listed by "
                         "GET /fabrics)")


# -- reading ---------------------------------------------------------------------------------------


def fabric_limits(settings: ServiceSettings, room_bytes: int) -> U3MLimits:
    """The reader's bounds for one upload: the service's pixels of a fabric, no more than the budget's
    `room_bytes` hold at BYTES_PER_PIXEL, and an archive no larger than an upload may be."""
    total = min(settings.max_fabric_pixels, room_bytes // BYTES_PER_PIXEL)
    return U3MLimits(max_image_pixels=min(DEFAULT_LIMITS.max_image_pixels, total), max_total_pixels=total,
                     max_archive_bytes=min(DEFAULT_LIMITS.max_archive_bytes, settings.max_upload_bytes))


def in_service_terms(exc: MaterialError, settings: ServiceSettings, limits: U3MLimits, room_bytes: int,
                      fabrics: FabricStore) -> Exception:
    """The reader's refusal with the service's settings named in place of the reader's bounds; a 409
    where the fabrics' memory budget, not a fabric's own limit, was what refused it."""
    reason = exc.reason
    own = fabric_limits(settings, settings.max_fabric_bytes)   # the bounds with the whole budget free
    if ("U3MLimits.max_total_pixels" in reason and limits.max_total_pixels < own.max_total_pixels) or \
            ("U3MLimits.max_image_pixels" in reason and limits.max_image_pixels < own.max_image_pixels):
        return ConflictError(
            f"{exc}: the fabrics held take {fabrics.nbytes / 2**20:.0f} of the {fabrics.max_bytes / 2**20:.0f} MiB "
            f"they may keep (GARMENT_RENDER_MAX_FABRIC_BYTES), which leaves {room_bytes / 2**20:.0f} MiB, "
            f"{limits.max_total_pixels} px at {BYTES_PER_PIXEL} bytes a decoded pixel; delete one with "
            "DELETE /fabrics/{id}, or send smaller images")
    for name, setting in (("U3MLimits.max_total_pixels", "GARMENT_RENDER_MAX_FABRIC_PIXELS"),
                          ("U3MLimits.max_image_pixels", "one image: GARMENT_RENDER_MAX_FABRIC_PIXELS, and 8192^2 "
                           "px at most"),
                          ("U3MLimits.max_archive_bytes", "GARMENT_RENDER_MAX_UPLOAD_BYTES")):
        reason = reason.replace(name, setting)
    return MaterialError(reason, file=exc.file, field=exc.field)


# -- on a mesh -------------------------------------------------------------------------------------

def fabric_material(fabrics: dict[str, FabricRecord], fabric_id: str, uv_scale: list[float] | None, mesh: Mesh,
                    role: str) -> tuple[Material, list[str]]:
    """The renderer's Material of a fabric on `mesh` (its front outward, each texture at its physical
    size: measured on the mesh unless `uv_scale` gives the metres a UV unit spans), and what of it the
    renderer does not carry, one note each naming `role` and the fabric."""
    rec = fabrics.get(fabric_id)
    if rec is None:   # pragma: no cover - scene_fabrics found every one the scene names
        raise unknown_fabric(fabric_id)
    if mesh.uvs is None:
        raise MaterialError(f"{role} mesh {mesh.name!r} has no UVs, and fabric {rec.id} ({rec.name}) is laid on the "
                            "mesh by them: send uvs (V, 2), or a mesh file with UVs")
    scale = None if uv_scale is None else (float(uv_scale[0]), float(uv_scale[1]))
    try:
        material, warnings = material_from_u3m(rec.material, mesh, uv_scale=scale)
        material.vertex_arrays(mesh.n_vertices)
        material.pbr_arrays(mesh.n_vertices)
        material.face_texture_sets(mesh.faces, mesh.n_vertices)
        material.has_textures()   # validates every map
    except ValueError as exc:   # MaterialError and InvalidInputError are ValueErrors
        raise MaterialError(f"{role}: fabric {rec.id} ({rec.name}): {exc}") from None
    return material, [f"{role} ({rec.id}): {w}" for w in warnings]

