"""From request models to validated renderer objects: meshes, materials, camera, quality. Runs in
worker threads of the request handlers (validation touches every vertex), never on the GL thread,
so that the GL job that creates a scene cannot fail half-way on bad input."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from renderer import config
from renderer.camera import Camera, bounds_sphere, frame_meshes
from renderer.costs import FrameCost, frame_cost
from renderer.errors import MeshError
from renderer.lighting.pem_plan import PEMSettings, pem_cost
from renderer.mesh import Mesh, bounds, z_up_to_y_up
from renderer.presets import pem_settings, resolve
from renderer.procedural import floor_under
from renderer.settings import Background, FrameSettings, ShadingMode
from renderer.shading.fields import FIELDS as MATERIAL_FIELDS
from renderer.shading.material import Material, TextureSet
from renderer.shadows.proxy import shadow_faces_isolated

from .errors import InvalidRequestError, PayloadTooLargeError
from .fabrics import FabricRecord, fabric_material
from .registry import MeshStore
from .schemas import (
    CameraSpec,
    FabricRef,
    MaterialSpec,
    MeshSpec,
    OutputSpec,
    QualitySpec,
    SceneCreate,
    TextureSetSpec,
)
from .settings import ServiceSettings

_KNOBS = config.NAMES


@dataclass
class RequestQuality:
    face_size: int
    pem: PEMSettings
    frame: FrameSettings
    knobs: dict   # every setting as resolved (`renderer.presets.resolve`)
    info: dict    # the resolved settings and where they came from, reported with each frame


def resolve_quality(q: QualitySpec, out: OutputSpec, presets: dict, measured: dict | None,
                    settings: ServiceSettings, device: str | None = None) -> RequestQuality:
    """The request's knobs over its preset's (renderer/presets) or its budget's, resolved by the one
    rule the command line shares (`renderer.presets.resolve`), as frame and PEM settings; the PEM
    set's full chain (a scene narrows it to its materials' levels in `prepare_scene`). Budgets choose
    from `measured` (the table read at start-up; None: none stored), measured on `device` (the
    service's GL renderer; None: not known yet)."""
    name = q.preset.value if q.preset is not None else settings.default_preset
    # A budget chooses the measured setting that meets it, never a guess (InvalidInputError: 422).
    resolved = resolve(name, {k: getattr(q, k) for k in q.model_fields_set if k in _KNOBS},
                       frame_budget_ms=q.frame_budget_ms, error_budget=q.error_budget,
                       filter=q.filter.value if "filter" in q.model_fields_set else None, in_use=(presets, None),
                       table=measured, size=(out.width, out.height), device=device)
    knobs = dict(resolved.knobs)
    pem = resolved.pems(q.levels)   # checks the PEM set's settings (renderer/config.py)
    for side, value in (("width", out.width), ("height", out.height)):
        if value > settings.max_image_side:
            raise InvalidRequestError(f"output.{side} {value} exceeds the limit {settings.max_image_side} "
                                      "(GARMENT_RENDER_MAX_IMAGE_SIDE)")
    frame = resolved.frame(out.width, out.height, bleed_reduction=q.bleed_reduction,
                           mode=ShadingMode(q.mode.value), background=Background(out.background),
                           environment_rotation_deg=out.environment_rotation, aovs=tuple(out.aovs))
    applied = frame.as_dict()   # the knobs as the frame holds them (enums as their values)
    info = {"preset": resolved.preset, "source": resolved.source, **{k: applied.get(k, knobs[k]) for k in _KNOBS},
            "filter": pem.filter.value,
            "levels": q.levels, "bleed_reduction": frame.bleed_reduction, "mode": frame.mode.value}
    return RequestQuality(knobs["face_size"], pem, frame, knobs, info)


def _pem_over(face_size: int, pem: PEMSettings, settings: ServiceSettings) -> list[str]:
    """The limits a PEM set of these settings exceeds, each with its value and the limit."""
    cost = pem_cost(face_size, pem, export=settings.pem_cache_dir is not None)
    seconds = cost.texel_lights * settings.pem_build_ns_per_texel_light * 1e-9
    over = []
    if settings.pem_cache_bytes > 0 and cost.stored_bytes > settings.pem_cache_bytes:
        over.append(f"its {cost.stored_bytes / 2**20:.0f} MiB exceed the PEM cache's {settings.pem_cache_bytes / 2**20:.0f} "
                    "MiB (GARMENT_RENDER_PEM_CACHE_BYTES)")
    if cost.peak_bytes > settings.max_pem_build_bytes:
        over.append(f"its build would hold {cost.peak_bytes / 2**20:.0f} MiB at once, over the "
                    f"{settings.max_pem_build_bytes / 2**20:.0f} MiB of GARMENT_RENDER_MAX_PEM_BUILD_BYTES")
    if seconds > settings.max_pem_build_s:
        over.append(f"its build would take about {seconds:.0f} s ({cost.texel_lights / 1e6:.0f} M texel-lights at "
                    f"{settings.pem_build_ns_per_texel_light:g} ns), over the {settings.max_pem_build_s:g} s of "
                    "GARMENT_RENDER_MAX_PEM_BUILD_S")
    return over


def check_pem_set(quality: RequestQuality, settings: ServiceSettings) -> None:
    """Refuse (422) the PEM sets of a request's quality beyond the service's limits: the one judgement
    an upload and a scene both make. Judged on the whole chain, which an upload builds and which costs
    the most of any set of these settings (a scene keeps only the levels its materials read, fewer
    bytes in the same time: `pem_cost` grows with the levels kept), so that one face size gets one
    answer, and what it says fits, fits either route."""
    check_pem_cost(quality.face_size, replace(quality.pem, base_level=0), settings)


def check_pem_cost(face_size: int, pem: PEMSettings, settings: ServiceSettings) -> None:
    """Refuse (422) a PEM set beyond the service's limits from its settings alone, before any of it is
    allocated, naming each limit and the face size and light count that would fit."""
    over = _pem_over(face_size, pem, settings)
    if not over:
        return
    faces = [f for f in (face_size >> k for k in range(1, 12)) if f >= 4 and not _pem_over(f, pem, settings)]
    counts = [n for n in (pem.lights >> k for k in range(1, 8)) if n >= 6 and n % 6 == 0
              and not _pem_over(face_size, replace(pem, lights=n), settings)]
    fits = [f"face_size {faces[0]}" for f in faces[:1]] + [f"lights {counts[0]}" for f in counts[:1]]
    raise InvalidRequestError(
        f"the PEM set of face_size {face_size} with {pem.lights} lights is refused before it is built: "
        + "; ".join(over) + (f". What would fit: {' or '.join(fits)}" if fits else "")
        + " (or raise the limit)")


def check_counts(n_vertices: int, n_faces: int, role: str, settings: ServiceSettings) -> None:
    if n_vertices > settings.max_vertices:
        raise PayloadTooLargeError(f"{role}: {n_vertices} vertices exceed the limit {settings.max_vertices} "
                                   "(GARMENT_RENDER_MAX_VERTICES)")
    if n_faces > settings.max_faces:
        raise PayloadTooLargeError(f"{role}: {n_faces} faces exceed the limit {settings.max_faces} "
                                   "(GARMENT_RENDER_MAX_FACES)")


def build_mesh(spec: MeshSpec, role: str, up: str, meshes: MeshStore, settings: ServiceSettings) -> Mesh:
    """The Mesh of a spec: an uploaded file (already Y-up) or inline arrays in the scene's up axis."""
    if spec.mesh_id is not None:
        mesh = meshes.get(spec.mesh_id).mesh
        check_counts(mesh.n_vertices, mesh.n_faces, role, settings)
        return mesh
    check_counts(len(spec.positions), len(spec.faces), role, settings)
    name = spec.name or role
    if not spec.positions or not spec.faces:
        # Caught here: an empty JSON list has shape (0,), which the renderer would call a flat array.
        raise MeshError(f"mesh '{name}' ({role}) is empty: {len(spec.positions)} vertices, {len(spec.faces)} faces")
    positions = np.asarray(spec.positions, dtype=np.float64) if _rectangular(spec.positions) else spec.positions
    if up == "z" and isinstance(positions, np.ndarray) and positions.ndim == 2 and positions.shape[1:] == (3,):
        positions = z_up_to_y_up(positions)
    return Mesh.from_arrays(positions, np.asarray(spec.faces) if _rectangular(spec.faces) else spec.faces,
                            spec.uvs, name=name)


def _rectangular(rows: list) -> bool:
    return bool(rows) and len({len(r) for r in rows}) == 1


def material_spec_of(m: Material) -> MaterialSpec:
    """The MaterialSpec of a physically based Material read from a file (gltf.material_from_gltf)."""
    def listed(x):
        return None if x is None else np.asarray(x, np.float64).round(6).tolist()

    def value(x):   # a scalar, or a list per vertex (a file of several materials)
        return float(x) if np.ndim(x) == 0 else listed(x)

    def maps(ts) -> dict:
        return {"albedo_map": listed(ts.albedo_map), "metallic_roughness_map": listed(ts.metallic_roughness_map),
                "normal_map": listed(ts.normal_map), "normal_scale": float(ts.normal_scale),
                "sheen_map": listed(ts.sheen_map)}

    sets = {} if not m.texture_sets else {
        "texture_sets": [TextureSetSpec(**maps(ts)) for ts in m.texture_sets],
        "texture_set": np.asarray(m.texture_set, np.int64).tolist()}
    values = {f.name: listed(getattr(m, f.name)) if f.kind == "colour" else value(getattr(m, f.name))
              for f in MATERIAL_FIELDS}
    return MaterialSpec(model=m.model, **values, **({} if m.texture_sets else maps(m)), **sets)


def file_material(spec: MeshSpec, meshes: MeshStore) -> MaterialSpec | None:
    """A mesh's material: None where its spec names a fabric, else the one its spec names, else (an
    uploaded glTF/GLB that carries one) the file's own, else the default."""
    if spec.fabric_id is not None:
        return None
    if spec.mesh_id is not None and "material" not in spec.model_fields_set:
        rec = meshes.get(spec.mesh_id)
        if rec.material is not None:
            return material_spec_of(rec.material)
    return spec.material


def build_material(spec: MaterialSpec, mesh: Mesh, role: str) -> Material:
    """A Material checked against its mesh (shapes, ranges, maps need UVs) before any GL work."""
    def arr(x):
        return None if x is None else np.asarray(x, np.float32) if _rectangular_any(x) else _ragged(role, x)

    def maps(ts) -> dict:
        return {"albedo_map": arr(ts.albedo_map), "gloss_map": arr(ts.gloss_map),
                "metallic_roughness_map": arr(ts.metallic_roughness_map), "normal_map": arr(ts.normal_map),
                "normal_scale": ts.normal_scale, "sheen_map": arr(ts.sheen_map)}

    try:
        values = {f.name: arr(getattr(spec, f.name)) if f.per_vertex else getattr(spec, f.name)
                  for f in MATERIAL_FIELDS}
        mat = Material(model=spec.model, **values, **maps(spec),
                       texture_sets=tuple(TextureSet(**maps(ts)) for ts in spec.texture_sets),
                       texture_set=None if spec.texture_set is None else np.asarray(spec.texture_set, np.int64))
        mat.vertex_arrays(mesh.n_vertices)
        mat.pbr_arrays(mesh.n_vertices)
        mat.face_texture_sets(mesh.faces, mesh.n_vertices)
        textured = mat.has_textures()   # validates every map
    except ValueError as e:  # InvalidInputError is a ValueError
        raise type(e)(f"{role} material: {e}") from None
    if textured and mesh.uvs is None:
        raise InvalidRequestError(f"{role} material has texture maps but the mesh has no UVs; send uvs (V, 2)")
    return mat


def _rectangular_any(x) -> bool:
    try:
        np.asarray(x, np.float32)
        return True
    except ValueError:
        return False


def _ragged(role: str, x):
    raise InvalidRequestError(f"{role} material: an array is ragged (rows of different lengths)")


def build_camera(spec: CameraSpec | None, up: str, meshes: list[Mesh], aspect: float) -> Camera:
    """The scene's fixed camera: the given one (rotated to Y-up), or one framing the initial meshes."""
    if spec is None:
        return frame_meshes(meshes, aspect)
    vecs = [np.asarray(v, np.float64) for v in (spec.eye, spec.target, spec.up)]
    if up == "z":
        vecs = [z_up_to_y_up(v).astype(np.float64) for v in vecs]
    return Camera(*(tuple(float(c) for c in v) for v in vecs), fov_y_deg=spec.fov_y_deg)


def check_camera_sees(camera: Camera, meshes: list[Mesh], width: int, height: int) -> None:
    """Refused at registration, not frame after frame: a camera the frame's projection cannot hold
    (the renderer's own check, Camera.view_proj, on the scene's bounds), or one from which the whole
    scene would be less than a pixel across (an eye a thousand kilometres off)."""
    centre, radius = bounds_sphere(*bounds(meshes))
    camera.view_proj(width / height, centre, radius)
    distance = float(np.linalg.norm(np.asarray(camera.eye, np.float64) - centre))
    across_px = 2.0 * np.arctan2(radius, distance) / np.radians(camera.fov_y_deg) * height
    if across_px < 1.0:
        raise InvalidRequestError(
            f"from this camera (eye {distance:.4g} m from the scene, {camera.fov_y_deg:g} degrees) the scene, "
            f"{2 * radius:.3g} m across, would be {across_px:.2g} pixels across at {height} pixels high: bring the "
            "eye closer or leave the camera out (one is framed on the meshes)")


def camera_dict(camera: Camera) -> dict:
    return {"eye": [float(c) for c in camera.eye], "target": [float(c) for c in camera.target],
            "up": [float(c) for c in camera.up], "fov_y_deg": camera.fov_y_deg, "space": "world, Y-up"}


@dataclass
class PreparedScene:
    meshes: list[Mesh]
    roles: list[str]
    materials: list[Material]
    camera: Camera
    quality: RequestQuality
    casters: list[bool]
    proxies: dict | None = None   # the casters' shadow proxies at the quality's detail, made here (off the GL thread)
    material_specs: list | None = None   # each mesh's MaterialSpec as used (a glTF file's own; None: a fabric)
    colourways: list[Material] = field(default_factory=list)   # more garment materials (SceneCreate.colourways)
    material_notes: list[str] = field(default_factory=list)    # what of the fabrics the renderer does not carry
    catcher: int | None = None   # the shadow catcher's mesh (output.background "shadow-catcher")

    def exact_frame_cost(self, regions, settings: ServiceSettings) -> FrameCost:
        """`check_frame_cost` with the scene's PEM set's regions (on the GL thread, before the scene's
        GPU objects are made)."""
        return check_frame_cost(self.quality, self.casters, self.materials + self.colourways, settings, regions)


# The role of the floor a shadow-catcher scene without one gets (procedural.floor_under).
SHADOW_FLOOR = "shadow floor"


def prepare_scene(body: SceneCreate, presets: dict, measured: dict | None, meshes: MeshStore,
                  settings: ServiceSettings, device: str | None = None,
                  fabrics: dict[str, FabricRecord] | None = None) -> PreparedScene:
    """`fabrics`: every fabric the scene names, by id (operations.scene_fabrics)."""
    quality = resolve_quality(body.quality, body.output, presets, measured, settings, device)
    specs = [("garment", body.garment)] + [(role, getattr(body, role)) for role in ("body", "floor")
                                           if getattr(body, role) is not None]
    built = [build_mesh(spec, role, body.up, meshes, settings) for role, spec in specs]
    material_specs = [file_material(spec, meshes) for _, spec in specs]
    notes: list[str] = []

    def material(given: MaterialSpec | FabricRef | None, mesh: Mesh, role: str) -> Material:
        if isinstance(given, FabricRef):
            made, lines = fabric_material(fabrics or {}, given.fabric_id, given.uv_scale, mesh, role)
            notes.extend(lines)
            return made
        return build_material(given, mesh, role)

    materials = [material(m if m is not None else spec.fabric(), mesh, role)
                 for (role, spec), m, mesh in zip(specs, material_specs, built)]
    # Numbered as the views answer labels them: the garment's own material is 0.
    colourways = [material(m, built[0], f"colourway {k}") for k, m in enumerate(body.colourways, 1)]
    # A floor casts nothing unless its spec says so.
    casters = [spec.cast_shadows if role != "floor" or "cast_shadows" in spec.model_fields_set else False
               for role, spec in specs]
    # The default camera frames what casts (a floor that only receives would push it far back).
    framed = [m for m, c in zip(built, casters) if c] or built
    camera = build_camera(body.camera, body.up, framed, body.output.width / body.output.height)
    check_camera_sees(camera, built, body.output.width, body.output.height)
    if not any(casters):
        raise InvalidRequestError("cast_shadows is false on every mesh, so nothing would cast a shadow: set "
                                  "cast_shadows: true on the garment (a floor alone may be false)")
    roles = [r for r, _ in specs]
    catcher = None
    if body.output.background == "shadow-catcher":   # the floor catches the shadows, or one made under the meshes
        if "floor" in roles:
            catcher = roles.index("floor")
        else:
            built.append(floor_under(built))
            roles.append(SHADOW_FLOOR)
            materials.append(Material((0.5, 0.5, 0.5), 0.0, 0.3))
            casters.append(False)
            material_specs.append(None)
            catcher = len(built) - 1
    # Judged before the glossiness calibration the materials' levels need is made (seconds and a GB
    # at a 2048^2 face, once per process), as an upload judges its set (`check_pem_set`).
    check_pem_set(quality, settings)
    # The scene's PEM set: only the levels its materials' glossiness reads (no more than the whole chain).
    quality.pem = pem_settings(quality.knobs, quality.pem.filter, quality.pem.levels, materials + colourways)
    quality.info["base_level"] = quality.pem.base_level
    # The frame's memory from the settings alone: refused here, before the proxies, where no map could
    # fit (the light plan, and so the exact number, waits for the PEM set's regions).
    check_frame_cost(quality, casters, materials + colourways, settings)
    detail = quality.frame.caster_detail
    # The shadow pass's triangles at the main maps' detail and in full (the sharp maps'), made here, off
    # the GL thread.
    proxies = {d: [shadow_faces_isolated(m.positions, m.faces, d) if c else None for m, c in zip(built, casters)]
               for d in {min(detail, 1.0), 1.0}}
    return PreparedScene(built, roles, materials, camera, quality, casters, proxies, material_specs,
                         colourways, notes, catcher)


def check_frame_cost(quality: RequestQuality, casters: list[bool], materials: list[Material],
                     settings: ServiceSettings, regions=None) -> FrameCost:
    """What one frame of a scene allocates (renderer.costs.frame_cost): with its PEM set's `regions`
    (PEMSet.regions, on the GL thread: the light plan's own layout), else from the settings alone, of
    which only what the fewest maps would take is judged; InvalidRequestError (422) where its shadow
    maps pass GARMENT_RENDER_MAX_SHADOW_MAP_BYTES. `materials`: every material of the scene's meshes
    and colourways."""
    cost = frame_cost(quality.frame, quality.pem, quality.face_size, casters, regions=regions,
                      pbr=any(m.is_pbr for m in materials))
    need = cost.shadow_bytes if cost.exact else cost.least_shadow_bytes
    limit = settings.max_shadow_map_bytes
    if need > limit:
        raise InvalidRequestError(
            f"quality asks for {'' if cost.exact else 'at least '}{_gib(need)} of shadow maps ({cost.describe()}), "
            f"over the limit of {_gib(limit)} (GARMENT_RENDER_MAX_SHADOW_MAP_BYTES): use fewer lights, a smaller "
            "shadow_size or small_light_scale, or a larger small_light_min_energy")
    return cost


def _gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 1 << 30 else f"{n / 2**20:.0f} MiB"
