"""`garment-render` command line. The flag names of `render` are a contract users' scripts rely on."""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from . import config
from .aovs import exr_channels, parse_aovs
from .config import RETIRED
from .errors import InvalidInputError, RenderError
from .presets import PRESET_NAMES, resolve
from .presets import frame_settings as presets_frame_settings
from .presets import pem_settings as presets_pem_settings
from .shading.fields import FIELDS as GARMENT_FIELDS
from .shading.fields import MODEL_DOC, fields_of
from .shading.fields import MODELS as MATERIAL_MODELS
from .shading.tonemap import DEFAULT_CURVE, ToneCurve
from .views import VIEW_NAMES


def _floats(n: int):
    def parse(text: str) -> tuple:
        try:
            vals = tuple(float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}") from None
        if len(vals) == 1 and n == 3:
            vals = vals * 3
        if len(vals) != n:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
        return vals
    return parse


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 512x512, got {text!r}") from None
    return w, h


class _Retired(argparse.Action):
    """A flag of a setting that went: refused with what replaced it (config.RETIRED)."""

    def __init__(self, option_strings, dest, reason: str = "", **kw):
        super().__init__(option_strings, dest, nargs="?", help=argparse.SUPPRESS, **kw)
        self.reason = reason

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"{option_string}: {self.reason}; leave the flag out")


# The flags `--help` lists (the scripts' contract and the few a user reasons about); `--help-all`
# lists the rest too (docs/cli.md is generated from it).
COMMON_FLAGS = {"--env", "--env-rotation", "--mesh", "--up", "--mesh-scale", "--albedo", "--specular", "--glossiness", "--body-albedo",
                "--camera-eye", "--camera-target", "--fov", "--preset", "--frame-budget-ms", "--error-budget",
                "--lights", "--shadow-size", "--contact-shadow-texels", "--size", "--out", "--exr", "--timings",
                "--background", "--frames", "--topology", "--body", "--spp", "--seed", "--help", "--help-all"}


def _common_help_only(p: argparse.ArgumentParser) -> None:
    """Hide the flags outside COMMON_FLAGS from `--help` (they still parse)."""
    for action in p._actions:   # argparse keeps no public list of a parser's actions
        if action.option_strings and not COMMON_FLAGS & set(action.option_strings):
            action.help = argparse.SUPPRESS
    for group in p._action_groups:
        group.description = None


def _option_flag(group, name: str, registry_default: bool = True) -> None:
    """The flag of an option no preset chooses (config.OPTIONS): its choices or range, doc and default
    (registry_default False: None, for a caller that resolves it itself)."""
    opt = config.OPTION[name]
    default = opt.default if registry_default else None
    typ = float if opt.type is float else str

    def parse(text: str):
        try:
            return opt.check(typ(text))
        except (ValueError, InvalidInputError) as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    group.add_argument("--" + name.replace("_", "-"), type=parse if opt.choices is None else str, choices=opt.choices,
                       default=default, help=f"{opt.doc}; {opt.limits()} (default: {opt.default})")


def add_scene_arguments(p: argparse.ArgumentParser) -> None:
    """Scene, quality and output flags shared by `render` and the commands built on it."""
    g = p.add_argument_group("scene")
    g.add_argument("--env", type=Path, help="environment map (.exr, .hdr); default: bundled studio")
    _option_flag(g, "layout")
    g.add_argument("--repair", action="store_true", help="replace NaN/Inf/negative texels instead of failing")
    g.add_argument("--env-rotation", type=float, default=0.0, metavar="DEG",
                   help="the map turned about the up axis, counter-clockwise")
    g.add_argument("--mesh", type=Path, action="append", default=[],
                   help="mesh file (PLY/OBJ/GLB); the first is the garment, others (e.g. the body) follow; "
                        "default: the bundled dress, draped on a mannequin over a floor")
    g.add_argument("--up", type=_per_mesh(str, "y or z", ("y", "z")), default=("y",),
                   metavar="y|z", help="mesh files' up axis, or one a mesh: y,z")
    g.add_argument("--mesh-scale", type=_per_mesh(float, "a positive number"), default=(1.0,),
                   metavar="S", help="mesh files' scale (0.01: cm), or one a mesh")
    g.add_argument("--model", choices=list(MATERIAL_MODELS),
                   help="garment material model: " + MODEL_DOC + "; default: a glTF garment's own material, else phong")
    for f in GARMENT_FIELDS:   # the material registry's values (renderer/shading/fields.py)
        g.add_argument(f.flag, type=_floats(3) if f.kind == "colour" else float, default=f.garment_default,
                       help=f"garment, {'/'.join(f.models)}: {f.limits().removesuffix(', or one per vertex')}")
    g.add_argument("--material", type=Path,
                   help="garment material from a TOML or JSON file of Material fields (model and the flags' "
                        "values above, e.g. sheen_colour), a glTF/GLB file's "
                        "material (metallic-roughness, its textures, KHR_materials_sheen), or a U3M fabric (.u3m "
                        "with its images, .u3ma; its textures at their physical size: docs/u3m.md); replaces the "
                        "flags above")
    g.add_argument("--uv-scale", type=_floats(2), metavar="SU,SV",
                   help="metres of the garment a unit of its u and v span, for a U3M fabric's textures (default: "
                        "measured on the mesh, its triangles' 3D size against their UV size)")
    g.add_argument("--body-albedo", type=_floats(3), default=(0.55, 0.5, 0.45), help="body diffuse reflectance r,g,b")
    g.add_argument("--camera-eye", type=_floats(3), help="camera position x,y,z (default: framing the scene from +Z)")
    g.add_argument("--camera-target", type=_floats(3), help="point the camera looks at x,y,z")
    g.add_argument("--fov", type=float, default=35.0, help="vertical field of view, degrees")
    q = p.add_argument_group("quality")
    q.add_argument("--preset", choices=PRESET_NAMES, default="balanced",
                   help="quality preset (renderer/presets/*.toml; default balanced)")
    q.add_argument("--frame-budget-ms", type=float, help="choose the most accurate measured setting within this time")
    q.add_argument("--error-budget", type=float, help="choose the fastest measured setting within this rel. RMSE")
    # Every quality setting of renderer/config.py, in its order; None: the preset's (or budget's) value.
    for st in config.SETTINGS:
        flag = "--" + st.name.replace("_", "-")
        text = st.doc + ("" if st.type is bool else f"; {st.limits()}") + " (default: the preset's)"
        if st.type is bool:
            q.add_argument(flag, action=argparse.BooleanOptionalAction, help=text)
        else:
            q.add_argument(flag, type=st.type if st.choices is None else str, choices=st.choices, help=text)
    _option_flag(q, "filter", registry_default=False)   # None: a budget's measured filter, else the registry's
    q.add_argument("--levels", type=int, help="MIP levels to build (default: the full chain)")
    _option_flag(q, "bleed_reduction")
    _option_flag(q, "mode")
    for name, reason in RETIRED.items():
        flag = name.replace("_", "-")
        q.add_argument(f"--{flag}", f"--no-{flag}", action=_Retired, reason=reason, dest=f"retired_{name}")
    o = p.add_argument_group("output")
    o.add_argument("--size", type=_size, default=(512, 512), help="image size WxH (default 512x512)")
    o.add_argument("--out", type=Path, help="tone-mapped sRGB PNG")
    o.add_argument("--exr", type=Path, help="linear HDR EXR (RGBA float32)")
    o.add_argument("--aov", metavar="PASSES", help="passes beside the image in the EXR (render: --exr; sequence: "
                   "--exr-frames), comma-separated: depth (Z), normal (N.X/Y/Z), albedo (albedo.R/G/B), id "
                   "(0 background, 1 garment, 2.. the other meshes)")
    o.add_argument("--timings", type=Path, help="per-stage timings JSON")
    o.add_argument("--no-cache", action="store_true",
                   help="build the PEM set anew, and keep it out of the cache folder ($GARMENT_RENDER_CACHE_DIR, "
                        "else ~/.cache/garment-render: the PEM sets and cubes of the maps rendered before, the "
                        "mesh files read before)")
    o.add_argument("--exposure", type=float, help="exposure in EV (default: automatic)")
    o.add_argument("--tone", default=DEFAULT_CURVE.value, choices=[c.value for c in ToneCurve],
                   help=f"tone curve of the PNG (default {DEFAULT_CURVE.value}: it keeps base colours)")
    o.add_argument("--background", default="env", choices=["env", "black", "shadow-catcher"],
                   help="the map, nothing, or the floor's shadows alone")


def resolve_quality(args) -> dict:
    """Quality knobs (`renderer.presets.resolve`): a budget (chosen from the measured table), else the
    preset, over the defaults; explicit flags override all. The result says where they came from,
    and which PEM filter: --filter, else the budget's measured one, else sqrt-cosine. A budget's
    result names the GL renderer its table was measured on ("measured_on"): `check_budget_device`
    holds it against the renderer the frames run on, once there is one."""
    return resolve(args.preset, {k: getattr(args, k) for k in config.NAMES}, frame_budget_ms=args.frame_budget_ms,
                   error_budget=args.error_budget, filter=args.filter, size=tuple(args.size)).as_dict()


def check_budget_device(q: dict, renderer) -> None:
    """A budget's settings only on the device they were measured on (before any work on it)."""
    from .presets.budget import check_device

    if "measured_on" in q:
        check_device(q["measured_on"], renderer.gl.renderer_name)


def frame_settings(args, q: dict):
    """The frame's settings from the resolved quality (`resolve_quality`) and the output flags."""
    from .settings import Background, ShadingMode

    w, h = args.size
    return presets_frame_settings(q, w, h, bleed_reduction=args.bleed_reduction, mode=ShadingMode(args.mode),
                                  background=Background(args.background),
                                  environment_rotation_deg=getattr(args, "env_rotation", 0.0),
                                  aovs=parse_aovs(getattr(args, "aov", None)))


def shadow_catcher(args, meshes: list, materials: list, casters: list) -> int | None:
    """The floor a shadow-catcher frame draws as its shadows (--background shadow-catcher): the first
    mesh that casts nothing (a floor), else a ground plane added at the meshes' lowest point; None for
    the other backgrounds. `meshes`, `materials` and `casters` grow by the plane."""
    from .procedural import floor_under
    from .shading.material import Material

    if args.background != "shadow-catcher":
        return None
    for k, casts in enumerate(casters):
        if k and not casts:
            return k
    meshes.append(floor_under(meshes))
    materials.append(Material((0.5, 0.5, 0.5), 0.0, 0.3))
    casters.append(False)
    return len(meshes) - 1


def pem_settings(args, q: dict, materials):
    """The PEM set's settings; with needed levels only the levels the materials' glossiness reads."""
    return presets_pem_settings(q, q["filter"], args.levels, materials)


# The bundled default scene's floor: a matte mid grey.
FLOOR_MATERIAL = (0.45, 0.45, 0.45), 0.0, 0.3


MATERIAL_FIELDS = ("model",) + tuple(f.name for f in GARMENT_FIELDS)


def garment_material(args, garment=None):
    """The garment's Material: from --material (a TOML or JSON table of MATERIAL_FIELDS, a glTF file's,
    a U3M fabric's on `garment`, the garment's Mesh) or the flags."""
    from .shading.gltf import material_from_gltf
    from .shading.material import Material

    path = getattr(args, "material", None)
    meshes = getattr(args, "mesh", None) or []
    if path is None and args.model is None and meshes and meshes[0].suffix.lower() in (".glb", ".gltf"):
        material = material_from_gltf(meshes[0])   # a garment exported with its fabric renders with it
        if material is not None:
            return material
    if path is None:
        model = args.model or "phong"
        return Material(model=model, **{f.name: getattr(args, f.name) for f in fields_of(model)})
    return material_file(path, garment, getattr(args, "uv_scale", None))


def is_u3m(path: Path) -> bool:
    """A U3M fabric: named so, or a zip archive (a .u3ma under another name)."""
    if path.suffix.lower() in (".u3m", ".u3ma"):
        return True
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False


def material_file(path: Path, garment=None, uv_scale=None):
    """A Material from a TOML or JSON table of MATERIAL_FIELDS, from a glTF/GLB file's material, or from
    a U3M fabric on `garment` (its Mesh: the textures' physical size is measured on it, or `uv_scale`)."""
    from .shading.gltf import material_from_gltf
    from .shading.material import Material

    if is_u3m(path):
        from .u3m import load_u3m, material_from_u3m

        if garment is None:   # pragma: no cover - every caller has the garment
            raise InvalidInputError(f"'{path}': a U3M fabric needs the garment's mesh to place its textures")
        material, warnings = material_from_u3m(load_u3m(path), garment, uv_scale=uv_scale)
        for line in warnings:
            print(f"garment-render: warning: {path.name}: {line}", file=sys.stderr)
        return material
    if path.suffix.lower() in (".glb", ".gltf"):
        material = material_from_gltf(path)
        if material is None:
            raise InvalidInputError(f"'{path}' names no material: give its meshes one, or pass --material with a "
                                    f"TOML/JSON file of {', '.join(MATERIAL_FIELDS)}, or the --model flags")
        return material
    try:
        text = path.read_text()
        if path.suffix.lower() == ".toml":
            import tomllib
            fields = tomllib.loads(text)
        else:
            fields = json.loads(text)
    except (OSError, ValueError) as e:
        raise InvalidInputError(f"cannot read material file '{path}': {e}") from None
    if not isinstance(fields, dict):
        raise InvalidInputError(f"material file '{path}' must hold a table of {', '.join(MATERIAL_FIELDS)}")
    unknown = sorted(set(fields) - set(MATERIAL_FIELDS))
    if unknown:
        raise InvalidInputError(f"material file '{path}': unknown field(s) {', '.join(unknown)}; "
                                f"the fields are {', '.join(MATERIAL_FIELDS)}")
    material = Material(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
    material.vertex_arrays(1)
    material.pbr_arrays(1)
    return material


@functools.lru_cache(maxsize=2)
def _source_image(path: str | None) -> np.ndarray:
    """The environment's source pixels, read once per process (the PEMs' cube and the background's
    are made from them); None: the bundled procedural studio."""
    from .envmap import read_hdr_image, studio_environment

    img = read_hdr_image(path) if path is not None else studio_environment(1024)
    img.setflags(write=False)
    return img


def cache_folder(args, kind: str):
    """The folder of the user's cache (user_cache.py) where `kind` is kept ("cubes": resampled maps,
    "meshes": mesh files' parses), None with --no-cache."""
    if getattr(args, "no_cache", False):
        return None
    from .user_cache import user_cache_dir

    return user_cache_dir(kind)


def _per_mesh(kind, what: str, choices: tuple | None = None):
    """An argparse type: one value, or a comma-separated value a mesh (a tuple either way)."""
    def parse(text: str) -> tuple:
        try:
            values = tuple(kind(v.strip()) for v in text.split(","))
        except ValueError:
            values = ()
        if not values or any((choices is not None and v not in choices) or (kind is float and not v > 0)
                             for v in values):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {what}, or one a mesh separated by commas")
        return values
    return parse


def per_mesh(values: tuple, n: int, flag: str) -> list:
    """A flag's values for n meshes: one for all, or one each."""
    if len(values) == 1:
        return list(values) * n
    if len(values) != n:
        raise InvalidInputError(f"{flag} gives {len(values)} values for {n} meshes: give one, or one a mesh")
    return list(values)


def one_value(values: tuple, flag: str):
    """A flag's one value where a command has no meshes to give one each (a sequence's frames)."""
    if len(values) != 1:
        raise InvalidInputError(f"{flag} takes one value here, got {len(values)}")
    return values[0]


# The sizes' ratio beyond which meshes of one scene are taken to be in different units (a garment in
# centimetres beside a body in metres is 100 times its size).
UNITS_RATIO = 20.0


def mesh_warnings(meshes, names: list[str]) -> list[str]:
    """What a scene's meshes suggest was meant otherwise: meshes of very different sizes (one in
    centimetres, one in metres: the small one vanishes) and a scene far flatter along Y than along the
    horizontal (a Z-up file read as Y-up: the garment lies on its back)."""
    out = []
    sizes = [float(np.linalg.norm(m.positions.max(axis=0) - m.positions.min(axis=0))) for m in meshes]
    big, small = int(np.argmax(sizes)), int(np.argmin(sizes))
    if sizes[small] > 0 and sizes[big] / sizes[small] > UNITS_RATIO:
        out.append(f"{names[big]} is {sizes[big] / sizes[small]:.0f} times the size of {names[small]}: meshes in "
                   "different units? give each its scale (--mesh-scale 0.01,1: the first in centimetres)")
    everything = np.concatenate([m.positions for m in meshes])
    extent = everything.max(axis=0) - everything.min(axis=0)
    if extent[1] < 0.5 * max(extent[0], extent[2]):
        out.append(f"the meshes are {extent[1]:.3g} tall (Y) and {max(extent[0], extent[2]):.3g} across: a Z-up file "
                   "read as Y-up lies on its back (--up z, or one a mesh: --up y,z)")
    return out


def load_scene_inputs(args, face_size: int):
    """Environment map, meshes, materials and which meshes cast shadows, from the arguments (or
    the bundled defaults: the studio, and the draped dress on the mannequin over a floor that only
    receives shadows, `procedural.default_scene`)."""
    from .envmap import environment_from_array
    from .mesh_cache import load_mesh_cached
    from .procedural import default_scene
    from .shading.material import Material

    if args.env is not None:
        env = environment_from_array(_source_image(str(args.env)), args.layout, face_size, name=Path(args.env).stem,
                                     repair=args.repair, cube_cache=cache_folder(args, "cubes"))
    else:
        env = environment_from_array(_source_image(None), "latlong", face_size, name="studio (bundled)",
                                     cube_cache=cache_folder(args, "cubes"))
    body = Material(args.body_albedo, 0.1, 0.3)
    if args.mesh:
        ups, scales = per_mesh(args.up, len(args.mesh), "--up"), per_mesh(args.mesh_scale, len(args.mesh), "--mesh-scale")
        meshes = [load_mesh_cached(p, up=up, scale=scale, cache=cache_folder(args, "meshes"))
                  for p, up, scale in zip(args.mesh, ups, scales)]
        for line in mesh_warnings(meshes, [Path(p).name for p in args.mesh]):
            print(f"garment-render: warning: {line}", file=sys.stderr)
        garment = garment_material(args, meshes[0])
        return env, meshes, [garment] + [body] * (len(meshes) - 1), [True] * len(meshes)
    meshes, casters = default_scene()
    return env, meshes, [garment_material(args, meshes[0]), body, Material(*FLOOR_MATERIAL)], casters


def background_source(args, env):
    """What the background is drawn from (`shading.background.background_source`); None without a
    background (--background black)."""
    if args.background != "env":
        return None
    from .shading.background import background_source as source

    img = _source_image(None if args.env is None else str(args.env))
    return source(img, env.layout, repair=args.repair, name=env.name, cube_cache=cache_folder(args, "cubes"))


def camera_from_args(args, framed_meshes, aspect: float):
    """--camera-eye and --camera-target (both, with --fov), else the renderer's default framing of
    `framed_meshes` with --fov."""
    from .camera import Camera, frame_meshes

    if args.camera_eye is not None or args.camera_target is not None:
        if args.camera_eye is None or args.camera_target is None:
            raise SystemExit("error: give both --camera-eye and --camera-target")
        return Camera(args.camera_eye, args.camera_target, fov_y_deg=args.fov)
    return frame_meshes(framed_meshes, aspect, args.fov)


def view_cameras(args, camera):
    """--turntable N or --views a,b: `camera` (the scene's, from the flags) turned or placed around
    its target; [camera] alone when neither is given."""
    from .views import named_views, turntable

    if args.turntable is not None and args.views:
        raise InvalidInputError("give --turntable or --views, not both")
    if args.turntable is not None:
        return turntable(camera, args.turntable)
    return named_views(camera, args.views) if args.views else [camera]


def _write_views(args, frames, n_variants: int) -> None:
    """Each view beside --out (NAME_v00_c0.png: view, colourway) and their contact sheet as --out
    (one row per view, one column per colourway; a turntable alone in rows of up to 6; each tile
    labelled), all at the first view's exposure."""
    from PIL import Image

    from .shading.tonemap import auto_exposure_ev, encode_rgba8, srgb_pnginfo, write_png
    from .views import contact_sheet, label_tiles, sheet_columns, view_labels

    if not args.out:
        return
    exposure = args.exposure
    if exposure is None:
        exposure = auto_exposure_ev(frames[0].image[..., :3], frames[0].image[..., 3])
    images = [png_image(f.image, args.background == "env") for f in frames]
    for k, im in enumerate(images):
        view, colourway = divmod(k, n_variants)
        write_png(args.out.with_name(f"{args.out.stem}_v{view:02d}_c{colourway}.png"), im, exposure, ToneCurve(args.tone))
    columns = sheet_columns(len(images), n_variants)
    colourways = ["garment"] + [p.stem for p in args.colourway]
    labels = view_labels(len(images) // n_variants, args.views, colourways)
    sheet = encode_rgba8(contact_sheet(images, columns), exposure, ToneCurve(args.tone))
    Image.fromarray(label_tiles(sheet, labels, images[0].shape[:2], columns)).save(args.out, format="PNG",
                                                                                  pnginfo=srgb_pnginfo())


def png_image(img: np.ndarray, opaque: bool) -> np.ndarray:
    """The image to tone-map into a PNG: alpha is coverage, or 1 where the map fills the background."""
    if not opaque:
        return img
    out = img.copy()
    out[..., 3] = 1.0
    return out


def pem_set(r, env, settings, args):
    """`env`'s PEM set for `settings`: from the user's cache folder (user_cache.py), else built and
    stored there for the next command (the light decomposition is in it); built and not stored with
    --no-cache. Returns (the set, where it came from: "disk" or "built")."""
    pems = r.pem_set(env, settings, cache=not getattr(args, "no_cache", False))
    return pems, pems.source


def _pem_line(pems, source: str) -> str:
    if source == "built":
        return f"PEM build {pems.build_ms:.0f} ms"
    return f"PEM set from the cache folder ({pems.build_ms:.0f} ms)"


def check_outputs(args) -> None:
    """Before any work: a render that would write nothing, or into a folder that is not there, is
    refused with the flag named (InvalidInputError)."""
    given = {flag: getattr(args, flag.lstrip("-")) for flag in ("--out", "--exr", "--timings")}
    if all(path is None for path in given.values()):
        raise InvalidInputError(f"{args.command} would write nothing: name --out (a PNG), --exr or --timings")
    for flag, path in given.items():
        if path is not None and not Path(path).parent.is_dir():
            raise InvalidInputError(f"{flag} {path}: the folder {Path(path).parent} does not exist")


def cmd_render(args) -> int:
    from .envmap import write_exr
    from .renderer import Renderer
    from .shading.tonemap import auto_exposure_ev, write_png

    check_outputs(args)
    if args.aov and not args.exr:
        raise InvalidInputError("--aov writes its passes into the EXR: name --exr too")
    t_start = time.perf_counter()
    q = resolve_quality(args)
    env, meshes, materials, casters = load_scene_inputs(args, q["face_size"])
    catcher = shadow_catcher(args, meshes, materials, casters)
    t_loaded = time.perf_counter()
    w, h = args.size
    settings = frame_settings(args, q)
    camera = camera_from_args(args, [m for m, c in zip(meshes, casters) if c], w / h)   # a floor is not framed
    cameras = view_cameras(args, camera)
    colourways = [material_file(path, meshes[0], args.uv_scale) for path in args.colourway]
    bg_source = background_source(args, env)
    with Renderer() as r:
        check_budget_device(q, r)
        pems, pem_source = pem_set(r, env, pem_settings(args, q, materials + colourways), args)
        scene = r.create_scene(meshes, materials, casters=casters, catcher=catcher)
        background = r.background_map(bg_source) if bg_source is not None else None
        try:
            variants = [0] + [scene.add_variant([c] + [None] * (len(meshes) - 1)) for c in colourways]
            frames = r.render_views(scene, pems, settings, cameras, background=background, variants=variants)
        finally:
            if background is not None:
                background.release()
            scene.release()
            pems.release()
        gl_info = r.gl.info()
    frame = frames[0]
    if len(frames) > 1:
        _write_views(args, frames, len(variants))
    img = frame.image
    if args.exr:
        write_exr(args.exr, img, channels=exr_channels(frame.aovs))
    exposure = args.exposure
    if exposure is None:
        exposure = auto_exposure_ev(img[..., :3], img[..., 3])
    if args.out and len(frames) == 1:
        write_png(args.out, png_image(img, args.background == "env"), exposure, ToneCurve(args.tone))
    report = {"timings": frame.timings, "settings": frame.settings, "quality": q, "exposure_ev": exposure,
              "pem_source": pem_source, "pem_ms": pems.build_ms,
              "environment": {"name": env.name, "layout": env.layout.value, "face_size": q["face_size"],
                              "texel_report": env.texel_report.as_dict() if env.texel_report else None},
              "meshes": [{"name": m.name, "vertices": int(m.positions.shape[0]), "faces": int(m.faces.shape[0])}
                         for m in meshes],
              "views": [{"camera": f.settings["camera"], "timings": f.timings} for f in frames[1:]],
              "gl": gl_info, "load_ms": (t_loaded - t_start) * 1e3,
              "total_ms": (time.perf_counter() - t_start) * 1e3}
    if args.timings:
        args.timings.write_text(json.dumps(report, indent=2, default=float))
    stages = ", ".join(f"{k} {v:.1f} ms" for k, v in frame.timings["wall_ms"].items())
    print(f"rendered {w}x{h}, {q['lights']} lights, {_pem_line(pems, pem_source)}; frame: {stages}")
    return 0


def cmd_sequence(args) -> int:
    """Render every frame of a mesh sequence with one PEM set and one scene (only positions change)."""
    from .envmap import write_exr
    from .mesh import load_mesh
    from .renderer import Renderer
    from .sequence import load_sequence, to_meshes
    from .shading.material import Material
    from .shading.tonemap import auto_exposure_ev, to_png_bytes

    if args.out is None:
        raise SystemExit("error: sequence needs --out DIR (the folder for the numbered frames)")
    if args.aov and not args.exr_frames:
        raise InvalidInputError("--aov writes its passes into each frame's EXR: name --exr-frames too")
    q = resolve_quality(args)
    args.mesh = list(args.body or [])
    env, extra_meshes, materials, _ = load_scene_inputs(args, q["face_size"])
    if not args.body:
        extra_meshes = []
    # The first material is the garment's, the last the body's (load_scene_inputs' convention).
    materials = [materials[0]] + [Material(args.body_albedo, 0.1, 0.3)] * len(extra_meshes)
    up, scale = one_value(args.up, "--up"), one_value(args.mesh_scale, "--mesh-scale")
    topology = load_mesh(args.topology, up=up, scale=scale) if args.topology else None
    seq = load_sequence(args.frames, up=up, scale=scale, garment=args.garment)
    garment, positions = to_meshes(seq, topology, up=up, scale=scale)
    # A USD stage's still meshes (the body) join the scene with the body's material.
    extra_meshes = extra_meshes + list(seq.extras)
    materials = materials + [Material(args.body_albedo, 0.1, 0.3)] * len(seq.extras)
    meshes = [garment] + extra_meshes
    w, h = args.size
    # Frame the whole sequence, so the camera does not move with the cloth.
    lo = positions.reshape(-1, 3).min(axis=0)
    hi = positions.reshape(-1, 3).max(axis=0)
    box = type(garment).from_arrays(np.array([lo, hi, hi]), np.array([[0, 1, 2]]))
    camera = camera_from_args(args, [box] + extra_meshes, w / h)
    settings = frame_settings(args, q)
    catcher = None
    if args.background == "shadow-catcher":   # a floor under the whole sequence catches its shadows
        from .procedural import floor_under

        meshes.append(floor_under([box] + extra_meshes))
        materials = materials + [Material((0.5, 0.5, 0.5), 0.0, 0.3)]
        catcher = len(meshes) - 1
    args.out.mkdir(parents=True, exist_ok=True)
    timings, previews = [], []
    exposure = args.exposure
    bg_source = background_source(args, env)
    with Renderer() as r:
        check_budget_device(q, r)
        pems, pem_source = pem_set(r, env, pem_settings(args, q, materials), args)
        scene = r.create_scene(meshes, materials, casters=[k != catcher for k in range(len(meshes))],
                               catcher=catcher)
        background = r.background_map(bg_source) if bg_source is not None else None
        try:
            for k in range(seq.n_frames):
                # The file's own other meshes move with it where they have frames (a body in a USD stage).
                moving = [None if f is None else f[k] for f in seq.extra_frames]
                frame = r.render(scene, pems, settings, camera,
                                 positions=[positions[k]] + [None] * (len(extra_meshes) - len(moving)) + moving
                                 + [None] * (catcher is not None), background=background)
                img = frame.image
                if exposure is None:  # fixed from the first frame, so the sequence does not flicker
                    exposure = auto_exposure_ev(img[..., :3], img[..., 3])
                png = png_image(img, args.background == "env")
                (args.out / f"frame_{k:04d}.png").write_bytes(to_png_bytes(png, exposure, ToneCurve(args.tone)))
                if args.exr_frames:
                    write_exr(args.out / f"frame_{k:04d}.exr", img, channels=exr_channels(frame.aovs))
                timings.append(frame.timings)
                previews.append(k)
                done = int(30 * (k + 1) / seq.n_frames)
                print(f"\r[{'#' * done}{'.' * (30 - done)}] {k + 1}/{seq.n_frames} frames, "
                      f"{frame.timings['frame_wall_ms']:.0f} ms", end="", file=sys.stderr, flush=True)
            print(file=sys.stderr)
        finally:
            if background is not None:
                background.release()
            scene.release()
            pems.release()
    _write_preview(args.out, seq.n_frames)
    ms = np.array([t["frame_wall_ms"] for t in timings])
    summary = {"frames": seq.n_frames, "frame_ms_median": float(np.median(ms)), "frame_ms_p90": float(np.quantile(ms, 0.9)),
               "pem_build_ms": pems.build_ms, "pem_source": pem_source, "quality": q, "exposure_ev": exposure, "per_frame": timings}
    (args.out / "timings.json").write_text(json.dumps(summary, indent=1, default=float))
    print(f"rendered {seq.n_frames} frames to {args.out}: median {np.median(ms):.0f} ms per frame "
          f"(p90 {np.quantile(ms, 0.9):.0f} ms), {_pem_line(pems, pem_source)} once; preview.gif, timings.json")
    return 0


def _write_preview(out: Path, n_frames: int, max_side: int = 256) -> None:
    """An animated GIF of the numbered PNGs, at most max_side pixels wide."""
    from PIL import Image

    frames = []
    for k in range(n_frames):
        im = Image.open(out / f"frame_{k:04d}.png").convert("RGB")
        im.thumbnail((max_side, max_side))
        frames.append(im)
    frames[0].save(out / "preview.gif", save_all=True, append_images=frames[1:], duration=1000 // 24, loop=0)


def cmd_reference(args) -> int:
    """The Monte Carlo ground truth of the same scene, with the same output flags as `render`."""
    from .envmap import write_exr
    from .reference import render_reference
    from .shading.tonemap import auto_exposure_ev, write_png

    check_outputs(args)
    if getattr(args, "aov", None):
        raise InvalidInputError("--aov: the reference writes the image alone (render writes the passes)")
    face = args.face_size or 256  # the reference reads the map itself: a fine cube by default
    env, meshes, materials, casters = load_scene_inputs(args, face)
    w, h = args.size
    camera = camera_from_args(args, [m for m, c in zip(meshes, casters) if c], w / h)
    t0 = time.perf_counter()
    ref = render_reference(meshes, materials, env.cube, camera, w, h, args.spp, seed=args.seed,
                           pixel_samples=args.pixel_samples)
    wall = time.perf_counter() - t0
    # As the renderer draws it: over black, the surfaces' colour premultiplied by their coverage.
    img = ref.foreground if args.background == "black" else ref.image
    if args.exr:
        write_exr(args.exr, img)
    exposure = args.exposure if args.exposure is not None else auto_exposure_ev(img[..., :3], img[..., 3])
    if args.out:
        write_png(args.out, png_image(img, args.background == "env"), exposure, ToneCurve(args.tone))
    report = {"spp": int(ref.spp), "pixel_samples": args.pixel_samples, "seed": args.seed, "wall_s": wall, "rays_cast": int(ref.rays_cast),
              "noise_floor_rel": float(ref.noise_floor_rel()), "environment": env.name, "face_size": face,
              "background": args.background,
              "camera": {"eye": list(camera.eye), "target": list(camera.target), "fov_y_deg": camera.fov_y_deg}}
    if args.timings:
        args.timings.write_text(json.dumps(report, indent=2))
    print(f"reference {w}x{h}, {args.spp} spp: {wall:.1f} s, {ref.rays_cast / max(wall, 1e-9) / 1e6:.2f} M rays/s, "
          f"relative noise (standard error / mean) {ref.noise_floor_rel():.4f}")
    return 0


# Ray's switch (read when Ray is imported) that makes a node's address the loopback, as Ray does on
# macOS and Windows; `serve --ray` sets it for a local instance.
LOCAL_RAY_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def cmd_serve(args) -> int:
    # The one place the command line reaches the service layer; the renderer's library code never
    # imports it (the dependency arrow is service -> renderer), hence importlib.
    if args.ray:
        if args.workers != 1:
            raise InvalidInputError("--workers is for uvicorn's processes; with --ray give --replicas")
        if args.address is None and not os.environ.get("RAY_ADDRESS"):
            # A local instance: Ray takes the node's address from this switch when it is imported, and
            # with the loopback as that address its GCS, raylet, workers and agents listen on 127.0.0.1
            # alone (on every interface otherwise). Serve's proxy still binds --host.
            os.environ.setdefault(LOCAL_RAY_SWITCH, "0")
        try:
            importlib.import_module("service.ray_serve").run(args.host, args.port, args.replicas, args.address,
                                                             args.gpus_per_replica)
        except ValueError as e:   # a setting the replicas could not start with
            raise InvalidInputError(str(e)) from None
        return 0
    importlib.import_module("service.main").serve(args.host, args.port, workers=args.workers, log_level=args.log_level)
    return 0


def cmd_devices(args) -> int:
    from .gpu.context import GLContext
    from .gpu.egl_devices import cuda_visible, egl_devices, egl_index_for_gpu

    devices = egl_devices()
    for d in devices:
        print(d.describe())
    if args.gpu is not None:
        index, how = egl_index_for_gpu(args.gpu, devices, cuda_visible())
        print(f"GPU {args.gpu}: EGL device {index} ({how})")
        gl = GLContext(device_index=index)
        print(f"  renders on {gl.renderer_name}, OpenGL {gl.version}")
        gl.release()
    return 0


def build_parser(show_all: bool = True) -> argparse.ArgumentParser:
    """The command line; `show_all` False: `render`, `sequence` and `reference` list only COMMON_FLAGS
    in their help (what `--help` shows; `--help-all` shows everything). The product's commands (render,
    sequence, reference, serve, devices) and the lab's (bench, speed, error-split and the figures)."""
    p = argparse.ArgumentParser(prog="garment-render", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    _scene_commands(sub, show_all)
    _serve_command(sub)
    _devices_command(sub)
    lab_commands(sub)
    return p


def _scene_commands(sub, show_all: bool) -> None:
    """render, sequence and reference: a scene's flags each (add_scene_arguments) and their own."""
    r = sub.add_parser("render", help="render one frame")
    add_scene_arguments(r)
    v = r.add_argument_group("views and colourways")
    v.add_argument("--turntable", type=int, metavar="N",
                   help="N views: the camera turned about its target in equal steps, sharing one shadow pass; "
                        "--out is their contact sheet and each view is written beside it (NAME_v00_c0.png ...)")
    v.add_argument("--views", type=lambda t: [v.strip() for v in t.split(",") if v.strip()],
                   help="named views (" + ", ".join(VIEW_NAMES) + ") at the camera's distance from its target, "
                        "comma-separated, sharing one shadow pass")
    v.add_argument("--colourway", type=Path, action="append", default=[],
                   help="one more garment material (a --material file) rendered from the same frame, "
                        "sharing everything but shading; repeat for more")
    r.set_defaults(func=cmd_render)
    sq = sub.add_parser("sequence", help="render a mesh sequence (OBJ folder, .pc2, .mdd, .npz, USD, glTF) to "
                                         "numbered images")
    add_scene_arguments(sq)
    sq.add_argument("--frames", type=Path, required=True,
                    help="folder of .obj files, a .pc2/.mdd/.npz file, a USD stage (.usd/.usda/.usdc/.usdz) or a "
                         "glTF file with morph-target animation (.glb/.gltf): in the last two, the moving meshes are "
                         "the garment, the still ones the body")
    sq.add_argument("--topology", type=Path, help="mesh giving the faces (and UVs) of a point cache")
    sq.add_argument("--garment", metavar="GLOB",
                    help="a USD stage's or glTF file's garment: a glob over its meshes' paths or names (e.g. "
                         "'/World/Shirt*'); the other meshes are the body, moving where they have frames (default: "
                         "the meshes that move are the garment)")
    sq.add_argument("--body", type=Path, action="append", help="static meshes rendered with the garment")
    sq.add_argument("--exr-frames", action="store_true", help="also write a linear EXR per frame")
    sq.set_defaults(func=cmd_sequence)
    ref = sub.add_parser("reference", help="Monte Carlo ground truth of the same scene (embree ray casting)")
    add_scene_arguments(ref)
    ref.add_argument("--spp", type=int, default=256, help="samples per pixel (per technique)")
    ref.add_argument("--seed", type=int, default=0)
    ref.add_argument("--pixel-samples", type=int, default=4, metavar="K",
                     help="each pixel's area integrated over K x K jittered strata (the truth of an anti-aliased "
                          "frame; 1: one ray through the pixel's centre)")
    ref.set_defaults(func=cmd_reference)
    for scene_command in (r, sq, ref):
        scene_command.add_argument("--help-all", action="help", help="show every flag, the advanced ones too")
        if not show_all:
            _common_help_only(scene_command)


def _serve_command(sub) -> None:
    sv = sub.add_parser("serve", help="run the HTTP render service (uvicorn); settings: GARMENT_RENDER_* variables")
    sv.add_argument("--host", help="default: GARMENT_RENDER_HOST, else 127.0.0.1")
    sv.add_argument("--port", type=int, help="default: GARMENT_RENDER_PORT, else 8000")
    sv.add_argument("--workers", type=int, default=1, help="processes, each with its own GL context")
    sv.add_argument("--log-level", default="info")
    sv.add_argument("--ray", action="store_true",
                    help="serve as Ray Serve replicas of one deployment (pip install .[ray]; service/ray_serve.py): "
                         "scenes stay on the replica that holds them, sharing GARMENT_RENDER_STATE_DIR (a local "
                         "instance without it: a default the log names)")
    sv.add_argument("--replicas", type=int, default=2, help="with --ray: replicas, each a process with a GL context")
    sv.add_argument("--address", help="with --ray: a running Ray cluster (default: start a local Ray instance)")
    sv.add_argument("--gpus-per-replica", type=float, default=0.0,
                    help="with --ray: GPUs Ray gives each replica (its EGL device follows the one it gets)")
    sv.set_defaults(func=cmd_serve)


def _devices_command(sub) -> None:
    dv = sub.add_parser("devices", help="the EGL devices in moderngl's order, with the CUDA device each is, and "
                                       "which one a GPU number (as Ray and CUDA_VISIBLE_DEVICES give it) renders on")
    dv.add_argument("--gpu", type=int, help="also say which EGL device this GPU is, and open a context on it")
    dv.set_defaults(func=cmd_devices)


# The lab's commands (benchmarks and figures, lab/garment_lab): the garment-render-lab distribution adds
# them through this entry-point group; an install without it answers each with the line that installs it.
LAB_ENTRY_POINTS = "garment_render.commands"
LAB_COMMANDS = ("bench", "speed", "error-split", "lobes", "brdf-lobes", "area-lights")
LAB_INSTALL = "pip install ./lab (garment-render-lab, from a checkout; scripts/setup.sh installs it)"


def lab_commands(sub) -> None:
    """The subcommands other distributions add (`LAB_ENTRY_POINTS`: a function of the subparsers);
    without the lab, its commands each say how to install it."""
    from importlib.metadata import entry_points

    added = set(sub.choices)
    for ep in entry_points(group=LAB_ENTRY_POINTS):
        ep.load()(sub)
    if set(LAB_COMMANDS) <= set(sub.choices) - added:
        return
    for name in LAB_COMMANDS:
        if name not in sub.choices:
            p = sub.add_parser(name, help=f"one of the lab's benchmarks and figures, not installed: {LAB_INSTALL}")
            p.set_defaults(func=functools.partial(_lab_missing, name), lab_missing=True)   # its flags: any


def _lab_missing(name: str, args) -> int:
    print(f"garment-render: error: {name} is one of the lab's commands (benchmarks and figures), which this "
          f"install leaves out: {LAB_INSTALL}", file=sys.stderr)
    return 2


def cli_reference() -> str:
    """docs/cli.md: every command's `--help-all`, at a fixed width (tests/test_cli_reference.py
    checks the stored file against it)."""
    p = build_parser(show_all=True)
    out = ["# Command-line reference", "", "Generated from the parser (`renderer/cli.py`, `cli_reference`); "
           "`garment-render COMMAND --help` shows the common flags, `--help-all` all of them.", ""]
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        parser.formatter_class = lambda prog: argparse.HelpFormatter(prog, width=100, max_help_position=32)
        out += [f"## {name}", "", "```", parser.format_help().rstrip(), "```", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(show_all="--help-all" in argv)
    args, unknown = parser.parse_known_args(argv)
    if unknown and not getattr(args, "lab_missing", False):
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return args.func(args)
    except RenderError as exc:
        print(f"garment-render: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
