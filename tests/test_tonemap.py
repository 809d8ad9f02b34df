"""Tone curves, the sRGB OETF, PNG encoding and auto exposure (numpy + Pillow, no GPU)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from conftest import assert_tagged_srgb
from hypothesis import example, given
from hypothesis import strategies as st
from PIL import Image

from renderer.errors import InvalidInputError
from renderer.shading.tonemap import (
    DEFAULT_CURVE,
    EXPOSURE_KEY,
    ToneCurve,
    aces_filmic,
    auto_exposure_ev,
    encode_rgba8,
    pbr_neutral,
    srgb_eotf,
    srgb_oetf,
    to_png_bytes,
    tonemap,
    write_png,
)

SCENE_VALUES = np.concatenate([[0.0], np.geomspace(1e-6, 1e6, 4001)]).astype(np.float32)


def grey(value: float, h: int = 2, w: int = 3) -> np.ndarray:
    return np.full((h, w, 3), value, np.float32)


def greys(values) -> np.ndarray:
    """Values (...,) as grey colours (..., 3): every curve maps them, pbr-neutral only RGB triples."""
    return np.repeat(np.asarray(values, np.float32)[..., None], 3, axis=-1)


# --- sRGB --------------------------------------------------------------------------------------


def test_srgb_oetf_endpoints_and_known_value():
    assert srgb_oetf(np.float32(0.0)) == 0.0
    assert srgb_oetf(np.float32(1.0)) == 1.0
    assert float(srgb_oetf(np.float32(0.5))) == pytest.approx(0.7354, abs=1e-4)
    assert float(srgb_oetf(np.float32(0.18))) == pytest.approx(0.4614, abs=1e-4)  # middle grey


def test_srgb_oetf_pieces_meet_and_increase():
    # The linear toe and the power segment agree at the breakpoint (continuity of IEC 61966-2-1).
    t = 0.0031308
    assert 12.92 * t == pytest.approx(1.055 * t ** (1 / 2.4) - 0.055, abs=1e-6)
    x = np.linspace(0.0, 1.0, 100001, dtype=np.float32)
    assert (np.diff(srgb_oetf(x)) >= 0).all()


def test_srgb_eotf_inverts_oetf():
    x = np.linspace(0.0, 1.0, 1001, dtype=np.float32)
    np.testing.assert_allclose(srgb_eotf(srgb_oetf(x)), x, atol=2e-6)


# --- tone curves -------------------------------------------------------------------------------


@pytest.mark.parametrize("curve", list(ToneCurve))
def test_tonemap_is_monotone_and_in_unit_range(curve):
    y = tonemap(greys(SCENE_VALUES), curve=curve)
    assert y.dtype == np.float32 and y.shape == SCENE_VALUES.shape + (3,)
    assert y.min() >= 0.0 and y.max() <= 1.0
    assert (np.diff(y, axis=0) >= 0).all()
    assert (y[0] == 0.0).all()


@given(st.floats(0, 1e6), st.floats(0, 1e6), st.sampled_from(list(ToneCurve)), st.floats(-20, 20))
@example(846202.0, 619645.5, ToneCurve.REINHARD, 5.1171875)  # x / (1 + x) in float32 mapped these the wrong way
def test_tonemap_is_monotone_for_any_pair(a, b, curve, ev):
    lo, hi = sorted((a, b))
    y = tonemap(greys([lo, hi]), ev, curve)
    assert (y[0] <= y[1]).all()


def test_curves_at_known_points():
    # Narkowicz: the fit is pre-exposed so that 1 maps to ~0.8 (display-linear), and saturates.
    assert float(aces_filmic(np.float32(1.0))) == pytest.approx(2.54 / 3.16, abs=1e-6)
    assert float(aces_filmic(np.float32(1e6))) == 1.0
    x = np.array([0.5, 1.0, 2.0], np.float32)
    np.testing.assert_allclose(tonemap(x, curve="linear"), srgb_oetf(np.array([0.5, 1.0, 1.0])))
    np.testing.assert_allclose(tonemap(x, curve=ToneCurve.REINHARD), srgb_oetf(x / (1 + x)), atol=1e-7)
    np.testing.assert_allclose(tonemap(x, curve="filmic"), srgb_oetf(aces_filmic(x)), atol=1e-7)
    # PBR Neutral on a grey 1: p = 1 - F90 = 0.96 > Ks, so p_n = 1 - (1 - Ks)^2 / (p + 1 - 2 Ks) = 1 - 0.0576 / 0.44.
    np.testing.assert_allclose(tonemap(greys([1.0]), curve="pbr-neutral"), srgb_oetf(greys([1 - 0.0576 / 0.44])),
                               atol=1e-6)


def test_the_default_curve_is_pbr_neutral_everywhere():
    """Product images keep their base colours: the default of the functions, the CLI and the service."""
    from renderer.cli import build_parser
    from service.schemas import OutputSpec

    assert DEFAULT_CURVE is ToneCurve.PBR_NEUTRAL
    rgb = np.array([[0.3, 0.5, 0.9], [2.0, 0.1, 0.05]], np.float32)
    np.testing.assert_array_equal(tonemap(rgb), tonemap(rgb, curve="pbr-neutral"))
    for command in (["render"], ["sequence", "--frames", "f", "--out", "o"], ["reference"]):
        assert build_parser().parse_args(command).tone == "pbr-neutral"
    assert OutputSpec().tone == "pbr-neutral"


@pytest.mark.parametrize("curve", list(ToneCurve))
def test_every_curve_is_offered_by_the_cli_and_the_service(curve):
    from renderer.cli import build_parser
    from service.schemas import OutputSpec

    for command in (["render"], ["sequence", "--frames", "f", "--out", "o"], ["reference"]):
        assert build_parser().parse_args(command + ["--tone", curve.value]).tone == curve.value
    assert OutputSpec(tone=curve.value).tone == curve.value


def test_one_stop_of_exposure_doubles_the_input():
    x = greys(np.geomspace(1e-3, 10, 50))
    for curve in ToneCurve:
        np.testing.assert_allclose(tonemap(x, 1.0, curve), tonemap(2 * x, 0.0, curve), atol=1e-7)


def test_non_finite_and_negative_values_never_escape():
    x = np.repeat(np.array([np.nan, -1.0, -np.inf, np.inf, 1e300], np.float64)[:, None], 3, axis=1)
    for curve in ToneCurve:
        y = tonemap(x, 0.0, curve)
        np.testing.assert_array_equal(y[:3], 0.0)
        assert y[3] == pytest.approx(1.0) and y[4] == pytest.approx(1.0)
    # Extreme exposure cannot produce NaN either (0 * 2**huge would).
    assert np.isfinite(tonemap(greys([0.0, 1.0]), 1e6)).all()
    assert (tonemap(greys([0.0]), 1e6) == 0.0).all()


# --- Khronos PBR Neutral -------------------------------------------------------------------------

F90 = 0.04  # the specification's F90: what a dielectric reflects at normal incidence


def base_colours(n: int, lo: float, hi: float, seed: int = 5) -> np.ndarray:
    """n random colours (n, 3) with every channel in [lo, hi], and the corners of that cube."""
    rng = np.random.default_rng(seed)
    corners = np.array(np.meshgrid([lo, hi], [lo, hi], [lo, hi])).reshape(3, -1).T
    return np.concatenate([rng.uniform(lo, hi, (n, 3)), corners]).astype(np.float32)


def test_pbr_neutral_shows_a_furnace_dielectric_as_its_base_colour():
    """The specification's guarantee: where every channel of a colour lies in [2 F90, Ks + F90] =
    [0.08, 0.8], the curve is exactly c - F90. So a shiny dielectric of base colour c in [0.04, 0.76]
    facing the camera under white light of radiance 1, whose radiance Khronos takes as c + F90, shows
    as c: the same 8-bit sRGB code values as the base colour itself (within float32 rounding)."""
    c = base_colours(20000, F90, 0.8 - 2 * F90)
    np.testing.assert_allclose(pbr_neutral(c + np.float32(F90)), c, rtol=0, atol=2e-7)
    codes = encode_rgba8(c[None] + np.float32(F90), 0.0, ToneCurve.PBR_NEUTRAL)[0, :, :3].astype(int)
    want = np.rint(srgb_oetf(c) * 255).astype(int)
    assert np.abs(codes - want).max() <= 1 and (codes == want).mean() > 0.999
    # The range's own ends: min(c) = 0.08 and max(c) = 0.8 are still on the identity.
    np.testing.assert_allclose(pbr_neutral(np.array([0.08, 0.8, 0.3], np.float32)), [0.04, 0.76, 0.26], atol=2e-7)


def test_pbr_neutral_lifts_dark_colours_by_its_offset():
    """Below min(c) = 2 F90 the offset is f = x - x^2 / (4 F90), x = min(c): so the furnace colour
    c + F90 of a base colour with min(c) < F90 shows as c + (x - 2 F90)^2 / (4 F90) on every channel,
    with x = min(c) + F90: black base colour as F90 / 4 = 0.01, never the base colour itself."""
    c = base_colours(5000, 0.0, 0.7)
    n = np.arange(len(c))
    c[n, n % 3] *= np.float32(F90 / 0.7)  # one channel of each below F90
    x = c.min(axis=1, keepdims=True) + F90
    lift = (x - 2 * F90) ** 2 / (4 * F90)
    np.testing.assert_allclose(pbr_neutral(c + np.float32(F90)), c + lift, rtol=0, atol=3e-7)
    assert float(pbr_neutral(np.full(3, F90, np.float32))[0]) == pytest.approx(0.01, abs=1e-8)
    assert (pbr_neutral(np.zeros((4, 3), np.float32)) == 0).all()  # black stays black


@given(st.tuples(*[st.floats(0.0, 1e4)] * 3))
def test_pbr_neutral_keeps_hue(rgb):
    """No hue shift: the output lies in the plane of the input and the white axis (the offset
    subtracts grey, the compression scales and mixes with grey), and the channels keep their order."""
    c = np.array(rgb, np.float32)
    out = pbr_neutral(c).astype(np.float64)
    assert 0.0 <= out.min() and out.max() <= 1.0
    normal = np.cross(c.astype(np.float64), np.ones(3))
    assert abs(out @ normal) <= 1e-5 * max(np.linalg.norm(normal), 1.0)
    order = np.argsort(c, kind="stable")
    assert (np.diff(out[order]) >= -1e-6).all()


def test_pbr_neutral_compresses_smoothly_from_ks_toward_white():
    """Above the peak Ks = 0.76 (after the offset) the curve leaves the identity with value and slope
    continuous, saturated colours desaturate toward the grey p_n, and white is reached only in the limit."""
    ks = 0.8 - F90
    p = np.array([ks - 1e-4, ks, ks + 1e-4], np.float32) + np.float32(F90)
    y = pbr_neutral(greys(p))[:, 0]
    np.testing.assert_allclose(np.diff(y), 1e-4, rtol=2e-2)  # slope 1 on both sides of Ks
    red = pbr_neutral(np.array([[1.0, 0.1, 0.1], [10.0, 1.0, 1.0], [1e3, 100.0, 100.0]], np.float32))
    spread = (red.max(axis=1) - red.min(axis=1)) / red.max(axis=1)
    assert (np.diff(spread) < 0).all() and spread[-1] < 0.01
    y = pbr_neutral(greys([1.0, 10.0, 1e3]))[:, 0]
    assert (np.diff(y) > 0).all() and y[-1] < 1.0
    with pytest.raises(InvalidInputError, match=r"\(\.\.\., 3\)"):
        pbr_neutral(np.ones(5, np.float32))


def test_tonemap_rejects_bad_options():
    with pytest.raises(InvalidInputError, match="filmic"):
        tonemap(grey(1.0), curve="aces2")
    with pytest.raises(InvalidInputError, match="finite"):
        tonemap(grey(1.0), exposure_ev=float("nan"))
    with pytest.raises(InvalidInputError, match="real numeric"):
        tonemap(np.array(["a"]))
    assert ToneCurve("reinhard") is ToneCurve.REINHARD and ToneCurve.parse("LINEAR") is ToneCurve.LINEAR


# --- PNG ---------------------------------------------------------------------------------------


def test_png_round_trip_through_pillow():
    rng = np.random.default_rng(3)
    rgba = rng.uniform(0, 4, size=(5, 7, 4)).astype(np.float32)
    rgba[..., 3] = rng.uniform(0, 1, size=(5, 7))
    data = to_png_bytes(rgba, 0.5, ToneCurve.REINHARD)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    img = Image.open(io.BytesIO(data))
    assert img.mode == "RGBA" and img.size == (7, 5)  # (width, height): row 0 is the top row
    decoded = np.asarray(img)
    np.testing.assert_array_equal(decoded, encode_rgba8(rgba, 0.5, ToneCurve.REINHARD))
    # The frame's colour is premultiplied by coverage, the PNG's straight: divided by alpha, then mapped.
    expected_rgb = np.rint(tonemap(rgba[..., :3] / rgba[..., 3:], 0.5, "reinhard") * 255)
    np.testing.assert_array_equal(decoded[..., :3], expected_rgb)
    np.testing.assert_array_equal(decoded[..., 3], np.rint(rgba[..., 3] * 255))  # coverage, not tone-mapped


def test_png_survives_nan_and_treats_it_as_zero():
    rgba = np.ones((2, 2, 4), np.float32)
    rgba[0, 0] = np.nan
    rgba[1, 1, 3] = np.inf
    rgba[1, 0, 3] = -2.0
    decoded = np.asarray(Image.open(io.BytesIO(to_png_bytes(rgba))))
    np.testing.assert_array_equal(decoded[0, 0], [0, 0, 0, 0])
    assert decoded[1, 1, 3] == 255 and decoded[1, 0, 3] == 0


def test_png_of_rgb_is_opaque_and_bad_shapes_are_errors(tmp_path):
    decoded = np.asarray(Image.open(io.BytesIO(to_png_bytes(grey(0.18)))))
    np.testing.assert_array_equal(decoded[..., 3], 255)
    for bad in (np.zeros((4, 4)), np.zeros((4, 4, 2)), np.zeros((0, 4, 4))):
        with pytest.raises(InvalidInputError, match="shape"):
            to_png_bytes(bad)
    with pytest.raises(InvalidInputError, match="compress_level"):
        to_png_bytes(grey(0.5), compress_level=12)


def test_write_png(tmp_path):
    path = tmp_path / "frame.png"
    rgba = np.concatenate([grey(0.5, 3, 4), np.ones((3, 4, 1), np.float32)], axis=2)
    write_png(path, rgba, 0.0, ToneCurve.LINEAR)
    decoded = np.asarray(Image.open(path))
    assert decoded.shape == (3, 4, 4)
    np.testing.assert_array_equal(decoded[..., :3], round(0.7354 * 255))


def test_every_png_is_tagged_srgb(tmp_path):
    rgba = np.concatenate([grey(0.5, 3, 4), np.ones((3, 4, 1), np.float32)], axis=2)
    assert_tagged_srgb(to_png_bytes(rgba))
    assert_tagged_srgb(to_png_bytes(grey(0.5)[..., :3], compress_level=0))
    write_png(tmp_path / "frame.png", rgba, 0.0, ToneCurve.FILMIC)
    assert_tagged_srgb((tmp_path / "frame.png").read_bytes())


# --- auto exposure -----------------------------------------------------------------------------


def test_auto_exposure_maps_the_median_of_covered_pixels_to_the_key():
    lum = np.array([[0.05, 0.1, 0.2], [0.4, 0.8, 1000.0]], np.float32)
    rgb = np.repeat(lum[..., None], 3, axis=2)  # grey: luminance = value
    alpha = np.array([[1, 1, 1], [1, 1, 0]], np.float32)  # the bright background is not covered
    ev = auto_exposure_ev(rgb, alpha)
    assert ev == pytest.approx(np.log2(EXPOSURE_KEY / 0.2))
    # The 4th channel is used as alpha when no alpha is given.
    assert auto_exposure_ev(np.concatenate([rgb, alpha[..., None]], axis=2)) == pytest.approx(ev)
    # Without alpha, every pixel counts.
    assert auto_exposure_ev(rgb) == pytest.approx(np.log2(EXPOSURE_KEY / 0.3))


def test_auto_exposure_uses_rec709_luminance():
    rgb = np.zeros((1, 1, 3), np.float32)
    rgb[..., 1] = 1.0  # pure green: luminance 0.7152
    assert auto_exposure_ev(rgb) == pytest.approx(np.log2(EXPOSURE_KEY / 0.7152), rel=1e-6)


@pytest.mark.parametrize(
    "rgb, alpha",
    [
        (grey(0.0), None),  # all black
        (grey(1.0), np.zeros((2, 3))),  # nothing covered
        (np.full((2, 3, 3), np.nan, np.float32), None),  # nothing finite
        (grey(-1.0), None),  # negative ringing counts as black
    ],
)
def test_auto_exposure_is_zero_when_there_is_nothing_to_expose(rgb, alpha):
    assert auto_exposure_ev(rgb, alpha) == 0.0


def test_auto_exposure_is_always_finite():
    assert auto_exposure_ev(grey(1e-30)) == 32.0
    assert auto_exposure_ev(grey(3e38)) == -32.0  # clamped, and no overflow on the way
    img = grey(0.5)
    img[0, 0] = np.inf  # ignored, not propagated
    assert auto_exposure_ev(img) == pytest.approx(np.log2(0.18 / 0.5))
    with pytest.raises(InvalidInputError, match="alpha"):
        auto_exposure_ev(grey(0.5), np.ones((3, 3)))


def test_auto_exposure_is_the_figures_over_a_shadow_catchers_floor():
    """A shadow catcher's floor is black with its shadow in alpha: the figure alone sets the exposure."""
    rgb = np.zeros((4, 4, 3), np.float32)
    alpha = np.full((4, 4), 0.9, np.float32)   # the floor's shadow
    rgb[:2] = 0.3   # the figure: half of the covered pixels
    alpha[:2] = 1.0
    assert auto_exposure_ev(rgb, alpha) == pytest.approx(np.log2(EXPOSURE_KEY / 0.3))
