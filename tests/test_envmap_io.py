"""Reading and writing HDR images, texel checks, and loading environment maps (renderer.envmap.io, __init__)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from conftest import HDRI, assert_rec709_exr, needs_assets
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from renderer.envmap import (
    EnvironmentMap,
    Layout,
    TexelReport,
    check_texels,
    environment_from_array,
    load_environment,
    read_hdr_image,
    write_exr,
)
from renderer.errors import EnvironmentMapError, InvalidInputError

# (file, height, width, has negative texels) from shared/assets/MANIFEST.md
ASSETS = [
    ("adams_place_bridge_1k.hdr", 512, 1024, False),
    ("dikhololo_night_1k.hdr", 512, 1024, False),
    ("empty_warehouse_01_1k.hdr", 512, 1024, False),
    ("forest_slope_1k.hdr", 512, 1024, False),
    ("immenstadter_horn_1k.hdr", 512, 1024, False),
    ("kiara_1_dawn_1k.hdr", 512, 1024, False),
    ("lebombo_1k.hdr", 512, 1024, False),
    ("potsdamer_platz_1k.hdr", 512, 1024, False),
    ("rooitou_park_1k.hdr", 512, 1024, False),
    ("st_fagans_interior_1k.hdr", 512, 1024, False),
    ("ennis.hdr", 128, 256, False),
    ("pisa.hdr", 128, 256, False),
    ("wells.hdr", 128, 256, False),
    ("openexr_StageEnvLatLong.exr", 500, 1000, False),
    ("openexr_KernerEnvLatLong.exr", 512, 1024, False),
    ("pmndrs_assets_hall.exr", 256, 512, True),
    ("pmndrs_assets_sky.exr", 256, 512, True),
]


# ------------------------------------------------------------------------------------------------------------
# A reference Radiance writer and a slow, obviously sequential reader to compare the fast decoder with.


def _rle_plane(b: bytes) -> bytes:
    """Radiance new-style RLE of one channel plane: runs (>= 3 equal bytes, <= 127) and literals (<= 128)."""
    out = bytearray()
    i, n = 0, len(b)
    while i < n:
        j = i
        while j < n and j - i < 127 and b[j] == b[i]:
            j += 1
        if j - i >= 3:
            out += bytes([128 + j - i, b[i]])
            i = j
            continue
        k = i
        while k < n and k - i < 128 and not (k + 2 < n and b[k] == b[k + 1] == b[k + 2]):
            k += 1
        out += bytes([k - i]) + b[i:k]
        i = k
    return bytes(out)


def write_rgbe(path: Path, rgbe: np.ndarray, *, rle: bool = True, header: bytes = b"FORMAT=32-bit_rle_rgbe\n",
               resolution: bytes | None = None) -> Path:
    h, w = rgbe.shape[:2]
    data = bytearray(b"#?RADIANCE\n# test writer\n" + header + b"\n")
    data += resolution if resolution is not None else b"-Y %d +X %d\n" % (h, w)
    for row in rgbe.astype(np.uint8):
        if rle and 8 <= w < 0x8000:
            data += bytes([2, 2, w >> 8, w & 255])
            for c in range(4):
                data += _rle_plane(row[:, c].tobytes())
        else:
            data += row.tobytes()
    path.write_bytes(bytes(data))
    return path


def read_rgbe_reference(path: Path) -> np.ndarray:
    """Byte-at-a-time decoder straight from the format description (Graphics Gems II, 'Real Pixels')."""
    data = path.read_bytes()
    pos = data.index(b"\n\n") + 2
    end = data.index(b"\n", pos)
    _, h, _, w = data[pos:end].split()
    h, w = int(h), int(w)
    pos = end + 1
    out = np.zeros((h, w, 4), np.uint8)
    for y in range(h):
        if data[pos] == 2 and data[pos + 1] == 2 and 8 <= w < 0x8000:
            pos += 4
            for c in range(4):
                x = 0
                while x < w:
                    count = data[pos]
                    pos += 1
                    if count > 128:
                        out[y, x:x + count - 128, c] = data[pos]
                        pos += 1
                        x += count - 128
                    else:
                        out[y, x:x + count, c] = list(data[pos:pos + count])
                        pos += count
                        x += count
        else:
            out[y] = np.frombuffer(data[pos:pos + 4 * w], np.uint8).reshape(w, 4)
            pos += 4 * w
    e = out[..., 3:].astype(np.float64)
    return np.where(e > 0, out[..., :3] * np.exp2(e - 136), 0.0).astype(np.float32)


def _rgbe_image(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Random RGBE bytes with runs (flat areas) and noise, exponent 0 (black) in places."""
    img = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    img[:, : w // 3] = img[:, :1]  # a long run in every plane
    img[::3, ::5, 3] = 0
    img[..., 3] = np.where(img[..., 3] == 0, 0, 100 + img[..., 3] % 60)
    return img


def _expected(rgbe: np.ndarray) -> np.ndarray:
    e = rgbe[..., 3:].astype(np.float64)
    return np.where(e > 0, rgbe[..., :3] * np.exp2(e - 136), 0.0).astype(np.float32)


# ------------------------------------------------------------------------------------------------------------
# Real assets


@needs_assets
@pytest.mark.parametrize("name,h,w,negative", ASSETS, ids=[a[0] for a in ASSETS])
def test_shared_assets_load(name, h, w, negative):
    img = read_hdr_image(HDRI / name)
    assert img.shape == (h, w, 3) and img.dtype == np.float32
    assert np.isfinite(img).all()
    if negative:
        with pytest.raises(EnvironmentMapError, match=r"\d+ negative texel values") as err:
            check_texels(img, repair=False, name=name)
        assert name in str(err.value) and "repair=True" in str(err.value)
        fixed, report = check_texels(img, repair=True, name=name)
        assert report.repaired and report.n_negative == int(np.count_nonzero(img < 0)) > 0
        assert report.n_nan == report.n_inf == 0
        assert fixed.min() >= 0 and np.isfinite(fixed).all()
    else:
        assert img.min() >= 0
        _, report = check_texels(img, repair=False, name=name)
        assert report == TexelReport(0, 0, 0, False)


@needs_assets
def test_rooitou_sun_exceeds_half_float_range():
    img = read_hdr_image(HDRI / "rooitou_park_1k.hdr")
    assert img.max() > 65504.0
    assert img.max() == 69120.0  # 135 * 2^9: mantissa * 2^(E - 136) without Radiance's +0.5 bias


@needs_assets
@pytest.mark.parametrize("name", ["ennis.hdr", "pisa.hdr"])
def test_fast_rgbe_decoder_matches_reference(name):
    np.testing.assert_array_equal(read_hdr_image(HDRI / name), read_rgbe_reference(HDRI / name))


@needs_assets
def test_1k_rgbe_decodes_well_under_a_second():
    read_hdr_image(HDRI / "adams_place_bridge_1k.hdr")  # warm up imports and caches
    t0 = time.perf_counter()
    img = read_hdr_image(HDRI / "adams_place_bridge_1k.hdr")
    elapsed = time.perf_counter() - t0
    assert img.shape == (512, 1024, 3)
    assert elapsed < 1.0, f"decoding a 1024x512 RLE file took {elapsed:.2f} s"


@needs_assets
def test_tiled_mipmapped_exr_reads_full_resolution_level():
    header = OpenEXR.File(str(HDRI / "openexr_StageEnvLatLong.exr"), header_only=True).header()
    assert header["tiles"].mode == OpenEXR.MIPMAP_LEVELS
    img = read_hdr_image(HDRI / "openexr_StageEnvLatLong.exr")
    assert img.shape == (500, 1000, 3)
    assert img.max() == 4096.0


# ------------------------------------------------------------------------------------------------------------
# Radiance RGBE details


@pytest.mark.parametrize("rle", [True, False])
def test_rgbe_round_trip_exact(tmp_path, rle):
    rgbe = _rgbe_image(np.random.default_rng(1), 9, 37)
    path = write_rgbe(tmp_path / "a.hdr", rgbe, rle=rle)
    np.testing.assert_array_equal(read_hdr_image(path), _expected(rgbe))
    np.testing.assert_array_equal(read_hdr_image(path), read_rgbe_reference(path))


def test_a_file_named_for_another_format_reads_as_what_it_is_and_says_so(tmp_path):
    """A Radiance file saved as .exr (and an EXR saved as .hdr) reads by its bytes, with a warning that
    names both."""
    import shutil

    rgbe = _rgbe_image(np.random.default_rng(2), 5, 11)
    hdr = write_rgbe(tmp_path / "a.hdr", rgbe)
    misnamed = shutil.copy(hdr, tmp_path / "studio.exr")
    with pytest.warns(UserWarning, match=r"studio\.exr: named \.exr but a Radiance RGBE file"):
        np.testing.assert_array_equal(read_hdr_image(misnamed), _expected(rgbe))
    exr = tmp_path / "b.exr"
    write_exr(exr, np.ones((4, 8, 3), np.float32))
    with pytest.warns(UserWarning, match="named .hdr but an OpenEXR file"):
        assert read_hdr_image(shutil.copy(exr, tmp_path / "b.hdr")).shape == (4, 8, 3)


def test_rgbe_narrow_images_are_flat(tmp_path):
    rgbe = _rgbe_image(np.random.default_rng(2), 3, 6)  # width < 8: writers never run-length encode
    np.testing.assert_array_equal(read_hdr_image(write_rgbe(tmp_path / "n.hdr", rgbe)), _expected(rgbe))


def test_rgbe_literal_runs_of_one_worst_case(tmp_path):
    # Every value its own literal run: 2 bytes per value, twice the usual scanline length.
    rgbe = _rgbe_image(np.random.default_rng(3), 4, 40)
    h, w = rgbe.shape[:2]
    data = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w))
    for row in rgbe:
        data += bytes([2, 2, 0, w])
        for c in range(4):
            for v in row[:, c]:
                data += bytes([1, v])
    (tmp_path / "lit.hdr").write_bytes(bytes(data))
    np.testing.assert_array_equal(read_hdr_image(tmp_path / "lit.hdr"), _expected(rgbe))


def test_rgbe_exposure_is_ignored_and_other_orientations_flip(tmp_path):
    rgbe = _rgbe_image(np.random.default_rng(4), 5, 16)
    base = read_hdr_image(write_rgbe(tmp_path / "a.hdr", rgbe))
    exposed = read_hdr_image(write_rgbe(tmp_path / "b.hdr", rgbe,
                                        header=b"FORMAT=32-bit_rle_rgbe\nEXPOSURE=2.5\n"))
    np.testing.assert_array_equal(base, exposed)
    up = read_hdr_image(write_rgbe(tmp_path / "c.hdr", rgbe, resolution=b"+Y 5 +X 16\n"))
    np.testing.assert_array_equal(up, base[::-1])
    mirrored = read_hdr_image(write_rgbe(tmp_path / "d.hdr", rgbe, resolution=b"-Y 5 -X 16\n"))
    np.testing.assert_array_equal(mirrored, base[:, ::-1])


def test_rgbe_rejects_rotated_orientation_and_xyz(tmp_path):
    rgbe = _rgbe_image(np.random.default_rng(5), 4, 8)
    with pytest.raises(EnvironmentMapError, match=r"orientation '\+X 8 -Y 4' is not supported"):
        read_hdr_image(write_rgbe(tmp_path / "rot.hdr", rgbe, resolution=b"+X 8 -Y 4\n"))
    with pytest.raises(EnvironmentMapError, match="32-bit_rle_xyze"):
        read_hdr_image(write_rgbe(tmp_path / "xyz.hdr", rgbe, header=b"FORMAT=32-bit_rle_xyze\n"))


def test_truncated_and_garbage_files_name_the_file(tmp_path):
    rgbe = _rgbe_image(np.random.default_rng(6), 12, 64)
    good = write_rgbe(tmp_path / "good.hdr", rgbe).read_bytes()
    cases = {
        "cut_in_header.hdr": (good[:20], "header does not end"),
        "cut_in_resolution.hdr": (good[:good.index(b"\n\n") + 4], "resolution"),
        "cut_in_pixels.hdr": (good[:len(good) * 2 // 3], "truncated"),
        "cut_flat.hdr": (write_rgbe(tmp_path / "f.hdr", rgbe, rle=False).read_bytes()[:-5], "truncated"),
        "garbage.hdr": (bytes(range(256)) * 4, "not a Radiance RGBE file"),
        "empty.hdr": (b"", "not a Radiance RGBE file"),
        "bad_width.hdr": (good.replace(b"\x02\x02\x00\x40", b"\x02\x02\x00\x41", 1), "declares width 65"),
        "garbage.exr": (b"\x76\x2f\x31\x01" + bytes(range(200)), "OpenEXR"),
        "not_exr.exr": (b"hello world", "not an OpenEXR file"),
        "unknown.png": (b"\x89PNG....", "unsupported file type"),
    }
    for name, (data, what) in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(EnvironmentMapError, match=what) as err:
            read_hdr_image(tmp_path / name)
        assert name in str(err.value)
    with pytest.raises(EnvironmentMapError, match="no such file"):
        read_hdr_image(tmp_path / "missing.hdr")


def test_truncated_exr(tmp_path):
    path = tmp_path / "t.exr"
    write_exr(path, np.random.default_rng(7).random((64, 128, 3), np.float32))
    data = path.read_bytes()
    for keep in (len(data) // 3, len(data) - 10):
        (tmp_path / "cut.exr").write_bytes(data[:keep])
        with pytest.raises(EnvironmentMapError, match="cut.exr"):
            read_hdr_image(tmp_path / "cut.exr")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0, 1),
       st.integers(0, 255)), max_size=4))
def test_damaged_rgbe_raises_only_environment_map_error(tmp_path, seed, cut, flips):
    rgbe = _rgbe_image(np.random.default_rng(seed), 6, 24)
    data = bytearray(write_rgbe(tmp_path / "src.hdr", rgbe).read_bytes())
    start = data.index(b"\n\n") + 2
    for where, value in flips:
        data[start + int(where * (len(data) - start - 1))] = value
    data = data[:max(start, int(cut * len(data)))] if cut < 0.98 else data
    (tmp_path / "damaged.hdr").write_bytes(bytes(data))
    try:
        img = read_hdr_image(tmp_path / "damaged.hdr")
    except EnvironmentMapError as err:
        assert "damaged.hdr" in str(err)
    else:
        assert img.dtype == np.float32 and img.ndim == 3 and img.shape[2] == 3


# ------------------------------------------------------------------------------------------------------------
# OpenEXR


def test_write_exr_round_trip(tmp_path):
    rng = np.random.default_rng(8)
    rgb = (rng.random((33, 70, 3)) * 1e5).astype(np.float32)
    write_exr(tmp_path / "f.exr", rgb)
    np.testing.assert_array_equal(read_hdr_image(tmp_path / "f.exr"), rgb)
    assert OpenEXR.File(str(tmp_path / "f.exr"), header_only=True).header()["compression"] == OpenEXR.ZIP_COMPRESSION

    small = rgb / 10.0
    write_exr(tmp_path / "h.exr", small, half=True)
    np.testing.assert_allclose(read_hdr_image(tmp_path / "h.exr"), small, rtol=2**-11)

    rgba = np.concatenate([rgb, np.full((33, 70, 1), 0.25, np.float32)], axis=-1)
    write_exr(tmp_path / "a.exr", rgba)
    np.testing.assert_array_equal(read_hdr_image(tmp_path / "a.exr"), rgb)  # alpha dropped


def test_written_exrs_state_rec709_chromaticities(tmp_path):
    """The renderer's linear RGB is Rec. 709 / sRGB with D65 white; every EXR it writes says so."""
    rgb = np.full((3, 5, 3), 0.5, np.float32)
    for name, image, half in (("rgb.exr", rgb, False), ("half.exr", rgb, True),
                              ("rgba.exr", np.concatenate([rgb, np.ones((3, 5, 1), np.float32)], axis=-1), False)):
        write_exr(tmp_path / name, image, half=half)
        assert_rec709_exr(tmp_path / name)


def test_write_exr_refuses_half_overflow_and_bad_shapes(tmp_path):
    with pytest.raises(InvalidInputError, match="half-float range"):
        write_exr(tmp_path / "o.exr", np.full((2, 2, 3), 70000.0, np.float32), half=True)
    with pytest.raises(InvalidInputError, match=r"\(H, W, 3\)"):
        write_exr(tmp_path / "s.exr", np.zeros((4, 4), np.float32))


def test_exr_luminance_only_and_data_window(tmp_path):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    y = np.arange(12, dtype=np.float32).reshape(3, 4)
    OpenEXR.File(header, {"Y": y}).write(str(tmp_path / "y.exr"))
    img = read_hdr_image(tmp_path / "y.exr")
    assert img.shape == (3, 4, 3)
    for c in range(3):
        np.testing.assert_array_equal(img[..., c], y)

    windowed = dict(header, dataWindow=(np.array([2, 1], np.int32), np.array([5, 2], np.int32)),
                    displayWindow=(np.array([0, 0], np.int32), np.array([7, 3], np.int32)))
    OpenEXR.File(windowed, {"RGB": np.ones((2, 4, 3), np.float32)}).write(str(tmp_path / "w.exr"))
    img = read_hdr_image(tmp_path / "w.exr")
    assert img.shape == (4, 8, 3)
    assert img[1:3, 2:6].min() == 1.0 and img.sum() == 2 * 4 * 3


def test_exr_without_colour_channels(tmp_path):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"Z": np.ones((2, 2), np.float32)}).write(str(tmp_path / "z.exr"))
    with pytest.raises(EnvironmentMapError, match=r"z.exr: no colour channels; found \['Z'\]"):
        read_hdr_image(tmp_path / "z.exr")


# ------------------------------------------------------------------------------------------------------------
# Texel checks


def test_check_texels_clean_is_passthrough():
    img = np.ones((4, 8, 3), np.float32)
    out, report = check_texels(img, repair=False, name="clean")
    assert out is img
    assert report.as_dict() == {"n_nan": 0, "n_inf": 0, "n_negative": 0, "repaired": False}
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.n_nan = 1


def test_check_texels_reports_and_repairs():
    img = np.ones((4, 8, 3), np.float32)
    img[0, 1, 0] = np.nan
    img[0, 1, 2] = np.nan
    img[2, 3, 1] = np.inf
    img[3, 0, 0] = -np.inf
    img[1, 5] = -0.5
    img[1, 6, 2] = 7.0
    with pytest.raises(EnvironmentMapError) as err:
        check_texels(img, repair=False, name="dirty")
    msg = str(err.value)
    assert "dirty: 2 NaN, 1 +Inf, 1 -Inf and 3 negative texel values in 4 of 32 texels (12.5%)" in msg
    assert "(0, 1), (1, 5), (2, 3), (3, 0)" in msg

    fixed, report = check_texels(img, repair=True, name="dirty")
    assert report == TexelReport(n_nan=2, n_inf=2, n_negative=3, repaired=True)
    assert fixed[0, 1, 0] == 0 and fixed[3, 0, 0] == 0 and (fixed[1, 5] == 0).all()
    assert fixed[2, 3, 1] == 7.0  # +Inf -> largest finite value
    assert np.isnan(img[0, 1, 0])  # the input is not modified


# ------------------------------------------------------------------------------------------------------------
# Loading environment maps


def test_environment_from_array():
    rng = np.random.default_rng(9)
    img = rng.random((32, 64, 3)).astype(np.float32)
    env = environment_from_array(img, "auto", 16, "noise")
    assert isinstance(env, EnvironmentMap)
    assert env.layout is Layout.LATLONG and env.face_size == 16 and env.source_shape == (32, 64, 3)
    assert env.cube.shape == (6, 16, 16, 3) and env.cube.dtype == np.float32
    assert not env.cube.flags.writeable
    with pytest.raises(ValueError):
        env.cube[0, 0, 0, 0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        env.name = "other"
    assert env.texel_report == TexelReport(0, 0, 0, False)

    same = environment_from_array(img.copy(), Layout.LATLONG, 8, "again")
    assert same.content_hash == env.content_hash  # pixels + layout, not face size or name
    changed = img.copy()
    changed[3, 4, 1] += 1e-3
    assert environment_from_array(changed, "latlong", 16, "x").content_hash != env.content_hash
    square = rng.random((32, 32, 3)).astype(np.float32)
    assert environment_from_array(square, "auto", 8, "probe").layout is Layout.ANGULAR


@pytest.mark.parametrize("bad", [3, 100, 4096, 0, True, 16.0, "128"])
def test_face_size_validation(bad):
    with pytest.raises(InvalidInputError, match="face_size must be a power of two from 4 to 2048"):
        environment_from_array(np.ones((8, 16, 3), np.float32), "auto", bad, "x")


def test_environment_input_validation():
    with pytest.raises(InvalidInputError, match=r"\(H, W, 3\)"):
        environment_from_array(np.ones((8, 16), np.float32), "auto", 8, "gray")
    with pytest.raises(InvalidInputError, match="unknown environment-map layout 'cubemap'"):
        environment_from_array(np.ones((8, 16, 3), np.float32), "cubemap", 8, "x")
    with pytest.raises(EnvironmentMapError, match="cannot tell the layout of a 10x8"):
        environment_from_array(np.ones((8, 10, 3), np.float32), "auto", 8, "x")
    with pytest.raises(EnvironmentMapError, match="hcross map must be 4x3 square tiles"):
        environment_from_array(np.ones((8, 16, 3), np.float32), "hcross", 8, "x")
    nan = np.ones((8, 16, 3), np.float32)
    nan[2, 2] = np.nan
    with pytest.raises(EnvironmentMapError, match="nanmap: 3 NaN"):
        environment_from_array(nan, "auto", 8, "nanmap")
    env = environment_from_array(nan, "auto", 8, "nanmap", repair=True)
    assert env.texel_report.n_nan == 3 and env.texel_report.repaired and np.isfinite(env.cube).all()


@needs_assets
def test_load_environment_repairs_negative_texels():
    path = HDRI / "pmndrs_assets_hall.exr"
    with pytest.raises(EnvironmentMapError, match="pmndrs_assets_hall"):
        load_environment(path, face_size=32)
    env = load_environment(path, face_size=32, repair=True)
    assert env.name == "pmndrs_assets_hall" and env.source == str(path)
    assert env.texel_report.n_negative > 0 and env.cube.min() >= 0
