"""Request and response models (pydantic). Arrays travel as nested lists in JSON; per-frame vertex
positions travel as raw little-endian float32 bytes (see routes/frames.py), never as JSON."""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, create_model, model_validator

from renderer import config
from renderer.aovs import AOVS
from renderer.lighting.pem_reference import mip_levels
from renderer.presets import PRESET_NAMES
from renderer.shading.fields import FIELDS as MATERIAL_FIELDS
from renderer.shading.fields import MODEL_DOC as MATERIAL_MODEL_DOC
from renderer.shading.fields import MODELS as MATERIAL_MODELS
from renderer.shading.fields import MaterialField
from renderer.shading.material import MAX_TEXTURE_SETS
from renderer.shading.tonemap import DEFAULT_CURVE, ToneCurve

Preset = Enum("Preset", {name.upper(): name for name in PRESET_NAMES}, type=str)
Preset.__doc__ = "A quality preset (renderer/presets/*.toml)."


def _range_bounds(st: config.Setting) -> dict:
    """A numeric setting's range as pydantic's bounds, its ends excluded where the registry says so."""
    return {"gt" if st.above_minimum else "ge": st.minimum, "lt" if st.below_maximum else "le": st.maximum}


def _option_enum(name: str, option: str) -> type[Enum]:
    """The values of an option no preset chooses (renderer/config.py, OPTIONS), as the schema's enum."""
    return Enum(name, {v.upper().replace("-", "_"): v for v in config.OPTION[option].choices}, type=str,
                module=__name__)


# The renderer's tone curves (renderer/shading/tonemap.py), as the strings a request names.
ToneName = Literal[tuple(c.value for c in ToneCurve)]

FilterName = _option_enum("FilterName", "filter")
LayoutName = _option_enum("LayoutName", "layout")
ModeName = _option_enum("ModeName", "mode")


class ImageFormat(str, Enum):
    PNG = "png"
    EXR = "exr"
    JSON = "json"


class EmbeddedImageFormat(str, Enum):
    """The image inside a JSON answer (?image=)."""
    PNG = "png"
    EXR = "exr"


# Colourways a scene carries beside its own garment material.
MAX_COLOURWAYS = 16


class BatchFormat(str, Enum):
    JSON = "json"
    ZIP = "zip"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


# -- quality and output --------------------------------------------------------------------------


def _registry_field(st: config.Setting):
    """A request field of a quality setting of renderer/config.py: its type (strict: no strings for
    numbers, no floats for whole numbers), its range for the schema, and the registry's own check
    (a power of two) with the registry's message. None: the preset's value."""
    base = Literal[st.choices] if st.choices is not None else st.type
    # The range in JSON Schema's own words (a Field's ge/le beside the validators below would reach the
    # schema as "ge"/"le", which no checker reads); the registry's check enforces it with its message.
    bounds = {} if st.minimum is None else {("exclusiveMinimum" if st.above_minimum else "minimum"): st.type(st.minimum),
                                            "maximum": st.type(st.maximum)}

    def checked(value):
        return None if value is None else st.check(value)   # InvalidInputError is a ValueError: a 422

    strict = {} if st.choices is not None else {"strict": True}
    schema = dict(bounds)
    if st.type is int and st.power_of_two:   # the registry's rule in the schema too
        lo = max(int(st.minimum), 1)
        schema["enum"] = [1 << k for k in range(16) if lo <= 1 << k <= st.maximum]
    validators = [BeforeValidator(_whole)] if st.type is int else []
    kind = Annotated[base, *validators, Field(**strict, json_schema_extra=schema or None), AfterValidator(checked)]
    return (kind | None, Field(None, description=f"{st.doc}; {st.limits()} (null: the preset's)"))


def _whole(value):
    """A JSON number with no fraction (340.0) is an integer, as JSON Schema has it; a string or a
    boolean is not, nor is 340.5 (then the strict int refuses it by name)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


# The longest MIP chain a PEM set has: the largest face's, down to 1 x 1.
MAX_LEVELS = mip_levels(int(config.BY_NAME["face_size"].maximum))


class _QualityBase(_Strict):
    """A preset, refined by explicit knobs (each overrides the preset's value)."""

    preset: Preset | None = Field(None, description=" | ".join(PRESET_NAMES) + "; default: the service's default")
    frame_budget_ms: float | None = Field(None, gt=0.0, description="instead of a preset: the most accurate setting "
                                          "measured within this frame time (the stored benchmark table)")
    error_budget: float | None = Field(None, gt=0.0, description="instead of a preset: the fastest setting measured "
                                       "within this worst-scene rel. RMSE (with frame_budget_ms: the most accurate "
                                       "within both)")
    filter: FilterName = Field(FilterName(config.OPTION["filter"].default), description=config.OPTION["filter"].doc)
    levels: int | None = Field(None, ge=1, le=MAX_LEVELS, description="MIP levels built (default: the full chain)")
    bleed_reduction: float = Field(config.OPTION["bleed_reduction"].default,
                                   **_range_bounds(config.OPTION["bleed_reduction"]),
                                   description=config.OPTION["bleed_reduction"].doc)
    mode: ModeName = Field(ModeName(config.OPTION["mode"].default), description=config.OPTION["mode"].doc)

    @model_validator(mode="before")
    @classmethod
    def _no_retired_settings(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for name in data:
                if config.retired(name):
                    raise ValueError(f"quality.{name}: {config.retired(name)}; leave the field out")
        return data


# Every quality setting of the registry, as a field of its own.
QualitySpec = create_model("QualitySpec", __base__=_QualityBase, __module__=__name__,
                           **{st.name: _registry_field(st) for st in config.SETTINGS})


# A 3-vector: a list of exactly three numbers (minItems = maxItems = 3 in the schema, which every
# OpenAPI tool reads; a tuple's prefixItems is JSON Schema 2020-12 alone and some read it as an error).
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Face = Annotated[list[int], Field(min_length=3, max_length=3)]   # 0-based vertex indices
UV = Annotated[list[float], Field(min_length=2, max_length=2)]


class OutputSpec(_Strict):
    width: int = Field(512, ge=1)
    height: int = Field(512, ge=1)
    background: Literal["env", "black", "shadow-catcher"] = Field(
        "env", description="env: the map; black: nothing (alpha 0); shadow-catcher: nothing but the shadows on the "
        "floor (black, alpha the light the figure takes from it; without a floor mesh, a ground plane at the "
        "meshes' lowest point), the garment and body opaque: a product image over any backdrop")
    exposure_ev: float | None = Field(None, ge=-64, le=64,
                                      description="fixed exposure in stops (-64..64); null: automatic per frame")
    tone: ToneName = Field(DEFAULT_CURVE.value, description="tone curve of PNG images (pbr-neutral: a base colour "
                           "under white light of radiance 1 shows as itself)")
    aovs: list[Literal[AOVS]] = Field([], max_length=len(AOVS), description="passes beside the image, in EXR "
                                      "answers as channels (Z; N.X, N.Y, N.Z; albedo.R, .G, .B; id) and in JSON "
                                      "answers as float32 arrays: depth (metres from the eye), normal (world space), "
                                      "albedo (after textures), id (0 background, 1 garment, 2 body, 3 floor)")
    environment_rotation: float = Field(0.0, ge=-360.0, le=360.0, description="the environment turned about the up "
                                        "axis, degrees counter-clockwise seen from above (90: a light from the "
                                        "camera's right comes from behind); a frame's ?environment_rotation= "
                                        "overrides it; nothing is built again")


class CameraSpec(_Strict):
    eye: Vec3
    target: Vec3
    up: Vec3 = Field(default_factory=lambda: [0.0, 1.0, 0.0])
    fov_y_deg: float = 35.0


# -- meshes and materials --------------------------------------------------------------------------


class TextureSetSpec(_Strict):
    """One set of a material's textures (the MaterialSpec fields of the same names)."""

    albedo_map: list[list[list[float]]] | None = None
    gloss_map: list[list[list[float]]] | None = None
    metallic_roughness_map: list[list[list[float]]] | None = None
    normal_map: list[list[list[float]]] | None = None
    normal_scale: float = Field(1.0, ge=0.0, le=10.0)
    sheen_map: list[list[list[float]]] | None = None


class _MaterialBase(_Strict):
    """A material's textures and texture sets; MaterialSpec adds its values (the registry's)."""

    albedo_map: list[list[list[float]]] | None = None
    gloss_map: list[list[list[float]]] | None = None
    metallic_roughness_map: list[list[list[float]]] | None = Field(
        None, description="pbr: (H, W, 2) texture of (metallic, roughness) multiplying the two; needs mesh UVs")
    normal_map: list[list[list[float]]] | None = Field(
        None, description="(H, W, 3) tangent-space normal texture in [0, 1] (glTF's); needs mesh UVs")
    normal_scale: float = Field(1.0, ge=0.0, le=10.0, description="scale of the normal map's x and y")
    sheen_map: list[list[list[float]]] | None = Field(
        None, description="pbr: (H, W, 4) texture whose rgb multiplies sheen_colour and a sheen_roughness "
        "(KHR_materials_sheen's textures); needs mesh UVs")
    texture_sets: list[TextureSetSpec] = Field(
        default_factory=list, max_length=MAX_TEXTURE_SETS, description="several sets of the maps above, one per "
        "part of the mesh (a shirt's fabric, its buttons); the maps above then stay empty")
    texture_set: list[int] | None = Field(None, description="(V,) the texture set each vertex reads (a "
                                          "triangle's three corners read the same)")


def _material_field(f: MaterialField):
    """A request field of a material value of renderer/shading/fields.py. Per-vertex values are typed
    only (a mesh's thousands of numbers are checked by Material, with its message); a scalar-only one
    carries its range."""
    doc = f"{' and '.join(f.models)}: {f.doc}; {f.limits()}"
    if f.kind == "colour":
        kind = list[float] | list[list[float]] if f.per_vertex else list[float]
        return kind, Field(list(f.default), description=doc)
    if f.per_vertex:
        return float | list[float], Field(f.default, description=doc)
    return float, Field(f.default, ge=f.lo, le=f.hi, description=doc)


# Scalars or per-vertex lists; maps are (H, W, 3) / (H, W, 2) nested lists and need mesh UVs.
MaterialSpec = create_model("MaterialSpec", __base__=_MaterialBase, __module__=__name__,
                            __doc__="A material: its model, its values (renderer/shading/fields.py) and textures.",
                            model=(Literal[MATERIAL_MODELS], Field("phong", description=MATERIAL_MODEL_DOC)),
                            **{f.name: _material_field(f) for f in MATERIAL_FIELDS})


# A U3M fabric's physical scale on a mesh: the metres a unit of u and a unit of v span.
UVScale = Annotated[list[Annotated[float, Field(gt=0.0, le=1000.0)]], Field(min_length=2, max_length=2)]
_FABRIC_ID = "a fabric uploaded with POST /fabrics (fab_...): its front on the side the mesh's winding faces, its " \
             "back behind it, each texture at its physical size"
_UV_SCALE = "the metres a unit of u and of v span on the mesh, [su, sv]; default: measured on the mesh (its " \
            "triangles' size against their UVs' size)"


class FabricRef(_Strict):
    """A U3M fabric (POST /fabrics) in place of a material: a colourway, or a mesh's `fabric_id`."""

    fabric_id: str = Field(description=_FABRIC_ID)
    uv_scale: UVScale | None = Field(None, description=_UV_SCALE)


# The rule of MeshSpec._one_material in the schema: neither fabric_id nor uv_scale (absent or null),
# or no material. A uv_scale with neither a fabric_id nor a material is refused by the validator alone:
# the exact rule's case split puts a fabric first among a generator's simplest meshes, where the mesh
# with the default material belongs.
_ONE_MATERIAL = {"anyOf": [{"properties": {"fabric_id": {"type": "null"}, "uv_scale": {"type": "null"}}},
                           {"properties": {"material": {"not": {}}}}]}

# The rule of MeshSpec._one_source in the schema: a mesh_id and no inline arrays, or both arrays and
# no mesh_id (an absent field or null counts as not given).
_ONE_SOURCE = {"oneOf": [
    {"required": ["mesh_id"], "properties": {"mesh_id": {"type": "string"}, "positions": {"type": "null"},
                                             "faces": {"type": "null"}}},
    {"required": ["positions", "faces"], "properties": {"positions": {"type": "array"}, "faces": {"type": "array"},
                                                        "mesh_id": {"type": "null"}}},
]}


class MeshSpec(_Strict):
    """Either `mesh_id` (a file uploaded with POST /meshes) or inline `positions` + `faces`; either a
    `material` or a `fabric_id` (with an optional `uv_scale`)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={**_ONE_SOURCE, **_ONE_MATERIAL})

    mesh_id: str | None = None
    name: str | None = None
    positions: list[Vec3] | None = Field(None, min_length=1,
                                                description="(V, 3) initial positions, in the scene's up axis")
    faces: list[Face] | None = Field(None, min_length=1, description="(F, 3) 0-based vertex indices, counter-clockwise")
    uvs: list[UV] | None = Field(None, description="(V, 2) per-vertex texture coordinates")
    material: MaterialSpec = Field(default_factory=MaterialSpec)
    fabric_id: str | None = Field(None, description="instead of material: " + _FABRIC_ID + "; needs mesh UVs")
    uv_scale: UVScale | None = Field(None, description="with fabric_id: " + _UV_SCALE)
    cast_shadows: bool = Field(True, description="false: the mesh receives shadows but casts none (a floor): "
                               "the shadow maps then fit the other meshes, so their texels are finer")

    @model_validator(mode="after")
    def _one_source(self) -> MeshSpec:
        inline = self.positions is not None or self.faces is not None
        if self.mesh_id is not None and inline:
            raise ValueError("give either mesh_id or positions + faces, not both")
        if self.mesh_id is None and (self.positions is None or self.faces is None):
            raise ValueError("a mesh needs mesh_id, or both positions and faces")
        return self

    @model_validator(mode="after")
    def _one_material(self) -> MeshSpec:
        if self.fabric_id is not None and "material" in self.model_fields_set:
            raise ValueError("give either material or fabric_id, not both")
        if self.uv_scale is not None and self.fabric_id is None:
            raise ValueError("uv_scale places a fabric's textures: it needs fabric_id")
        return self

    def fabric(self) -> FabricRef | None:
        """The fabric this mesh names, or None (it has a material)."""
        return None if self.fabric_id is None else FabricRef(fabric_id=self.fabric_id, uv_scale=self.uv_scale)


class SceneCreate(_Strict):
    """A scene: the garment (and optionally a body), lit by an uploaded environment map."""

    name: str = "scene"
    environment_id: str
    up: Literal["y", "z"] = Field("y", description="up axis of inline positions, every frame and the camera")
    garment: MeshSpec
    body: MeshSpec | None = None
    floor: MeshSpec | None = Field(None, description="a mesh under the others that takes their shadows and, "
                                   "unless its cast_shadows says otherwise, casts none: the shadow maps then fit "
                                   "the garment and the body; it never moves")
    camera: CameraSpec | None = Field(None, description="default: frames the initial meshes from +Z (fixed)")
    quality: QualitySpec = Field(default_factory=QualitySpec)
    output: OutputSpec = Field(default_factory=OutputSpec)
    colourways: list[MaterialSpec | FabricRef] = Field(
        default_factory=list, max_length=MAX_COLOURWAYS, description="more garment materials or fabrics "
        "({fabric_id, uv_scale}), rendered from the same frame by POST .../frames/views (sharing everything but "
        "shading); a physically based one (every fabric is) makes the scene's shading physically based")

    def fabric_ids(self) -> list[str]:
        """Every fabric the scene names (its meshes' and its colourways'), each once, in order."""
        meshes = [getattr(self, role) for role in ("garment", "body", "floor")]
        ids = [m.fabric_id for m in meshes if m is not None and m.fabric_id is not None]
        return list(dict.fromkeys(ids + [c.fabric_id for c in self.colourways if isinstance(c, FabricRef)]))


class ViewsFormat(str, Enum):
    SHEET = "sheet"
    ZIP = "zip"


# -- answers ---------------------------------------------------------------------------------------


class LightInfo(BaseModel):
    direction: Vec3
    energy_rgb: Vec3
    energy_share: float
    solid_angle_sr: float


class PemSetInfo(BaseModel):
    key: str
    face_size: int
    n_lights: int
    filter: str
    levels: int
    base_level: int = Field(description="the first MIP level kept (0 unless only the levels the scene's "
                                         "glossiness reads were built)")
    whole_sources: bool = Field(description="the median cut kept compact bright sources whole")
    lights_from: str = Field("median-cut", description="the quality's lights_from: median-cut, area or auto")
    lights_from_used: str = Field("median-cut", description="what the set was cut with: median-cut or area (an area "
                                  "set's lights are Arbree, Walter and Bala's discs plus the remainder's median cut; "
                                  "its preview shows each disc as a region)")
    area_lights: list[dict] | None = Field(None, description="the area lights: direction, angular radius (degrees) "
                                           "and energy share; null for a median-cut set")
    ambient_share: float | None = Field(None, description="the remainder's share of the energy (area sets)")
    source: str = Field(description="where the first request for it found it: built, disk or memory")
    build_ms: float
    median_cut_ms: float
    bytes: int
    lights: list[LightInfo] | None = None
    preview_url: str


class EnvironmentInfo(BaseModel):
    id: str
    name: str
    layout: str
    width: int
    height: int
    content_hash: str
    file_sha256: str
    repair: bool
    texel_report: dict | None
    decode_ms: float
    created: float
    pem_sets: list[PemSetInfo]
    scenes: list[str] = []
    cached: bool = Field(False, description="true when this upload matched an earlier one (nothing rebuilt)")


class MeshInfo(BaseModel):
    id: str
    name: str
    format: str
    n_vertices: int
    n_faces: int
    has_uvs: bool
    bounds: Annotated[list[Vec3], Field(min_length=2, max_length=2, description="the least and the greatest corner")]
    n_degenerate: int
    n_unreferenced: int
    material: str | None = Field(None, description="the file's own material (glTF/GLB), used by a scene that "
                                 "names this mesh and no material; what of it was not read")


class FabricTextureOut(BaseModel):
    path: str = Field(description="the image, as the document names it")
    width_mm: float = Field(description="the fabric one image covers")
    height_mm: float
    width_px: int
    height_px: int
    rotation_deg: float
    repeat: str = Field(description="normal, mirror_x, mirror_y or mirror_xy")


class FabricFieldOut(BaseModel):
    name: str = Field(description="the U3M field (basecolor, normal, roughness, ...)")
    kind: Literal["constant", "texture"]
    value: float | list[float] = Field(description="the constant (a texture's fallback constant): a number, a "
                                       "linear RGB colour or a tangent-space normal")
    texture: FabricTextureOut | None = None


class FabricFaceOut(BaseModel):
    face: Literal["front", "back", "side"]
    fields: list[FabricFieldOut]


class FabricInfo(BaseModel):
    id: str
    name: str = Field(description="the upload's ?name=, else the document's material name")
    material_name: str = Field(description="the document's material name")
    version: str = Field(description="U3M schema version: 1.0 or 1.1")
    file_sha256: str
    archive_bytes: int = Field(description="bytes of the file as uploaded")
    bytes: int = Field(description="memory its decoded images keep (GARMENT_RENDER_MAX_FABRIC_BYTES counts it)")
    decode_ms: float
    created: float
    faces: list[FabricFaceOut] = Field(description="the visualisations the document gives (a null back renders "
                                       "with the front's, as the spec says)")
    thickness_mm: float | None = None
    weight_g_m2: float | None = None
    scenes: list[str] = []
    cached: bool = Field(False, description="true when this upload matched an earlier one (nothing decoded)")


class SceneMeshOut(BaseModel):
    role: str
    name: str
    n_vertices: int
    n_faces: int
    has_uvs: bool
    frame_bytes: int = Field(description="bytes of one block of positions (or normals): V x 3 x 4")


class SceneInfo(BaseModel):
    id: str
    name: str
    environment_id: str
    up: str
    meshes: list[SceneMeshOut]
    quality: dict[str, Any]
    output: dict[str, Any]
    camera: dict[str, Any]
    pem_set: PemSetInfo | None
    frames_rendered: int
    created: float
    default_layout: str = "positions"
    frame_memory: dict[str, Any] | None = Field(
        None, description="what one frame allocates on the GL device, in bytes, estimated at registration from the "
                          "PEM set's light plan (renderer.costs.frame_cost): the shadow maps (judged against "
                          "GARMENT_RENDER_MAX_SHADOW_MAP_BYTES), the render targets and the PEM set")
    fabrics: list[str] = Field([], description="the fabrics its meshes and colourways name")
    colourways: int = Field(0, description="garment materials beyond its own (registered, or added by POST "
                            "/scenes/{id}/colourways): POST .../frames/views?colourway=1..n renders each")
    material_notes: list[str] = Field([], description="what of its fabrics the renderer does not carry yet "
                                      "(textured alpha, clear coat, displacement, ...), each naming its mesh or colourway")


class FrameImage(BaseModel):
    format: str
    media_type: str
    base64: str


class FrameOut(BaseModel):
    scene_id: str | None
    frame_index: int | None
    width: int
    height: int
    exposure_ev: float | None
    timings_ms: dict[str, float]
    render: dict[str, Any]
    image: FrameImage


class BatchOut(BaseModel):
    scene_id: str
    n_frames: int
    timings_ms: dict[str, float]
    frames: list[FrameOut]
