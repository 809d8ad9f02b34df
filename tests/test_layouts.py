"""Layouts, direction <-> image mappings and the area-correct resampling to cubes (renderer.envmap.layouts),
plus the procedural environments."""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest
from conftest import HDRI, needs_assets
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from renderer.envmap import (
    Layout,
    cube_solid_angles,
    cube_to_latlong,
    detect_layout,
    dir_to_image,
    dir_to_texel,
    image_to_dir,
    latlong_row_solid_angles,
    read_hdr_image,
    sample_bilinear,
    sky_environment,
    studio_environment,
    texel_directions,
    to_cube,
)
from renderer.errors import EnvironmentMapError

SIZES = {Layout.LATLONG: (64, 128), Layout.ANGULAR: (96, 96), Layout.HCROSS: (48, 64), Layout.VCROSS: (64, 48)}
# Tiles of the crosses: (column, row) -> face direction, as pinned in the layouts module docstring.
TILES = {
    Layout.HCROSS: {(0, 1): (-1, 0, 0), (1, 1): (0, 0, -1), (2, 1): (1, 0, 0), (3, 1): (0, 0, 1),
                    (1, 0): (0, 1, 0), (1, 2): (0, -1, 0)},
    Layout.VCROSS: {(1, 0): (0, 1, 0), (0, 1): (-1, 0, 0), (1, 1): (0, 0, -1), (2, 1): (1, 0, 0),
                    (1, 2): (0, -1, 0), (1, 3): (0, 0, 1)},
}
GRID = {Layout.HCROSS: (4, 3), Layout.VCROSS: (3, 4)}


def _latlong_energy(img):
    return (img * latlong_row_solid_angles(*img.shape[:2])[:, None, None]).sum(axis=(0, 1))


def _cube_energy(cube):
    return (cube * cube_solid_angles(cube.shape[1])[..., None]).sum(axis=(0, 1, 2))


def _angle(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0))


def _direction_image(layout, h, w, junk=100.0):
    """An image whose texels hold their own direction; texels without one (outside disc/tiles) hold junk."""
    d, valid = image_to_dir((np.arange(w) + 0.5)[None, :], (np.arange(h) + 0.5)[:, None], layout, h, w)
    return np.where(valid[..., None], d, junk).astype(np.float32)


# ------------------------------------------------------------------------------------------------------------
# Layout detection and pinned conventions


@pytest.mark.parametrize("h,w,layout", [(512, 1024, Layout.LATLONG), (1, 2, Layout.LATLONG), (256, 256, Layout.ANGULAR),
                                        (384, 512, Layout.HCROSS), (512, 384, Layout.VCROSS), (3, 4, Layout.HCROSS)])
def test_detect_layout(h, w, layout):
    assert detect_layout(h, w) is layout


def test_detect_layout_names_size_and_accepted_aspects():
    with pytest.raises(EnvironmentMapError, match=r"1000x512 \(width x height\).*2:1 lat-long.*1:1.*4:3.*3:4"):
        detect_layout(512, 1000)


def test_latlong_convention():
    h, w = 64, 128
    centre, _ = image_to_dir(0.5 * w, 0.5 * h, "latlong", h, w)
    right, _ = image_to_dir(0.75 * w, 0.5 * h, "latlong", h, w)
    left, _ = image_to_dir(0.25 * w, 0.5 * h, "latlong", h, w)
    top, _ = image_to_dir(0.3 * w, 0.0, "latlong", h, w)
    np.testing.assert_allclose(centre, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(left, [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(top, [0, 1, 0], atol=1e-12)
    x, y, _ = dir_to_image(np.array([0.0, 0.0, 1.0]), "latlong", h, w)  # +Z is the seam, u = 0
    assert (x, y) == (0.0, 0.5 * h)


def test_angular_convention():
    n = 100
    at = lambda x, y: image_to_dir(n * (x + 1) / 2, n * (1 - y) / 2, "angular", n, n)  # noqa: E731
    np.testing.assert_allclose(at(0, 0)[0], [0, 0, 1], atol=1e-12)  # centre: +Z
    np.testing.assert_allclose(at(0.5, 0)[0], [1, 0, 0], atol=1e-12)  # image x right: +X, at 90 degrees
    np.testing.assert_allclose(at(0, 0.5)[0], [0, 1, 0], atol=1e-12)  # image y up: +Y
    np.testing.assert_allclose(at(0, -0.999999)[0], [0, 0, -1], atol=1e-5)  # rim: -Z
    d, valid = at(0.8, 0.8)
    assert not valid and np.isnan(d).all()  # outside the disc
    # Debevec's formula: r = acos(Dz) / (pi sqrt(Dx^2 + Dy^2)), image point (Dx r, Dy r).
    D = np.array([0.3, -0.5, 0.2])
    D /= np.linalg.norm(D)
    r = np.arccos(D[2]) / (np.pi * np.hypot(D[0], D[1]))
    x, y, valid = dir_to_image(D, "angular", n, n)
    np.testing.assert_allclose([x, y], [n * (D[0] * r + 1) / 2, n * (1 - D[1] * r) / 2], rtol=1e-12)


@pytest.mark.parametrize("layout", [Layout.HCROSS, Layout.VCROSS])
def test_cross_tile_centres_and_empty_cells(layout):
    h, w = SIZES[layout]
    cols, rows = GRID[layout]
    f = w // cols
    for col in range(cols):
        for row in range(rows):
            d, valid = image_to_dir((col + 0.5) * f, (row + 0.5) * f, layout, h, w)
            if (col, row) in TILES[layout]:
                assert valid
                np.testing.assert_allclose(d, TILES[layout][(col, row)], atol=1e-12)
            else:
                assert not valid and np.isnan(d).all()


def test_cross_tile_orientation():
    # In the horizontal cross the -Z tile is seen with +X to the right and +Y up; the vertical cross's
    # +Z tile (below -Y) has +X to the right and -Y up.
    d, _ = image_to_dir(1.9 * 16, 1.5 * 16, Layout.HCROSS, 48, 64)
    assert d[0] > 0.5 and abs(d[1]) < 1e-12
    d, _ = image_to_dir(1.5 * 16, 1.1 * 16, Layout.HCROSS, 48, 64)
    assert d[1] > 0.5
    d, _ = image_to_dir(1.9 * 16, 3.5 * 16, Layout.VCROSS, 64, 48)
    assert d[0] > 0.5 and d[2] > 0
    d, _ = image_to_dir(1.5 * 16, 3.1 * 16, Layout.VCROSS, 64, 48)
    assert d[1] < -0.5


# ------------------------------------------------------------------------------------------------------------
# Round trips (hypothesis)

unit_vectors = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).map(np.array).filter(
    lambda v: np.linalg.norm(v) > 0.1).map(lambda v: v / np.linalg.norm(v))


@settings(max_examples=300, deadline=None)
@given(d=unit_vectors, layout=st.sampled_from(list(Layout)))
def test_direction_image_direction_round_trip(d, layout):
    h, w = SIZES[layout]
    if layout is Layout.ANGULAR:
        assume(d[2] > -1 + 1e-9)  # -Z is the whole rim circle: no unique image point
    x, y, valid = dir_to_image(d, layout, h, w)
    assert valid and 0 <= x <= w and 0 <= y <= h
    back, valid = image_to_dir(x, y, layout, h, w)
    assert valid
    assert _angle(back, d) < 1e-7


@settings(max_examples=300, deadline=None)
@given(xn=st.floats(0, 1, exclude_max=True), yn=st.floats(0, 1, exclude_max=True),
       layout=st.sampled_from(list(Layout)))
def test_image_direction_image_round_trip(xn, yn, layout):
    h, w = SIZES[layout]
    x, y = xn * w, yn * h
    d, valid = image_to_dir(x, y, layout, h, w)
    if not valid:
        return
    if layout is Layout.LATLONG:
        assume(1e-6 < yn < 1 - 1e-6)  # the poles are single directions
    if layout is Layout.ANGULAR:
        assume(np.hypot(2 * xn - 1, 1 - 2 * yn) < 1 - 1e-6)
    if layout in GRID:
        cols, rows = GRID[layout]
        gx, gy = xn * cols, yn * rows
        assume(min(gx % 1, 1 - gx % 1, gy % 1, 1 - gy % 1) > 1e-6)  # a shared edge belongs to two tiles
    x2, y2, valid2 = dir_to_image(d, layout, h, w)
    assert valid2
    dx = x2 - x
    if layout is Layout.LATLONG:
        dx = (dx + w / 2) % w - w / 2  # the left and right edges are the same meridian
    assert abs(dx) < 1e-6 and abs(y2 - y) < 1e-6


@pytest.mark.parametrize("layout", [Layout.HCROSS, Layout.VCROSS])
def test_cross_unfolding_is_continuous(layout):
    """Across every edge two tiles share in the image, neighbouring pixels see neighbouring directions, and
    directions on either side of the edge land in neighbouring pixels."""
    h, w = SIZES[layout]
    cols, _ = GRID[layout]
    f = w // cols
    tiles = TILES[layout]
    eps = 1e-6
    t = (np.arange(64) + 0.5) / 64
    n_edges = 0
    for (col, row) in tiles:
        for dc, dr in ((1, 0), (0, 1)):
            if (col + dc, row + dr) not in tiles:
                continue
            n_edges += 1
            if dc:  # vertical edge at x = (col + 1) f
                xa, xb = (col + 1) * f - eps, (col + 1) * f + eps
                ya = yb = (row + t) * f
            else:   # horizontal edge at y = (row + 1) f
                ya, yb = (row + 1) * f - eps, (row + 1) * f + eps
                xa = xb = (col + t) * f
            da, _ = image_to_dir(xa, ya, layout, h, w)
            db, _ = image_to_dir(xb, yb, layout, h, w)
            assert np.max(_angle(da, db)) < 1e-5, f"tiles {(col, row)} and {(col + dc, row + dr)} do not meet"
            # Directions nudged off the edge into either tile map next to each other in the image.
            mid = da + db
            for nudge in (da - db, db - da):
                xs, ys, _ = dir_to_image(mid + 1e-3 * nudge, layout, h, w)
                xm, ym, _ = dir_to_image(mid, layout, h, w)
                assert np.max(np.hypot(xs - xm, ys - ym)) < 1.0
    assert n_edges == 5


# ------------------------------------------------------------------------------------------------------------
# Resampling to the cube


@pytest.mark.parametrize("layout", list(Layout))
def test_to_cube_follows_the_cube_convention(layout):
    """A map whose texels hold their own direction becomes a cube whose texels hold theirs (cube.py),
    and texels outside the probe's disc or the cross's tiles never leak in."""
    h, w = SIZES[layout]
    cube = to_cube(_direction_image(layout, h, w), layout, 16)
    assert cube.shape == (6, 16, 16, 3) and cube.dtype == np.float32
    assert np.abs(cube).max() <= 1.0 + 1e-5
    err = np.degrees(_angle(cube.astype(np.float64), texel_directions(16)))
    assert np.median(err) < 0.5 and err.max() < 3.0, (np.median(err), err.max())


@pytest.mark.parametrize("layout", list(Layout))
def test_constant_map_gives_constant_cube(layout):
    h, w = SIZES[layout]
    _, valid = image_to_dir((np.arange(w) + 0.5)[None, :], (np.arange(h) + 0.5)[:, None], layout, h, w)
    img = np.where(valid[..., None], 2.5, 50.0) * np.ones(3, np.float32)  # 50 where the layout has no data
    cube = to_cube(img, layout, 8)
    np.testing.assert_allclose(cube, 2.5, rtol=1e-5)


def test_checkerboard_4k_does_not_alias_and_keeps_energy():
    h, w = 2048, 4096
    board = ((np.arange(h)[:, None] + np.arange(w)[None, :]) % 2).astype(np.float32)
    img = np.repeat(board[..., None], 3, axis=2)
    cube = to_cube(img, "latlong", 128)
    assert np.abs(cube - 0.5).max() < 0.02
    np.testing.assert_allclose(_cube_energy(cube), _latlong_energy(img), rtol=1e-3)


def test_stripes_do_not_alias():
    # Vertical stripes 3 texels wide: every cube texel spans many periods, so its mean is 0.5 up to
    # the part of one period at its ends; point sampling would give 0s and 1s.
    h, w = 1024, 2048
    stripes = ((np.arange(w) // 3) % 2).astype(np.float32)
    img = np.broadcast_to(stripes[None, :, None], (h, w, 3))
    cube = to_cube(img, "latlong", 32)
    assert np.abs(cube - 0.5).max() < 0.05


def _smooth_map(h, w, seed=0):
    rng = np.random.default_rng(seed)
    d, _ = image_to_dir((np.arange(w) + 0.5)[None, :], (np.arange(h) + 0.5)[:, None], "latlong", h, w)
    img = np.full((h, w, 3), 0.2)
    for _ in range(6):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        img += rng.random(3) * 5.0 * np.exp(8.0 * (d @ axis - 1.0))[..., None]
    return img.astype(np.float32)


def _splat_reference(img, n, sub=4):
    """Monte Carlo-free reference: every source texel split into sub x sub parts, each dropped whole into
    the cube texel holding its centre with its exact share of solid angle. Slow; small inputs only."""
    h, w, c = img.shape
    ys = (np.arange(h * sub) + 0.5) / sub
    xs = (np.arange(w * sub) + 0.5) / sub
    d, _ = image_to_dir(xs[None, :], ys[:, None], "latlong", h, w)
    face, row, col = dir_to_texel(d, n)
    weight = np.broadcast_to(latlong_row_solid_angles(h * sub, w * sub)[:, None], face.shape)
    value = img[(ys.astype(int))[:, None], (xs.astype(int))[None, :]]
    flat = (face * n + row) * n + col
    total = np.bincount(flat.ravel(), weight.ravel(), minlength=6 * n * n)
    out = np.stack([np.bincount(flat.ravel(), (weight * value[..., k]).ravel(), minlength=6 * n * n)
                    for k in range(c)], axis=-1)
    return (out / total[:, None]).reshape(6, n, n, c)


def test_to_cube_matches_splat_reference():
    img = _smooth_map(128, 256)
    for n in (8, 32):
        fast = to_cube(img, "latlong", n)
        ref = _splat_reference(img, n)
        rel = np.abs(fast - ref) / ref
        assert rel.max() < 0.03 and rel.mean() < 0.005, (n, rel.max(), rel.mean())


@needs_assets
def test_to_cube_matches_splat_reference_on_a_real_map():
    img = read_hdr_image(HDRI / "ennis.hdr")
    fast = to_cube(img, "latlong", 16)
    ref = _splat_reference(img, 16)
    lum = lambda c: c.mean(axis=-1) * cube_solid_angles(16)  # noqa: E731  (energy per texel)
    assert np.abs(lum(fast) - lum(ref)).sum() / lum(ref).sum() < 0.05


@pytest.mark.parametrize("n", [4, 16, 128])
def test_energy_conserved_with_a_sun(n):
    img = sky_environment(1024)
    np.testing.assert_allclose(_cube_energy(to_cube(img, "latlong", n)), _latlong_energy(img), rtol=0.01)


@needs_assets
@pytest.mark.parametrize("name,n", [("rooitou_park_1k.hdr", 128), ("adams_place_bridge_1k.hdr", 128),
                                    ("rooitou_park_1k.hdr", 16), ("pmndrs_assets_sky.exr", 16),
                                    ("pisa.hdr", 8), ("ennis.hdr", 4)])
def test_energy_conserved_on_real_maps(name, n):
    img = np.maximum(read_hdr_image(HDRI / name), 0.0)  # the sky .exr has negative texels
    np.testing.assert_allclose(_cube_energy(to_cube(img, "latlong", n)), _latlong_energy(img), rtol=0.01)


@pytest.mark.parametrize("layout", [Layout.ANGULAR, Layout.HCROSS, Layout.VCROSS])
def test_energy_conserved_for_other_layouts(layout):
    """Resample a smooth lat-long map into the layout (point samples of a smooth field), then to a cube:
    the cube keeps the field's integral."""
    src = _smooth_map(128, 256, seed=3)
    src_cube = to_cube(src, "latlong", 32)
    h, w = {Layout.ANGULAR: (256, 256), Layout.HCROSS: (192, 256), Layout.VCROSS: (256, 192)}[layout]
    d, valid = image_to_dir((np.arange(w) + 0.5)[None, :], (np.arange(h) + 0.5)[:, None], layout, h, w)
    img = np.where(valid[..., None], sample_bilinear(src_cube, np.where(valid[..., None], d, 1.0)), 0.0)
    cube = to_cube(img.astype(np.float32), layout, 32)
    np.testing.assert_allclose(_cube_energy(cube), _cube_energy(src_cube), rtol=0.01)


def test_1k_map_to_128_cube_costs_a_few_dozen_bilinear_lookups_per_texel():
    # Side by side with scipy's bilinear lookup of as many points per channel (a machine's speed and
    # load cancel): measured 19-23x on 2-core llvmpipe's machine, ~1.1 s; a per-texel Python loop
    # or a full-resolution copy per face would be hundreds.
    from scipy.ndimage import map_coordinates

    img = _smooth_map(512, 1024)
    to_cube(img[:8, :16], "latlong", 4)  # imports and caches
    points = np.random.default_rng(0).random((2, 6 * 128 * 128)) * [[511], [1023]]

    def timed(job):
        t0 = time.perf_counter()
        job()
        return time.perf_counter() - t0

    # Each the least of three turns, taken in alternation: a turn that a busy neighbour (the suite's
    # other processes) slowed does not count, for either side.
    ours, scipys = [], []
    for _ in range(3):
        ours.append(timed(lambda: to_cube(img, "latlong", 128)))
        scipys.append(timed(lambda: [map_coordinates(img[..., c], points, order=1) for c in range(3)]))
    ratio = min(ours) / min(scipys)
    assert ratio < 60.0, f"1024x512 -> 6 x 128^2 took {ratio:.0f}x the bilinear lookups"


def test_memory_grows_by_a_fraction_of_the_input():
    """Level 0 is never copied unless sampled and the pyramid is built in bands, so memory beyond the input
    is a quarter of it (level 1) plus a fixed ~70 MiB of sample buffers (a 16k map: 0.5 GiB extra,
    tests/test_extremes.py). Checked here as the growth of tracemalloc's peak (numpy reports to it)
    from 1k to 4k."""
    peaks = []
    for h in (512, 2048):
        img = np.random.default_rng(0).random((h, 2 * h, 3), dtype=np.float32)
        tracemalloc.start()
        try:
            to_cube(img, "latlong", 128)
            peaks.append((img.nbytes, tracemalloc.get_traced_memory()[1]))
        finally:
            tracemalloc.stop()
    (small_bytes, small_peak), (big_bytes, big_peak) = peaks
    assert big_peak - small_peak < 0.5 * (big_bytes - small_bytes)
    assert big_peak < big_bytes + 128 * 2**20


@pytest.mark.parametrize("layout,shape", [(Layout.LATLONG, (1, 2, 3)), (Layout.ANGULAR, (1, 1, 3)),
                                          (Layout.HCROSS, (3, 4, 3)), (Layout.VCROSS, (4, 3, 3)),
                                          (Layout.LATLONG, (3, 7, 3))])
def test_tiny_inputs(layout, shape):
    img = np.full(shape, 1.5, np.float32)
    cube = to_cube(img, layout, 4)
    np.testing.assert_allclose(cube, 1.5, rtol=1e-5)
    two = np.array([[[1.0, 1, 1], [3.0, 3, 3]]], np.float32)
    assert np.isfinite(to_cube(two, "latlong", 8)).all()


def test_cube_to_latlong_round_trip():
    img = _smooth_map(64, 128)
    back = cube_to_latlong(to_cube(img, "latlong", 64), 64, 128)
    assert back.shape == (64, 128, 3) and back.dtype == np.float32
    rel = np.abs(back - img) / img
    assert np.median(rel) < 0.01 and rel.max() < 0.1


# ------------------------------------------------------------------------------------------------------------
# Procedural environments


def test_studio_environment():
    img = studio_environment(256)
    assert img.shape == (128, 256, 3) and img.dtype == np.float32
    assert np.isfinite(img).all() and img.min() > 0
    np.testing.assert_array_equal(img, studio_environment(256))  # deterministic
    d, _ = image_to_dir((np.arange(256) + 0.5)[None, :], (np.arange(128) + 0.5)[:, None], "latlong", 128, 256)
    lum = img.mean(axis=-1)
    key = d[np.unravel_index(np.argmax(lum), lum.shape)]
    assert key[0] < 0 and key[1] > 0 and key[2] > 0  # upper front-left (front = +Z, camera left = -X)
    assert 40 < lum.max() <= 50
    assert 0.05 < np.median(lum[d[..., 1] > 0]) < 0.5  # dim walls
    assert np.median(lum[d[..., 1] < -0.2]) < np.median(lum[(d[..., 1] > 0) & (d[..., 1] < 0.5)])  # darker floor
    overhead = img[d[..., 1] > 0.95].mean(axis=0)
    assert overhead[2] > overhead[0]  # slightly blue
    behind = (d[..., 2] < -0.5) & (lum > 20)
    assert behind.any()  # the rim light
    front_right = (d[..., 0] > 0.3) & (d[..., 2] > 0.3) & (lum > 5) & (lum < 15)
    assert front_right.any()  # the fill light


def test_sky_environment_sun_holds_most_energy():
    img = sky_environment(512)
    assert img.shape == (256, 512, 3) and np.isfinite(img).all() and img.min() > 0
    np.testing.assert_array_equal(img, sky_environment(512))
    weights = latlong_row_solid_angles(256, 512)[:, None]
    lum = img.mean(axis=-1)
    total = (lum * weights).sum()
    sun = (np.where(lum > 5, lum, 0.0) * weights).sum()
    assert sun / total > 0.5
    # Its energy is that of a 0.5 degree disc of radiance ~5e4, whatever the resolution.
    disc_sr = 2 * np.pi * (1 - np.cos(np.radians(0.25)))
    for width in (64, 512):
        sky = sky_environment(width)
        e = _latlong_energy(np.where(sky.mean(-1, keepdims=True) > 5, sky, 0.0))
        np.testing.assert_allclose(e / disc_sr, 5e4 * np.array([1.0, 0.93, 0.82]), rtol=0.05)
