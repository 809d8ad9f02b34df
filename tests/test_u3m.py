"""The U3M reader (renderer/u3m): U3M 1.0 and 1.1 written by hand from the spec, as a document with its
folder and as an archive, with every kind of field; the spec's own example; and every kind of bad input,
each refused with one typed error that names the file and the field, in bounded time and memory."""

from __future__ import annotations

import io
import json
import os
import pickle
import struct
import time
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from u3m_files import (
    ADOBE_GAMMA,
    ADOBE_PRIMARIES,
    SRGB_PRIMARIES,
    color,
    color_texture,
    document,
    encode,
    icc_profile,
    image,
    normal,
    physics,
    png16,
    png_header_only,
    rgb_to_xyz,
    scalar,
    scalar_texture,
    tiff16,
    u3ma_bytes,
    visualisation,
    write_u3m,
    write_u3ma,
)

from renderer.errors import InvalidInputError, MaterialError
from renderer.shading.tonemap import srgb_eotf, srgb_oetf
from renderer.u3m import (
    FIELDS,
    BlendMode,
    ColorConstant,
    ColorTexture,
    Face,
    ImageKind,
    NormalConstant,
    NormalTexture,
    RepeatMode,
    ScalarConstant,
    ScalarTexture,
    U3MLimits,
    load_u3m,
    path_problem,
)
from renderer.u3m.document import SCHEMA_DIR, SCHEMA_FILES

SPEC = Path(__file__).resolve().parents[1].parent / "shared" / "specs" / "u3m"
RNG = np.random.default_rng(61)

# The bound for a hostile input is "refused in under 2 s with under 300 MB more memory"; the
# reader needs about 1 MB, and a bound of 64 MB also catches a read that reserves its cap up front.
REFUSE_S = 2.0
REFUSE_BYTES = 64 * 2**20


def spec_file(name: str) -> Path:
    path = SPEC / name
    if not path.exists():
        pytest.skip(f"needs the U3M spec's files ({path} not found; they live beside the repo in ../shared)")
    return path


# -- a fabric with every kind of field --------------------------------------------------------------

BASE_RGB = RNG.integers(0, 256, (6, 8, 3), dtype=np.uint8)              # 8-bit colour, no profile
ROUGH_16 = RNG.integers(0, 65536, (6, 8), dtype=np.uint16)              # 16-bit greyscale
NORMAL_16 = RNG.integers(0, 65536, (6, 8, 3), dtype=np.uint16)          # 16-bit RGB
ALPHA_RGBA = RNG.integers(0, 256, (5, 7, 4), dtype=np.uint8)            # 8-bit RGBA, averaged to one channel
SHEEN_JPEG = np.full((16, 16), 140, np.uint8)                           # greyscale JPEG
TINT_JPEG = np.full((16, 16, 3), (200, 120, 40), np.uint8)              # colour JPEG
ADOBE_RGB = (200, 100, 50)                                              # ICC-tagged colour


def fabric_images() -> dict[str, bytes]:
    return {"textures/base.png": encode(BASE_RGB),
            "textures/rough16.png": encode(ROUGH_16),
            "textures/normal16.png": png16(NORMAL_16),
            "textures/alpha.png": encode(ALPHA_RGBA),
            "textures/sheen.jpg": encode(SHEEN_JPEG, "JPEG", quality=95),
            "textures/tint.jpg": encode(TINT_JPEG, "JPEG", quality=95),
            "textures/wide gamut/adobe.png": encode(np.full((4, 4, 3), ADOBE_RGB, np.uint8), icc_profile=icc_profile())}


def fabric(version: str, back: bool = False) -> dict:
    """A front with a texture in every kind of field and image; in 1.1 a side too; the back null unless
    asked for (then a plain one)."""
    v = version
    front = visualisation(
        v,
        basecolor=color((0.5, 0.5, 0.5), color_texture(image("textures/base.png", v, 50.0, 37.5, rotation=30.0,
                                                             mode="mirror_x"), (1.0, 0.5, 0.25), "multiply")),
        subsurface_color=color((0.2, 0.2, 0.2), color_texture(image("textures/wide gamut/adobe.png", v, 10, 10),
                                                              (0.0, 0.5, 1.0), "divide")),
        roughness=scalar(0.6, scalar_texture(image("textures/rough16.png", v, mode="mirror_y"), 0.5, 0.25)),
        normal=normal(v, image("textures/normal16.png", v, mode="mirror_xy"), scale=2.0),
        alpha=scalar(0.9, scalar_texture(image("textures/alpha.png", v))),
        sheen_value=scalar(0.5, scalar_texture(image("textures/sheen.jpg", v))),
        specular_value=scalar(0.3, scalar_texture(image("textures/tint.jpg", v))),
        anisotropy_rotation=scalar(90.0 if v == "1.0" else 0.25),
        metalness=scalar(0.0, scalar_texture(image("textures/wide gamut/adobe.png", v, 10, 10))),
    )
    side = visualisation(v, basecolor=color((0.1, 0.2, 0.3))) if v == "1.1" else None
    return document(v, front, visualisation(v, roughness=scalar(0.9)) if back else None, side,
                    physics=physics() if v == "1.1" else None)


@pytest.fixture(params=["1.0", "1.1"])
def version(request) -> str:
    return request.param


@pytest.fixture(params=["u3m", "u3ma"])
def form(request) -> str:
    return request.param


def write(tmp_path: Path, form: str, doc, images, name="fabric") -> Path:
    if form == "u3m":
        return write_u3m(tmp_path / name, doc, images)
    return write_u3ma(tmp_path / f"{name}.u3ma", doc, images)


def test_every_kind_of_field_reads_as_the_spec_says(tmp_path, version, form):
    m = load_u3m(write(tmp_path, form, fabric(version), fabric_images()))
    assert (m.version, m.name, m.back) == (version, "Hand-written fabric", None)
    front = m.front
    assert front.shader == "principled"

    base = front.basecolor
    assert isinstance(base, ColorTexture) and base.mode is BlendMode.MULTIPLY
    assert base.image.dtype == np.float32 and base.image.shape == (6, 8, 3) and not base.image.flags.writeable
    np.testing.assert_allclose(base.image, srgb_eotf(BASE_RGB / 255.0), atol=1e-6)   # no profile: sRGB
    np.testing.assert_allclose(base.factor, srgb_eotf(np.array([1.0, 0.5, 0.25])), atol=1e-6)
    np.testing.assert_allclose(base.constant.rgb, srgb_eotf(np.full(3, 0.5)), atol=1e-6)
    np.testing.assert_allclose(base.values(), base.image * np.asarray(base.factor, np.float32), atol=1e-6)
    assert (base.width_mm, base.height_mm, base.rotation_deg, base.repeat) == (50.0, 37.5, 30.0, RepeatMode.MIRROR_X)
    assert base.dpi == (300.0, 300.0) and base.size_px == (8, 6)
    assert base.repeat.mirror_x and not base.repeat.mirror_y

    rough = front.roughness   # 16-bit greyscale: raw, all 16 bits, factor and offset kept
    assert isinstance(rough, ScalarTexture) and rough.image.shape == (6, 8)
    np.testing.assert_allclose(rough.image, ROUGH_16 / 65535.0, atol=1e-7)
    assert (rough.factor, rough.offset, rough.constant, rough.repeat) == (0.5, 0.25, ScalarConstant(0.6),
                                                                        RepeatMode.MIRROR_Y)
    np.testing.assert_allclose(rough.values(), 0.25 + 0.5 * ROUGH_16 / 65535.0, atol=1e-6)

    nrm = front.normal   # 16-bit RGB: raw, all 16 bits (Pillow alone would keep 8)
    assert isinstance(nrm, NormalTexture) and nrm.repeat is RepeatMode.MIRROR_XY
    np.testing.assert_allclose(nrm.image, NORMAL_16 / 65535.0, atol=1e-7)
    assert nrm.scale == (1.0 if version == "1.0" else 2.0)

    alpha = front.alpha   # RGBA data image: the three colour channels averaged, alpha channel not
    np.testing.assert_allclose(alpha.image, ALPHA_RGBA[..., :3].mean(axis=2) / 255.0, atol=1e-6)
    assert abs(front.sheen_value.image.mean() - 140 / 255) < 2 / 255                # greyscale JPEG
    np.testing.assert_allclose(front.specular_value.image.mean(), np.mean(TINT_JPEG[0, 0]) / 255, atol=2 / 255)

    # The same ICC-tagged file: converted as colour, raw as data (the spec: data images ignore profiles).
    assert np.allclose(front.metalness.image, np.mean(ADOBE_RGB) / 255, atol=1e-6)
    assert not np.allclose(front.subsurface_color.image[0, 0], srgb_eotf(np.array(ADOBE_RGB) / 255), atol=0.01)

    # Constants where no texture is given, the spec's units.
    assert front.ior == ScalarConstant(1.4) and front.transmission == ScalarConstant(0.0)
    assert front.clearcoat_normal == NormalConstant((0.0, 0.0, 1.0))
    assert front.anisotropy_rotation == ScalarConstant(0.25)   # turns; 1.0's 90 degrees read as 0.25
    assert {name for name, _ in front.textures()} == {"basecolor", "subsurface_color", "roughness", "normal", "alpha",
                                                     "sheen_value", "specular_value", "metalness"}
    if version == "1.1":
        assert m.side.basecolor == ColorConstant(tuple(srgb_eotf(np.array([0.1, 0.2, 0.3])).tolist()))
        assert (m.thickness_mm, m.weight_g_m2) == (0.6, 180.0)
    else:
        assert m.side is None and m.thickness_mm is None
    # One decode a file and a use: 7 files, the ICC-tagged one read as colour and as data.
    assert len({id(t.image) for _, t in m.textures()}) == 8


def test_an_image_named_twice_is_decoded_once(tmp_path):
    v = visualisation("1.1", basecolor=color(texture=color_texture(image("a.png", "1.1"))),
                      roughness=scalar(0.5, scalar_texture(image("a.png", "1.1", mode="mirror_x"))))
    doc = document("1.1", v, back=v)
    m = load_u3m(write(tmp_path, "u3ma", doc, {"a.png": encode(np.zeros((10, 10, 3), np.uint8))}))
    assert m.back.basecolor.image is m.front.basecolor.image
    assert m.front.roughness.image is not m.front.basecolor.image   # the same file as data
    assert m.nbytes == 10 * 10 * 4 * (3 + 1)


def test_an_icc_profile_converts_colour_to_linear_srgb(tmp_path):
    """An Adobe RGB (1998) image (a profile written by hand, parsed by LittleCMS): its pixel equals the
    colorimetric conversion Adobe RGB -> XYZ -> sRGB, linear, within the 8-bit step ImageCms
    converts at; read as if it were sRGB it would be 0.19 off in red."""
    m = load_u3m(write(tmp_path, "u3ma", fabric("1.1"), fabric_images()))
    got = m.front.subsurface_color.image
    linear_adobe = (np.array(ADOBE_RGB) / 255.0) ** ADOBE_GAMMA
    expected = np.linalg.solve(rgb_to_xyz(SRGB_PRIMARIES), rgb_to_xyz(ADOBE_PRIMARIES) @ linear_adobe)
    assert np.all(np.abs(srgb_oetf(got) * 255 - srgb_oetf(expected) * 255) <= 1.0), (got[0, 0], expected)
    assert abs(expected[0] - srgb_eotf(np.array([200 / 255]))[0]) > 0.15
    # divide by (0, 0.5, 1) encoded: red is divided by zero, which the spec sets to 1.
    values = m.front.subsurface_color.values()
    assert np.all(values[..., 0] == 1.0)
    np.testing.assert_allclose(values[..., 2], got[..., 2], atol=1e-6)


@pytest.mark.parametrize("writer", [png16, tiff16, lambda v: tiff16(v, big_endian=True)],
                         ids=["png", "tiff-le", "tiff-be"])
def test_16_bit_rgb_keeps_its_low_byte(writer):
    """Pillow decodes 16-bit RGB to 8 bits; the reader's second pass restores the low byte (through every
    PNG filter; from TIFFs of either byte order), with and without an alpha channel."""
    from renderer.u3m.images import decode_image

    for channels in (3, 4):
        values = RNG.integers(0, 65536, (11, 9, channels), dtype=np.uint16)
        got = decode_image(writer(values), ImageKind.NORMAL, file="f", field="x", max_pixels=10**6)
        assert np.array_equal(np.rint(got * 65535).astype(np.uint16), values[..., :3])
        colour = decode_image(writer(values), ImageKind.COLOR, file="f", field="x", max_pixels=10**6)
        np.testing.assert_allclose(colour, srgb_eotf(values[..., :3] / 65535.0), atol=1e-6)


def test_an_8_bit_tiff_reads(tmp_path):
    values = RNG.integers(0, 256, (5, 6, 3), dtype=np.uint8)
    v = visualisation("1.1", basecolor=color(texture=color_texture(image("b.tif", "1.1"))))
    m = load_u3m(write(tmp_path, "u3ma", document("1.1", v), {"b.tif": encode(values, "TIFF", compression="tiff_lzw")}))
    np.testing.assert_allclose(m.front.basecolor.image, srgb_eotf(values / 255.0), atol=1e-6)


def test_the_folder_and_the_archive_read_the_same(tmp_path, version):
    a = load_u3m(write(tmp_path, "u3m", fabric(version), fabric_images()))
    b = load_u3m(write(tmp_path, "u3ma", fabric(version), fabric_images()))
    assert [n for n, _ in a.textures()] == [n for n, _ in b.textures()]
    for (_, ta), (_, tb) in zip(a.textures(), b.textures()):
        assert np.array_equal(ta.image, tb.image)


def test_the_kind_is_told_by_the_bytes_not_the_name(tmp_path):
    doc, images = fabric("1.1"), fabric_images()
    archive = tmp_path / "named-like-a-document.u3m"
    archive.write_bytes(u3ma_bytes(doc, images))
    assert isinstance(load_u3m(archive).front.basecolor, ColorTexture)
    folder_doc = write_u3m(tmp_path / "folder", doc, images, name="named-like-an-archive.u3ma")
    assert isinstance(load_u3m(folder_doc).front.basecolor, ColorTexture)
    # Bytes: an archive loads; a document alone loads when it names no image.
    assert isinstance(load_u3m(u3ma_bytes(doc, images), name="upload").front.normal, NormalTexture)
    plain = json.dumps(document("1.1", visualisation("1.1"))).encode()
    assert load_u3m(plain).front.roughness == ScalarConstant(0.7)
    with pytest.raises(MaterialError, match=r"upload: material\.front\.\w+\.texture\.image\.path: .*no folder"):
        load_u3m(json.dumps(doc).encode(), name="upload")


def test_an_archive_may_hold_its_document_in_a_folder(tmp_path):
    images = {f"Denim/{k}": v for k, v in fabric_images().items()}
    images["__MACOSX/Denim/._denim.u3m"] = b"\x00\x05\x16\x07"   # an archiver's resource fork: not a document
    path = write_u3ma(tmp_path / "denim.u3ma", fabric("1.1"), images, document_name="Denim/denim.u3m")
    assert load_u3m(path).front.normal.size_px == (8, 6)
    two = write_u3ma(tmp_path / "two.u3ma", fabric("1.1"), {"other.u3m": b"{}", **fabric_images()})
    refused(lambda: load_u3m(two), two, None, "exactly one .u3m document; found 2")


def test_back_and_side_fall_back_as_the_spec_says(tmp_path):
    m = load_u3m(write(tmp_path, "u3m", fabric("1.1"), fabric_images()))
    assert m.back is None
    assert m.visualisation(Face.BACK) is m.front and m.visualisation("back") is m.front   # back -> front
    assert m.visualisation(Face.SIDE) is m.side
    with_back = load_u3m(write(tmp_path, "u3ma", fabric("1.1", back=True), fabric_images(), name="b"))
    assert with_back.visualisation(Face.BACK) is with_back.back
    assert with_back.visualisation(Face.BACK).roughness == ScalarConstant(0.9)

    v = visualisation("1.1", roughness=scalar(0.3))
    only_back = load_u3m(json.dumps(document("1.1", None, back=v)).encode())
    assert only_back.visualisation(Face.FRONT) is only_back.back is only_back.visualisation(Face.SIDE)
    only_side = load_u3m(json.dumps(document("1.1", None, side=v)).encode())
    assert only_side.visualisation(Face.FRONT) is only_side.side is only_side.visualisation(Face.BACK)
    physics_only = load_u3m(json.dumps(document("1.1", None, physics=physics())).encode(), name="p.u3m")
    with pytest.raises(MaterialError, match=r"p\.u3m: material\.front: .*no visualisation"):
        physics_only.visualisation(Face.FRONT)


def test_version_1_0_null_fields_take_the_defaults_and_dpi_is_one_number(tmp_path):
    v = visualisation("1.0", roughness=None, basecolor=None, ior=None, normal=None)
    m = load_u3m(json.dumps(document("1.0", v)).encode())
    assert m.front.roughness == ScalarConstant(0.7) and m.front.ior == ScalarConstant(1.4)
    assert m.front.basecolor == ColorConstant((1.0, 1.0, 1.0)) and m.front.normal == NormalConstant((0.0, 0.0, 1.0))
    rotated = visualisation("1.0", anisotropy_rotation=scalar(
        45.0, scalar_texture(image("a.png", "1.0", dpi=254.0), factor=360.0, offset=180.0)))
    m = load_u3m(write(tmp_path, "u3m", document("1.0", rotated), {"a.png": encode(np.zeros((2, 2), np.uint8))}))
    t = m.front.anisotropy_rotation
    assert (t.constant.value, t.factor, t.offset, t.dpi) == (0.125, 1.0, 0.5, (254.0, 254.0))


def test_a_zero_size_is_taken_from_the_dpi(tmp_path):
    v = visualisation("1.1", roughness=scalar(0.5, scalar_texture(image("r.png", "1.1", 0.0, 0.0, dpi=254.0))))
    m = load_u3m(write(tmp_path, "u3m", document("1.1", v), {"r.png": encode(np.zeros((30, 20), np.uint8))}))
    assert (m.front.roughness.width_mm, m.front.roughness.height_mm) == pytest.approx((2.0, 3.0))


def test_blend_modes_follow_the_spec():
    a = np.array([[0.2, 0.6, 0.5]], np.float32)
    b = np.array([0.5, 0.0, 0.25], np.float32)
    expected = {BlendMode.ADD: [0.7, 0.6, 0.75], BlendMode.SUBTRACT: [-0.3, 0.6, 0.25],
                BlendMode.MULTIPLY: [0.1, 0.0, 0.125], BlendMode.DIVIDE: [0.4, 1.0, 2.0],   # b == 0 -> 1
                BlendMode.MAX: [0.5, 0.6, 0.5], BlendMode.MIN: [0.2, 0.0, 0.25],
                BlendMode.OVERLAY: [2 * 0.2 * 0.5, 1 - 2 * 0.4 * 1.0, 1 - 2 * 0.5 * 0.75]}
    for mode, want in expected.items():
        np.testing.assert_allclose(mode.apply(a, b)[0], want, atol=1e-6, err_msg=mode.value)
    assert {m.value for m in BlendMode} == set(_schema("1.1")["definitions"]["color_texture"]["properties"]
                                               ["mode"]["enum"])


def test_normals_decode_scale_and_renormalise():
    raw = np.array([[[0.5, 0.5, 1.0], [0.75, 0.5, 0.5 + 0.5 * np.sqrt(0.75)], [0.5, 0.5, 0.5]]], np.float32)
    t = NormalTexture("n.png", raw, 10.0, 10.0, (300.0, 300.0), 0.0, RepeatMode.NORMAL, scale=2.0,
                      constant=NormalConstant((0.0, 0.0, 1.0)))
    n = t.values()
    np.testing.assert_allclose(n[0, 0], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(n[0, 1], np.array([1.0, 0, np.sqrt(0.75)]) / np.sqrt(1.75), atol=1e-6)   # x doubled
    np.testing.assert_allclose(n[0, 2], [0, 0, 1])   # a zero vector: the spec's suggested up vector
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0)


def _schema(version: str) -> dict:
    return json.loads((SCHEMA_DIR / SCHEMA_FILES[version]).read_text())


def test_the_field_table_is_the_schemas():
    """Every field of a 1.1 visualisation, its kind (by the schema's type) and its default."""
    schema = _schema("1.1")
    props = schema["definitions"]["visualisation"]["properties"]
    kinds = {"texture_and_color": ImageKind.COLOR, "texture_and_normal": ImageKind.NORMAL}
    fields = {n: p["$ref"].rsplit("/", 1)[1] for n, p in props.items() if "$ref" in p and n != "preview"}
    assert set(fields) == set(FIELDS)
    for name, ref in fields.items():
        kind, default = FIELDS[name]
        assert kind is kinds.get(ref, ImageKind.SCALAR), name
        constant = schema["definitions"][ref]["properties"]["constant"]
        if kind is ImageKind.SCALAR:
            assert default == constant["default"], name
        elif kind is ImageKind.COLOR:
            assert default == tuple(schema["definitions"]["color_rgb"]["properties"][c]["default"] for c in "rgb")
        else:
            assert default == tuple(constant["properties"][c]["default"] for c in "xyz")
    assert set(_schema("1.0")["definitions"]["visualisation"]["properties"]) == set(FIELDS) | {"shader"}


def test_the_packaged_schemas_are_the_specs():
    for name in [*SCHEMA_FILES.values(), "LICENSE"]:
        assert (SCHEMA_DIR / name).read_bytes() == spec_file(name).read_bytes(), name


def test_the_spec_example_names_its_missing_images(tmp_path):
    """Example_1.0.u3m ships without its images: the first texture it names is a missing image, with
    the file and the field in the message."""
    path = tmp_path / "Example_1.0.u3m"
    path.write_bytes(spec_file("Example_1.0.u3m").read_bytes())
    with pytest.raises(MaterialError) as info:
        load_u3m(path)
    assert str(path) in str(info.value) and info.value.field == "material.front.alpha.texture.image.path"
    assert "'textures/Example_0.9_ALPHA.jpg', which is missing" in str(info.value)


def test_the_spec_example_loads_with_its_images(tmp_path):
    """With JPEGs where it names them, the example reads: a 1.0 document with null back, textures on
    alpha, basecolor (mode add), metalness, normal (a number field in 1.0) and roughness."""
    doc = spec_file("Example_1.0.u3m").read_bytes()
    names = ["ALPHA", "BASE", "MTL", "NRM", "ROUGH"]
    images = {f"textures/Example_0.9_{n}.jpg": encode(np.full((12, 13, 3), 128, np.uint8), "JPEG") for n in names}
    for form in ("u3m", "u3ma"):
        m = load_u3m(write(tmp_path, form, doc, images, name=f"example-{form}"))
        front = m.front
        assert m.version == "1.0" and m.back is None and m.visualisation(Face.BACK) is front
        assert front.basecolor.mode is BlendMode.ADD and front.basecolor.constant == ColorConstant((0.0, 0.0, 0.0))
        assert isinstance(front.normal, NormalTexture) and front.normal.scale == 1.0
        assert (front.alpha.width_mm, front.alpha.height_mm, front.alpha.dpi) == (12.1759, 11.1195, (1005.0, 1005.0))
        assert front.clearcoat_normal == NormalConstant((0.0, 0.0, 1.0))
        assert front.sheen_value == ScalarConstant(0.0)


# -- bad input: one typed error naming the file and the field, in bounded time and memory -----------

def _rss_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def refused(call, file: str | Path, field: str | None, *words: str) -> MaterialError:
    """The MaterialError `call` raises: its message names `file`, `field` (when the input has one) and
    `words`; it came within REFUSE_S and REFUSE_BYTES (Python's allocations by tracemalloc, all of them
    by the resident set's peak, where Linux lets a process reset it)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")   # resets VmHWM to the current resident set
        rss_before = _rss_kb("VmRSS")
    except OSError:
        rss_before = None
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(MaterialError) as info:
            call()
    finally:
        seconds = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    error = info.value
    assert isinstance(error, InvalidInputError) and isinstance(error, ValueError)
    message = str(error)
    assert str(file) in message, message
    if field is not None:
        assert error.field == field and field in message, message
    for word in words:
        assert word in message, message
    assert seconds < REFUSE_S, (seconds, message)
    assert peak < REFUSE_BYTES, (peak, message)
    if rss_before is not None:
        assert (_rss_kb("VmHWM") - rss_before) * 1024 < REFUSE_BYTES, message
    return error


def basecolor_doc(version: str, path: str) -> dict:
    return document(version, visualisation(version, basecolor=color(texture=color_texture(image(path, version)))))


BASE_FIELD = "material.front.basecolor.texture.image.path"


@pytest.mark.parametrize("path", ["../outside.png", "textures/../../outside.png", "/etc/passwd", "~/x.png",
                                  "C:/Windows/x.png", "textures\\..\\x.png", "textures//x.png", "./x.png"])
def test_a_path_out_of_the_archive_is_refused(tmp_path, version, form, path):
    (tmp_path / "outside.png").write_bytes(encode(np.zeros((2, 2, 3), np.uint8)))
    target = write(tmp_path, form, basecolor_doc(version, path), {"textures/x.png": encode(np.zeros((2, 2), np.uint8))})
    # 1.1's schema has a pattern for paths (its message says so); 1.0's has none and the reader's rule speaks.
    refused(lambda: load_u3m(target), target, BASE_FIELD, repr(path) if version == "1.0" else "not a path")


def test_a_path_that_a_link_takes_out_of_the_folder_is_refused(tmp_path):
    (tmp_path / "secret.png").write_bytes(encode(np.zeros((2, 2, 3), np.uint8)))
    target = write_u3m(tmp_path / "fabric", basecolor_doc("1.1", "textures/base.png"), {})
    (tmp_path / "fabric" / "textures").mkdir()
    os.symlink(tmp_path / "secret.png", tmp_path / "fabric" / "textures" / "base.png")
    refused(lambda: load_u3m(target), target, BASE_FIELD, "leads out of the material's folder")
    # A link that stays inside is a file like another.
    (tmp_path / "fabric" / "textures" / "base.png").unlink()
    (tmp_path / "fabric" / "real.png").write_bytes(encode(np.zeros((2, 2, 3), np.uint8)))
    os.symlink(tmp_path / "fabric" / "real.png", tmp_path / "fabric" / "textures" / "base.png")
    assert load_u3m(target).front.basecolor.size_px == (2, 2)


def test_an_archive_member_named_out_of_the_archive_is_refused(tmp_path):
    path = tmp_path / "evil.u3ma"
    write_u3ma(path, basecolor_doc("1.1", "base.png"), {"base.png": encode(np.zeros((2, 2), np.uint8)),
                                                        "../../evil.sh": b"#!/bin/sh\n"})
    refused(lambda: load_u3m(path), f"{path}:../../evil.sh", None, "'..' component")


def test_the_rule_for_paths():
    for good in ("a.png", "textures/a b.png", "Denim_01/x.v2.jpg"):
        assert path_problem(good) is None, good
    for bad in ("", "..", "a/../b", "/a", "~", "~/a", "a/./b", "C:a", "a\\b", "a//b", "a/", "a\x00b", "a\nb"):
        assert path_problem(bad) is not None, bad


def test_an_image_that_declares_60000_px_square_is_refused_from_its_header(tmp_path, form):
    target = write(tmp_path, form, basecolor_doc("1.1", "huge.png"), {"huge.png": png_header_only(60000, 60000)})
    shown = target.parent / "huge.png" if form == "u3m" else f"{target}:huge.png"
    refused(lambda: load_u3m(target), shown, BASE_FIELD, "3600000000 px", "U3MLimits.max_image_pixels")
    # Under Pillow's own bound (Image.MAX_IMAGE_PIXELS), over the reader's: its message gives the size.
    target = write(tmp_path, form, basecolor_doc("1.1", "huge.png"), {"huge.png": png_header_only(9000, 9000)},
                   name="b")
    shown = target.parent / "huge.png" if form == "u3m" else f"{target}:huge.png"
    refused(lambda: load_u3m(target), shown, BASE_FIELD, "9000 x 9000 px", "U3MLimits.max_image_pixels")


def test_the_pixel_limits_are_arguments(tmp_path):
    v = visualisation("1.1", basecolor=color(texture=color_texture(image("a.png", "1.1"))),
                      roughness=scalar(0.5, scalar_texture(image("b.png", "1.1"))))
    images = {"a.png": encode(np.zeros((40, 40, 3), np.uint8)), "b.png": encode(np.zeros((40, 40), np.uint8))}
    target = write_u3ma(tmp_path / "f.u3ma", document("1.1", v), images)
    # Images are judged in the order of the spec's fields: roughness, then basecolor.
    refused(lambda: load_u3m(target, limits=U3MLimits(max_image_pixels=1000)), f"{target}:b.png",
            "material.front.roughness.texture.image.path", "40 x 40 px", "U3MLimits.max_image_pixels")
    refused(lambda: load_u3m(target, limits=U3MLimits(max_total_pixels=2000)), target, BASE_FIELD,
            "3200 px in all", "U3MLimits.max_total_pixels")
    assert load_u3m(target, limits=U3MLimits(max_total_pixels=3200)).nbytes == 40 * 40 * 4 * 4


def test_a_zip_bomb_is_refused_from_its_directory(tmp_path):
    """32 MiB of zeros that deflate to 32 kB (about 1000:1): refused on the declared ratio, before a
    byte is inflated; and an archive whose members declare more than the limit in all."""
    path = tmp_path / "bomb.u3ma"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("fabric.u3m", json.dumps(basecolor_doc("1.1", "base.png")))
        with z.open("base.png", "w", force_zip64=False) as member:
            for _ in range(32):
                member.write(bytes(2**20))
    path.write_bytes(buf.getvalue())
    refused(lambda: load_u3m(path), f"{path}:base.png", None, "zip bomb")
    ok = write_u3ma(tmp_path / "ok.u3ma", basecolor_doc("1.1", "base.png"),
                    {"base.png": encode(RNG.integers(0, 256, (64, 64, 3), dtype=np.uint8))})
    refused(lambda: load_u3m(ok, limits=U3MLimits(max_archive_bytes=4000)), ok, None, "U3MLimits.max_archive_bytes")
    refused(lambda: load_u3m(ok, limits=U3MLimits(max_file_bytes=5000)), f"{ok}:base.png", None,
            "U3MLimits.max_file_bytes")
    padded = basecolor_doc("1.1", "base.png")
    padded["material"]["description"] = " " * 50000   # 50 kB that deflate to a few hundred bytes
    small = write_u3ma(tmp_path / "padded.u3ma", padded, {"base.png": encode(np.zeros((2, 2, 3), np.uint8))})
    assert small.stat().st_size < 4000
    refused(lambda: load_u3m(small, limits=U3MLimits(max_archive_bytes=4000)), small, None, "members declare")


def _patch_sizes(data: bytes, name: bytes, uncompressed: int) -> bytes:
    """The archive with `name` declaring `uncompressed` bytes in its local header and its directory."""
    out = bytearray(data)
    for signature, size_at in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        at = 0
        while (at := out.find(signature, at)) >= 0:
            name_at = at + (30 if signature == b"PK\x03\x04" else 46)
            if out[name_at:name_at + len(name)] == name:
                out[at + size_at:at + size_at + 4] = struct.pack("<I", uncompressed)
            at += 4
    return bytes(out)


def test_a_member_that_inflates_past_its_declared_size_is_refused(tmp_path):
    """The directory says 100 bytes; the data inflates to 1 MiB. Read with a byte cap, it ends at the
    declared size and fails its CRC: the declared size is never trusted to bound the read."""
    big = encode(RNG.integers(0, 256, (300, 300, 3), dtype=np.uint8))
    data = u3ma_bytes(basecolor_doc("1.1", "base.png"), {"base.png": big})
    path = tmp_path / "liar.u3ma"
    path.write_bytes(_patch_sizes(data, b"base.png", 100))
    refused(lambda: load_u3m(path), f"{path}:base.png", BASE_FIELD, "corrupt or truncated")


def test_a_truncated_or_corrupt_archive_is_refused(tmp_path):
    data = u3ma_bytes(fabric("1.1"), fabric_images())
    for cut in (len(data) // 2, len(data) - 10, 30):
        path = tmp_path / f"cut{cut}.u3ma"
        path.write_bytes(data[:cut])
        refused(lambda p=path: load_u3m(p), path, None, "zip archive")
    # The directory intact, a member's bytes flipped: its CRC fails when it is read.
    start = data.find(b"textures/normal16.png") + len("textures/normal16.png") + 40
    corrupt = bytearray(data)
    corrupt[start:start + 16] = bytes(b ^ 0xFF for b in corrupt[start:start + 16])
    path = tmp_path / "corrupt.u3ma"
    path.write_bytes(bytes(corrupt))
    refused(lambda: load_u3m(path), f"{path}:textures/normal16.png", "material.front.normal.texture.image.path")


@pytest.mark.parametrize("change, field, words", [
    (lambda d: d["material"]["front"]["roughness"].update(constant="high"), "material.front.roughness.constant",
     ["'high'", "not of type number"]),
    (lambda d: d["material"]["front"]["alpha"].update(constant=1.5), "material.front.alpha.constant", ["maximum"]),
    (lambda d: d["material"]["front"].pop("normal"), "material.front.normal", ["missing"]),
    (lambda d: d["material"]["front"].update(glitter=1), "material.front.glitter", ["not a field of U3M 1.1"]),
    (lambda d: d["material"]["front"]["basecolor"]["texture"]["image"]["repeat"].update(mode="clamp"),
     "material.front.basecolor.texture.image.repeat.mode", ["'clamp'", "mirror_xy"]),
    (lambda d: d.update(schema="2.0"), "schema", ["reads U3M 1.0 and 1.1"]),
    (lambda d: d["material"].update(front=None, back=None, side=None, physics=None), "material", ["all null"]),
])
def test_a_schema_violation_is_refused_naming_the_field(tmp_path, change, field, words):
    doc = fabric("1.1")
    change(doc)
    target = write(tmp_path, "u3ma", doc, fabric_images())
    refused(lambda: load_u3m(target), f"{target}:fabric.u3m", field, *words)


def test_version_1_0_is_held_to_its_own_schema(tmp_path):
    doc = fabric("1.0")
    doc["material"]["side"] = None   # 1.1's field, not 1.0's
    target = write(tmp_path, "u3m", doc, fabric_images())
    refused(lambda: load_u3m(target), target, "material.side", "not a field of U3M 1.0")
    doc = document("1.0", None)
    refused(lambda: load_u3m(json.dumps(doc).encode(), name="n.u3m"), "n.u3m", "material.front", "null")


def test_a_missing_image_is_refused(tmp_path, form):
    images = fabric_images()
    del images["textures/normal16.png"]
    target = write(tmp_path, form, fabric("1.1"), images)
    refused(lambda: load_u3m(target), target, "material.front.normal.texture.image.path",
            "'textures/normal16.png', which is missing")


@pytest.mark.parametrize("content, words", [
    (lambda: encode(np.zeros((4, 4, 3), np.uint8), "GIF"), ["PNG, JPEG or TIFF"]),     # Pillow reads it; U3M not
    (lambda: encode(np.zeros((4, 4, 3), np.uint8), "BMP"), ["PNG, JPEG or TIFF"]),
    (lambda: b"not an image at all" * 10, ["PNG, JPEG or TIFF"]),
    (lambda: encode(RNG.integers(0, 256, (64, 64, 3), dtype=np.uint8))[:300], ["corrupt or truncated"]),
    (lambda: encode(np.zeros((4, 4, 3), np.uint8), icc_profile=b"garbage profile"), ["ICC profile"]),
])
def test_an_image_pillow_cannot_read_is_refused(tmp_path, form, content, words):
    target = write(tmp_path, form, basecolor_doc("1.1", "base.png"), {"base.png": content()})
    shown = target.parent / "base.png" if form == "u3m" else f"{target}:base.png"
    refused(lambda: load_u3m(target), shown, BASE_FIELD, *words)


def test_a_normal_map_needs_three_channels(tmp_path):
    doc = document("1.1", visualisation("1.1", normal=normal("1.1", image("n.png", "1.1"))))
    target = write(tmp_path, "u3ma", doc, {"n.png": encode(np.zeros((4, 4), np.uint8))})
    refused(lambda: load_u3m(target), f"{target}:n.png", "material.front.normal.texture.image.path", "3 channels")


@pytest.mark.parametrize("content, words", [
    (b"\x00\x01garbage", ["neither a U3M document"]),
    (b"\xff\xfe{}", ["not UTF-8"]),
    (b'{"schema": "1.1", "material": ', ["not valid JSON", "line 1"]),
    (b'{"schema": "1.1", "schema": "1.0"}', ["'schema' appears twice"]),
    (b'{"schema": "1.1", "material": {"x": NaN}}', ["NaN"]),
    (b"[" * 100000 + b"]" * 100000, ["neither a U3M document"]),
    (b'{"a":' * 100000 + b"1" + b"}" * 100000, ["nested too deeply"]),
    (b'{"schema": "1.1", "material": {"x": 1e999}}', ["overflows"]),
])
def test_a_document_that_is_not_json_is_refused(tmp_path, content, words):
    path = tmp_path / "fabric.u3m"
    path.write_bytes(content)
    refused(lambda: load_u3m(path), path, None, *words)


def test_missing_files_folders_and_oversized_documents_are_refused(tmp_path):
    refused(lambda: load_u3m(tmp_path / "absent.u3ma"), tmp_path / "absent.u3ma", None, "no such file")
    refused(lambda: load_u3m(tmp_path), tmp_path, None, "is a folder")
    big = tmp_path / "big.u3m"
    big.write_bytes(b"{" + b" " * 5000 + b"}")
    refused(lambda: load_u3m(big, limits=U3MLimits(max_document_bytes=4096)), big, None,
            "U3MLimits.max_document_bytes")


def test_the_error_keeps_its_parts_through_pickle():
    e = MaterialError("is missing", file="a.u3ma:b.u3m", field="material.front")
    back = pickle.loads(pickle.dumps(e))
    assert (str(back), back.file, back.field, back.reason) == (str(e), e.file, e.field, "is missing")
    assert str(e) == "a.u3ma:b.u3m: material.front: is missing"


def test_a_zip_bomb_in_the_image_itself_is_bounded_by_its_header(tmp_path):
    """A PNG whose IDAT inflates to far more than its header's rows need: the decoder stops at the
    declared size, so the time and memory are the declared image's."""
    rows = b"".join(b"\x00" + bytes(3 * 64) for _ in range(64))
    flood = zlib.compress(rows + bytes(16 * 2**20), 1)
    header = struct.pack(">IIBBBBB", 64, 64, 8, 2, 0, 0, 0)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", flood) + chunk(b"IEND", b"")
    target = write(tmp_path, "u3ma", basecolor_doc("1.1", "base.png"), {"base.png": png})
    t0 = time.perf_counter()
    m = load_u3m(target)
    assert time.perf_counter() - t0 < REFUSE_S and m.front.basecolor.size_px == (64, 64)
    assert Image.open(io.BytesIO(png)).size == (64, 64)
