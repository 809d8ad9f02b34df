"""The contract between the Python side and the shaders, written once: every binding point, the shading
modes' numbers, the bits of a light's kind and the wide-lobe rule's constant.

`shaders.compose` prepends `glsl_defines()` to every program, so a shader names a binding
(`layout(binding = TEX_PEM0)`), a mode (`MODE == MODE_FULL`) or a kind bit by the name the Python
side binds or packs it with (`texture.use(location=LightingTexture.PEM0)`); tests/test_contract.py
checks that neither side writes one as a number and that every program compiles with them.
Binding points are per program: two programs may use one number for different things, one program
never (the enums below are one program or pass each, and a value appears once in each).
"""

from __future__ import annotations

from enum import IntEnum


class LightingBuffer(IntEnum):
    """Buffer binding points of the lighting pass (shaders/shading/lighting.frag and its includes) and
    of the shadow pass, which reads the same light records (shadows/moments.vert, blur.comp): shader
    storage and uniform blocks, numbered apart so that one name means one buffer."""

    LIGHTS = 0              # the light records (common/lights.glsl): a storage buffer, or a uniform block
    GLOSS_LEVELS = 1        # glossiness -> PEM level (renderer/lighting/glossiness.py)
    SHADOW_LIGHTS = 2       # each shadow layer's light (common/lights.glsl)
    LAYER_PROJECTIONS = 3   # a draw's layers' view-projections (shadows/moments.vert), a uniform block
    LIGHT_ORDER = 4         # the lights sorted by kind (renderer.plan.light_kinds), a uniform block
    LIGHT_SCREEN = 5        # each light in clip space for the contact search (shading/contact.glsl)
    SUB_LIGHTS = 6          # each region's glossy discs (shading/discs.glsl): a uniform block or storage
    MATERIAL_LOBES = 7      # the fitted lobe tables (shading/lobes.glsl)


class LightingTexture(IntEnum):
    """Texture units of the lighting pass and its background (shading/background.frag)."""

    PEM0 = 0                # regions 0 .. REGIONS_PER_TEXTURE - 1
    MOMENTS = 1             # the main shadow maps' moments
    ENVIRONMENT = 2         # the background's map (background.frag)
    PEM1 = 5                # the regions after the first texture's
    PEM_NORM = 6            # the normalizer B of the PEM lookups
    G_POSITION = 8          # the geometry pass's targets, in GBuffer's order from here
    G_NORMAL = 9
    G_GEOMETRIC = 10
    G_ALBEDO = 11
    MOMENTS_SHARP = 12      # the small lights' larger maps
    G_PBR = 13              # metallic, roughness, sheen roughness
    CASTERS = 14            # the main maps' caster share per group (blocker search)
    ORACLE = 15             # exact visibility per pixel and light (the error split's oracle)
    UNDER_LAYER = 18        # a layer seen through sheer cloth, blended under the image (shading/under.frag)


# The geometry pass's targets as LightingTexture binds them, in the order the geometry pass writes them.
G_BUFFER_UNITS = (LightingTexture.G_POSITION, LightingTexture.G_NORMAL, LightingTexture.G_GEOMETRIC,
                  LightingTexture.G_ALBEDO, LightingTexture.G_PBR)


class GeometryTexture(IntEnum):
    """Texture units of the geometry pass (shading/gbuffer.frag): a scene's material textures."""

    ALBEDO_MAP = 3
    GLOSS_MAP = 4
    NORMAL_MAP = 5
    SHEEN_MAP = 6
    ALPHA_MAP = 7           # multiplies the material's alpha (Material.alpha; gbuffer.frag packs it, below)
    PEEL_DEPTH = 16         # a layer behind sheer cloth: the last layer's depth (renderer.py, _sheer_layers)
    PEEL_OPACITY = 17       # ... and the image so far, whose alpha says where light still comes through


class EdgeTexture(IntEnum):
    """Texture units of the anti-aliasing's edges pass (shaders/edges/resolve.frag)."""

    MS_DEPTH = 0            # the coverage pass's depth at every sample
    DEPTH = 1               # the geometry pass's depth, position and geometric normal (at the centres)
    POSITION = 2
    GEOMETRIC = 3
    COLOUR = 4              # the lighting pass's output


class Image(IntEnum):
    """Image units: the lighting pass's output (compute variant), the shadow maps' blur and caster
    coverage (shadows/blur.comp, coverage.comp), the PEM build's output (pem/*.comp)."""

    LIGHTING_OUT = 0
    SHADOW_SRC = 1
    SHADOW_DST = 2
    PEM_OUT = 3


class PEMBuffer(IntEnum):
    """Storage buffers of the PEM build (shaders/pem/level0.comp, downsample.comp, filter.comp)."""

    ENV = 0                 # the map's texels times their solid angle
    LABELS = 1              # each texel's region
    INV_SCALE = 2           # each region's 1 / scale
    FILTERED = 3            # a batch of regions' filtered level
    REDUCED = 4             # a batch of regions' level reduced from the one above
    TILES = 5               # per workgroup of a reduction or filter: 0 where it reads zeros only


class NormalsBuffer(IntEnum):
    """Storage buffers of the vertex-normal pass (shaders/mesh/normals.comp)."""

    POSITIONS = 0
    FACES = 1
    ADJACENCY_START = 2
    ADJACENCY = 3
    NORMALS = 4


class ProbeBuffer(IntEnum):
    """Storage buffers of the light-record layout probe (shaders/common/light_layout_probe.comp)."""

    LIGHTS = 0
    OUT = 1


class Mode(IntEnum):
    """The lighting pass's MODE define, per renderer.ShadingMode."""

    FULL = 0
    NO_OCCLUSION = 1
    AO_GREY = 2
    AO_COLOUR = 3
    MANY_LIGHTS = 4


class LightKind(IntEnum):
    """Bits of a light's kind (renderer.plan.light_kinds; the lighting pass's KIND_LOOP)."""

    PEM_DIFFUSE = 1         # its diffuse term from its PEM
    PEM_GLOSSY = 2          # its glossy terms from its PEM
    SHARP = 4               # its map in the sharp array
    SECOND_PEM = 8          # its region in the second PEM texture


N_LIGHT_KINDS = 16
# The geometry pass's geometric target holds the mesh's shadow group in w, plus this where the mesh is a
# convex surface (renderer/scene.py, SceneMesh.convex; shading/gbuffer.frag, lighting.frag).
CONVEX_SURFACE = 4
# ... and, in multiples of this, the mesh's place in the scene plus one (0: no surface; the `id` pass,
# renderer/aovs.py): w = group + CONVEX_SURFACE (convex) + MESH_ID_STRIDE * (mesh + 1).
MESH_ID_STRIDE = 8
# ... and, below 1, the share an alpha map takes away (1 - its texel) times this: the integer part read
# by rounding (w + 0.5) stays that of the group and id (shading/gbuffer.frag, lighting.frag SHEETS).
ALPHA_MAP_FRACTION = 0.25
# Sheer or transmitting cloth (Material.alpha, .transmission): the lighting pass reads each mesh's pair
# by its id, for a scene's first this many meshes (renderer.py, _sheets; a scene whose later meshes are
# sheer is refused).
MAX_SHEET_MESHES = 64
# How many surfaces a pixel shows through sheer cloth: the nearest and those behind it (a skirt's front,
# its inside at the back, what is behind the skirt); the share of light still coming through after the
# last is the background's (renderer.py, _sheer_layers).
SHEER_LAYERS = 3

# The wide-lobe rule (shading/discs.glsl, wide_lobe; renderer.plan.light_kinds): a lobe of variance 1 / s is
# wider than a disc of angular radius a where 1 / s >= WIDE_LOBE_DISC_VARIANCE * a^2 (the disc's own
# variance, a^2 / 4), and then its term is in closed form.
WIDE_LOBE_DISC_VARIANCE = 0.25

_PREFIXES = ((LightingBuffer, "BUF"), (LightingTexture, "TEX"), (GeometryTexture, "TEX"), (EdgeTexture, "TEX_AA"),
             (Image, "IMG"),
             (PEMBuffer, "BUF_PEM"), (NormalsBuffer, "BUF_NORMALS"), (ProbeBuffer, "BUF_PROBE"), (Mode, "MODE"),
             (LightKind, "KIND"))


def glsl_defines() -> dict[str, str]:
    """Every name of the contract as a GLSL #define (shaders.compose prepends them to every program)."""
    out: dict[str, str] = {}
    for enum, prefix in _PREFIXES:
        for member in enum:
            out[f"{prefix}_{member.name}"] = str(int(member))
    out["N_LIGHT_KINDS"] = str(N_LIGHT_KINDS)
    out["CONVEX_SURFACE"] = str(CONVEX_SURFACE)
    out["MESH_ID_STRIDE"] = str(MESH_ID_STRIDE)
    out["MAX_SHEET_MESHES"] = str(MAX_SHEET_MESHES)
    out["ALPHA_MAP_FRACTION"] = repr(float(ALPHA_MAP_FRACTION))
    out["WIDE_LOBE_DISC_VARIANCE"] = repr(float(WIDE_LOBE_DISC_VARIANCE))
    return out
