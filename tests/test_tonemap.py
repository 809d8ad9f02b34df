"""Tone curves, the sRGB OETF, PNG encoding and auto exposure (numpy + Pillow, no GPU)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from PIL import Image

from renderer.errors import InvalidInputError
from renderer.shading.tonemap import (
    EXPOSURE_KEY,
    ToneCurve,
    aces_filmic,
    auto_exposure_ev,
    encode_rgba8,
    srgb_eotf,
    srgb_oetf,
    to_png_bytes,
    tonemap,
    write_png,
)

SCENE_VALUES = np.concatenate([[0.0], np.geomspace(1e-6, 1e6, 4001)]).astype(np.float32)


def grey(value: float, h: int = 2, w: int = 3) -> np.ndarray:
    return np.full((h, w, 3), value, np.float32)


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
    y = tonemap(SCENE_VALUES, curve=curve)
    assert y.dtype == np.float32 and y.shape == SCENE_VALUES.shape
    assert y.min() >= 0.0 and y.max() <= 1.0
    assert (np.diff(y) >= 0).all()
    assert y[0] == 0.0


@given(st.floats(0, 1e6), st.floats(0, 1e6), st.sampled_from(list(ToneCurve)), st.floats(-20, 20))
@example(846202.0, 619645.5, ToneCurve.REINHARD, 5.1171875)  # x / (1 + x) in float32 mapped these the wrong way
def test_tonemap_is_monotone_for_any_pair(a, b, curve, ev):
    lo, hi = sorted((a, b))
    y = tonemap(np.array([lo, hi], np.float32), ev, curve)
    assert y[0] <= y[1]


def test_curves_at_known_points():
    # Narkowicz: the fit is pre-exposed so that 1 maps to ~0.8 (display-linear), and saturates.
    assert float(aces_filmic(np.float32(1.0))) == pytest.approx(2.54 / 3.16, abs=1e-6)
    assert float(aces_filmic(np.float32(1e6))) == 1.0
    x = np.array([0.5, 1.0, 2.0], np.float32)
    np.testing.assert_allclose(tonemap(x, curve="linear"), srgb_oetf(np.array([0.5, 1.0, 1.0])))
    np.testing.assert_allclose(tonemap(x, curve=ToneCurve.REINHARD), srgb_oetf(x / (1 + x)), atol=1e-7)
    np.testing.assert_allclose(tonemap(x), srgb_oetf(aces_filmic(x)), atol=1e-7)


def test_one_stop_of_exposure_doubles_the_input():
    x = np.geomspace(1e-3, 10, 50).astype(np.float32)
    for curve in ToneCurve:
        np.testing.assert_allclose(tonemap(x, 1.0, curve), tonemap(2 * x, 0.0, curve), atol=1e-7)


def test_non_finite_and_negative_values_never_escape():
    x = np.array([np.nan, -1.0, -np.inf, np.inf, 1e300], np.float64)
    for curve in ToneCurve:
        y = tonemap(x, 0.0, curve)
        np.testing.assert_array_equal(y[:3], 0.0)
        assert y[3] == pytest.approx(1.0) and y[4] == pytest.approx(1.0)
    # Extreme exposure cannot produce NaN either (0 * 2**huge would).
    assert np.isfinite(tonemap(np.array([0.0, 1.0]), 1e6)).all()
    assert tonemap(np.array([0.0]), 1e6)[0] == 0.0


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
    expected_rgb = np.rint(tonemap(rgba[..., :3], 0.5, "reinhard") * 255)
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
