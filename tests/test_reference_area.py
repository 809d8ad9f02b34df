"""The reference's pixel area (renderer/reference/strata.py): coverage against a straight edge's analytic
area, the edge mask, the noise over the strata, the split of the samples; and the metrics that read
them (the silhouette error, the share of 5 x 5 windows off by 1.5x) on synthetic images."""

import numpy as np
import pytest
from conftest import CAM, plane, sphere, sun_sky_cube

from renderer.camera import Camera, bounds_sphere
from renderer.errors import InvalidInputError
from renderer.mesh import Mesh, bounds
from renderer.reference import artefact_share, silhouette_error, window_share
from renderer.reference.montecarlo import render_reference
from renderer.reference.strata import EDGE_FOOTPRINTS, sample_counts
from renderer.shading.material import Material

GREY = Material((0.5, 0.5, 0.5), 0.0, 0.5)   # in a uniform map of 2: radiance 1 wherever the plane is seen
L_ENV = 2.0
UNIFORM = np.full((6, 4, 4, 3), L_ENV, np.float32)
FRONT = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0)
SIZE = 32


def quad(corners, name="quad") -> Mesh:
    return Mesh.from_arrays(np.asarray(corners, np.float64), np.array([[0, 1, 2], [0, 2, 3]]), name=name)


# A quad in z = 0 filling the left of the view, its right edge the line x = 0.1 + 0.23 y (slanted, so it
# crosses pixels at every fraction).
EDGE_QUAD = quad([[-4, -4, 0], [0.1 - 0.92, -4, 0], [0.1 + 0.92, 4, 0], [-4, 4, 0]])


def to_pixels(meshes, points) -> np.ndarray:
    """World points (N, 3) -> (x, y) in pixel units (x right, y down from the top edge) of FRONT at SIZE^2."""
    vp = FRONT.view_proj(1.0, *bounds_sphere(*bounds(meshes)))
    p = np.c_[np.asarray(points, np.float64), np.ones(len(points))] @ vp.T
    ndc = p[:, :2] / p[:, 3:]
    return np.stack([(ndc[:, 0] + 1.0) / 2.0 * SIZE, (1.0 - ndc[:, 1]) / 2.0 * SIZE], axis=1)


def inside_area(line_a: np.ndarray, line_b: np.ndarray, inside: np.ndarray, x0: float, y0: float, side: float) -> float:
    """The area of the square [x0, x0 + side) x [y0, y0 + side) on `inside`'s side of the line through
    line_a and line_b (Sutherland-Hodgman against one half-plane, then the shoelace formula)."""
    normal = np.array([line_b[1] - line_a[1], line_a[0] - line_b[0]])
    if normal @ (inside - line_a) < 0:
        normal = -normal
    square = [np.array(p) for p in ((x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side))]
    d = [normal @ (p - line_a) for p in square]
    poly = []
    for i in range(4):
        p, q, dp, dq = square[i], square[(i + 1) % 4], d[i], d[(i + 1) % 4]
        if dp >= 0:
            poly.append(p)
        if (dp >= 0) != (dq >= 0):
            poly.append(p + (q - p) * dp / (dp - dq))
    if len(poly) < 3:
        return 0.0
    x, y = np.array(poly).T
    return 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


@pytest.fixture(scope="module")
def edge_truth():
    """Per pixel: the quad's analytic coverage, and the share of its 4 x 4 strata the edge crosses."""
    a, b, inside = to_pixels([EDGE_QUAD], [[0.1 - 0.92, -4, 0], [0.1 + 0.92, 4, 0], [-1.0, 0.0, 0.0]])
    area = np.array([[inside_area(a, b, inside, c, r, 1.0) for c in range(SIZE)] for r in range(SIZE)])
    crossed = np.zeros((SIZE, SIZE))
    for r in range(SIZE):
        for c in range(SIZE):
            for i in range(4):
                for j in range(4):
                    f = inside_area(a, b, inside, c + j / 4, r + i / 4, 0.25) * 16
                    crossed[r, c] += 0.0 < f < 1.0
    return area, crossed / 16, (a, b, inside)


@pytest.fixture(scope="module")
def edge_frames():
    return {k: render_reference([EDGE_QUAD], [GREY], UNIFORM, FRONT, SIZE, SIZE, 16, seed=5, pixel_samples=k)
            for k in (1, 4)}


def test_strata_give_a_straight_edge_its_analytic_coverage(edge_truth, edge_frames):
    area, crossed, _ = edge_truth
    alpha = edge_frames[4].image[..., 3].astype(np.float64)
    partial = (area > 0) & (area < 1)
    assert partial.sum() >= SIZE        # the edge crosses every row
    # Each pixel within the share of strata the edge crosses (the others are wholly in or out), and
    # exactly 0 or 1 where it crosses none.
    assert np.all(np.abs(alpha - area) <= crossed + 1e-9)
    assert np.array_equal(alpha[crossed == 0], np.round(area[crossed == 0]))
    # The jitter's error: ~0.4 k^-3/2 = 0.05 rms at k = 4, and none on average (unbiased).
    err = (alpha - area)[partial]
    assert np.sqrt(np.mean(err ** 2)) < 0.1
    assert abs(err.mean()) < 3.0 * err.std() / np.sqrt(err.size) + 1e-3
    # Coverage quantized to the strata: a share of 16.
    assert np.array_equal(alpha * 16, np.round(alpha * 16))


def test_one_pixel_sample_is_the_pixel_centre_as_before(edge_truth, edge_frames):
    _, _, (a, b, inside) = edge_truth
    one = edge_frames[1]
    alpha = one.image[..., 3]
    assert set(np.unique(alpha)) == {0.0, 1.0} and not one.edge.any() and one.pixel_samples == 1
    # The centre's side of the line, wherever it is not within a hair of it.
    normal = np.array([b[1] - a[1], a[0] - b[0]])
    normal *= np.sign(normal @ (inside - a)) / np.linalg.norm(normal)
    cy, cx = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    dist = (cx - a[0]) * normal[0] + (cy - a[1]) * normal[1]
    clear = np.abs(dist) > 1e-6
    assert np.array_equal(alpha[clear], (dist[clear] > 0).astype(np.float32))
    again = render_reference([EDGE_QUAD], [GREY], UNIFORM, FRONT, SIZE, SIZE, 16, seed=5)
    np.testing.assert_array_equal(again.image, one.image)
    np.testing.assert_array_equal(again.noise_std, one.noise_std)


def test_foreground_is_the_image_over_black_and_edges_are_the_mixed_pixels(edge_frames):
    for frame in edge_frames.values():
        img, fg = frame.image.astype(np.float64), frame.foreground.astype(np.float64)
        alpha = img[..., 3]
        np.testing.assert_array_equal(fg[..., 3], alpha)
        # What the strata that miss see: the map along their rays, (1 - alpha) L over the pixel.
        np.testing.assert_allclose(img[..., :3] - fg[..., :3], np.repeat((1.0 - alpha)[..., None] * L_ENV, 3, axis=2),
                                   atol=1e-5)
        # The plane's radiance is 1 (albedo 0.5 x L 2): premultiplied by the coverage, within the noise.
        lit = alpha > 0
        err = fg[..., :3][lit] - alpha[lit, None]
        assert np.mean(np.abs(err) < 3.0 * frame.noise_std[lit] + 1e-4) > 0.95
        assert abs(err.sum() / alpha[lit].sum() / 3) < 0.01
    # One mesh, one plane: the edges are exactly the pixels whose strata both hit and miss.
    four = edge_frames[4]
    alpha = four.image[..., 3]
    np.testing.assert_array_equal(four.edge, (alpha > 0) & (alpha < 1))


def layers(separation: float, two_meshes: bool) -> list[Mesh]:
    """A wall filling the view and a strip in front of it (x in [-0.31, 0.27]) `separation` nearer."""
    z = separation
    strip = [[-0.31, -4, z], [0.27, -4, z], [0.27, 4, z], [-0.31, 4, z]]
    wall = [[-4, -4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]]
    if two_meshes:
        return [quad(wall, "torso"), quad(strip, "sleeve")]
    m = Mesh.from_arrays(np.array(wall + strip, np.float64), np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]),
                         name="one mesh")
    return [m]


@pytest.mark.parametrize("two_meshes", [False, True])
def test_a_layer_over_another_makes_edges_where_its_border_crosses(two_meshes):
    # Footprint at the wall: 3 x 2 tan(20 deg) / 32 = 0.068; a strip 0.4 nearer is ~6 footprints off
    # the wall's plane, one 0.05 nearer under one (the threshold is EDGE_FOOTPRINTS).
    assert EDGE_FOOTPRINTS <= 4.0
    meshes = layers(0.4, two_meshes)
    frame = render_reference(meshes, [GREY] * len(meshes), UNIFORM, FRONT, SIZE, SIZE, 8, seed=2, pixel_samples=4)
    assert np.all(frame.image[..., 3] == 1.0)
    xs = to_pixels(meshes, [[-0.31, 0, 0.4], [0.27, 0, 0.4]])[:, 0]
    cols = np.flatnonzero(frame.edge.any(axis=0))
    assert set(cols) == {int(np.floor(x)) for x in xs}      # the two columns the strip's borders cross
    assert frame.edge[:, cols].all()                         # every row of them
    if not two_meshes:   # the same mesh closer than a few footprints: one surface
        near = layers(0.05, False)
        assert not render_reference(near, [GREY], UNIFORM, FRONT, SIZE, SIZE, 8, seed=2, pixel_samples=4).edge.any()


def test_a_crease_and_a_sphere_seen_to_its_rim_make_no_edge_of_their_own():
    # A ridge towards the camera (z = -|x|, a right angle between its faces): one surface, folded.
    ridge = Mesh.from_arrays(np.array([[-4, -4, -4], [0, -4, 0], [0, 4, 0], [-4, 4, -4], [4, -4, -4], [4, 4, -4]],
                                      np.float64), np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]))
    frame = render_reference([ridge], [GREY], UNIFORM, FRONT, SIZE, SIZE, 8, seed=3, pixel_samples=4)
    assert np.all(frame.image[..., 3] == 1.0) and not frame.edge.any()
    # A sphere's grazing rim: edges only where the strata both hit and miss.
    ball = render_reference([sphere(0.5)], [GREY], UNIFORM, CAM, SIZE, SIZE, 8, seed=3, pixel_samples=4)
    alpha = ball.image[..., 3]
    np.testing.assert_array_equal(ball.edge, (alpha > 0) & (alpha < 1))


def sun_scene(spp: int, seed: int, pixel_samples: int, occlusion: bool = True):
    cube = sun_sky_cube(16, (0.5, 1.0, 0.6), sun_radiance=300.0, sun_radius_deg=6.0)
    return render_reference([sphere(0.5, subdivisions=3), plane()], [Material((0.8, 0.6, 0.4), 0.5, 0.7), GREY],
                            cube, Camera((0.0, 1.2, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0), 24, 24, spp, seed,
                            occlusion=occlusion, pixel_samples=pixel_samples)


def test_the_noise_of_the_strata_describes_the_spread_between_seeds():
    a, b = sun_scene(64, 1, 2), sun_scene(64, 2, 2)
    inner = (a.image[..., 3] == 1) & (b.image[..., 3] == 1) & ~a.edge & ~b.edge
    diff = (a.image - b.image)[inner][:, :3]
    predicted = np.sqrt(a.noise_std[inner] ** 2 + b.noise_std[inner] ** 2)
    assert np.sqrt(np.mean(diff ** 2)) == pytest.approx(np.sqrt(np.mean(predicted ** 2)), rel=0.2)
    # The strata share one stratification of the samples (strata.py): the noise at the same samples per
    # pixel is about the centre's, not the ~3x of strata stratified each on its own.
    centre = sun_scene(64, 1, 1)
    assert a.noise_floor_rel() < 1.3 * centre.noise_floor_rel()


def test_a_white_furnace_with_strata_reflects_the_environment_and_its_noise_is_honest():
    frame = render_reference([sphere()], [Material((1.0, 1.0, 1.0), 0.0, 0.5)], np.full((6, 8, 8, 3), 2.5, np.float32),
                             CAM, 24, 24, 32, seed=4, pixel_samples=2)
    inner = (frame.image[..., 3] == 1) & ~frame.edge
    z = (frame.image[inner][:, :3] - 2.5) / frame.noise_std[inner]
    assert inner.sum() > 100 and np.mean(np.abs(z) < 3.0) > 0.93 and abs(float(z.mean())) < 0.25


def test_samples_are_split_over_the_strata_and_cost_primary_rays_only():
    assert sample_counts(256, 4, 8) == (16, 8)     # spp per pixel, split evenly
    assert sample_counts(64, 4, 8) == (8, 8)       # below k^2 x batches: every batch holds every stratum
    assert sample_counts(3, 2, 8) == (3, 3) and sample_counts(1, 4, 8) == (1, 1)
    assert sample_counts(100, 1, 8) == (100, 8)     # one stratum: as before
    one, four = sun_scene(64, 1, 1), sun_scene(64, 1, 2)
    assert (one.spp, four.spp) == (64, 64)
    # The same shadow rays (within the images' differences), plus k^2 primary rays a pixel.
    assert (four.rays_cast - 4 * 24 * 24) == pytest.approx(one.rays_cast - 24 * 24, rel=0.1)
    assert sun_scene(16, 1, 2, occlusion=False).rays_cast == 4 * 24 * 24
    assert sun_scene(16, 1, 4).spp == 16 * 8


def test_strata_are_deterministic_and_jittered_by_the_seed():
    a, b, c = sun_scene(8, 7, 2), sun_scene(8, 7, 2), sun_scene(8, 8, 2)
    for field in ("image", "noise_std", "foreground", "edge"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.rays_cast == b.rays_cast
    assert not np.array_equal(a.image[..., 3], c.image[..., 3])   # other positions at the edges
    assert a.image.shape == a.foreground.shape == (24, 24, 4) and a.edge.shape == (24, 24)


@pytest.mark.parametrize("k", [0, 17, 2.0, True])
def test_invalid_pixel_samples_are_rejected(k):
    with pytest.raises(InvalidInputError, match="pixel_samples"):
        render_reference([sphere(0.5, subdivisions=1)], [GREY], UNIFORM, CAM, 8, 8, 1, pixel_samples=k)


# --- the silhouette error -----------------------------------------------------------------------


def disc(radius: float, centre=(16.3, 15.6), size: int = 32, sub: int = 16, colour=(0.6, 0.5, 0.3)) -> np.ndarray:
    """A disc's premultiplied image over black (H, W, 4): coverage from sub x sub samples a pixel."""
    g = (np.arange(size * sub) + 0.5) / sub
    inside = (g[None, :] - centre[0]) ** 2 + (g[:, None] - centre[1]) ** 2 < radius ** 2
    alpha = inside.reshape(size, sub, size, sub).mean(axis=(1, 3))
    return np.concatenate([alpha[..., None] * np.asarray(colour), alpha[..., None]], axis=2).astype(np.float32)


def test_the_silhouette_error_sees_a_shifted_edge_and_an_aliased_one():
    ref = disc(9.0)
    edge = (ref[..., 3] > 0) & (ref[..., 3] < 1)
    exact = silhouette_error(ref, ref, edge)
    assert (exact.rel_rmse, exact.coverage_rmse, exact.pixels) == (0.0, 0.0, int(edge.sum()))
    # A renderer shading pixel centres: coverage 0 or 1.
    aliased = disc(9.0, sub=1)
    centre = silhouette_error(aliased, ref, edge)
    # The same disc a pixel to the right: wrong on the whole rim.
    shifted = silhouette_error(np.roll(ref, 1, axis=1), ref, edge)
    assert 0.15 < centre.coverage_rmse < 0.45 and centre.rel_rmse > 0.2
    assert shifted.coverage_rmse > 1.3 * centre.coverage_rmse and shifted.rel_rmse > centre.rel_rmse
    # Only the edge pixels count: the inside may be anything.
    worse_inside = ref.copy()
    worse_inside[16, 16, :3] *= 3.0
    assert silhouette_error(worse_inside, ref, edge).rel_rmse == 0.0
    with pytest.raises(InvalidInputError):
        silhouette_error(ref[..., :3], ref, edge)
    assert np.isnan(silhouette_error(ref, ref, np.zeros_like(edge)).rel_rmse)


# --- the window share ---------------------------------------------------------------------------


def smooth_object(seed: int, noise: float = 0.01) -> np.ndarray:
    """A 40 x 40 object over rows and columns 4..35 with a smooth shading and a little noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:40, 0:40] / 40.0
    img = np.zeros((40, 40, 4), np.float32)
    img[..., :3] = ((0.5 + 0.4 * x + 0.3 * y) * (1.0 + noise * rng.standard_normal((40, 40))))[..., None]
    img[4:36, 4:36, 3] = 1.0
    return img


def test_the_window_share_counts_a_band_too_bright_and_not_noise():
    a, b = smooth_object(1), smooth_object(2)
    truth = 0.5 * (a + b)
    inside = 32 - 5 + 1   # window positions a side within the 32 x 32 object
    assert window_share(truth, a, b).share == 0.0
    assert window_share(truth, a, b).judged_pixels == inside ** 2
    # A band six columns wide 1.6x too bright: the windows wholly inside it (two columns of them) are
    # off; the pixels are within the artefact share's 2x.
    band = truth.copy()
    band[:, 10:16, :3] *= 1.6
    w = window_share(band, a, b)
    assert w.too_bright == 2 * inside and w.too_dark == 0 and w.share == pytest.approx(2 / inside)
    assert artefact_share(band, a, b).share == 0.0
    dark = truth.copy()
    dark[:, 10:16, :3] /= 1.6
    assert window_share(dark, a, b).too_dark == 2 * inside
    # Lone bright pixels (every 7th, 3x): the pixels are off, hardly a window's mean.
    speckle = truth.copy()
    speckle[::7, ::7, :3] *= 3.0
    assert artefact_share(speckle, a, b).share > 0.0 and window_share(speckle, a, b).share == 0.0
    # Outside the object (or on windows reaching past it) nothing counts.
    outside = truth.copy()
    outside[:, 36:, :3] *= 5.0
    outside[:, 33:36, :3] *= 1.6
    assert window_share(outside, a, b).share == 0.0


def test_the_window_share_skips_windows_where_the_references_disagree():
    a, b = smooth_object(1), smooth_object(2)
    b[:, 10:16, :3] *= 1.6   # one reference's blotch: its windows are not judged
    band = 0.5 * (a + b)
    band[:, 10:16, :3] *= 1.6
    w = window_share(band, a, b)
    assert w.too_bright == 0 and w.judged_pixels < (32 - 5 + 1) ** 2
    # Partly covered pixels of a reference with strata are not inside the object.
    soft = a.copy()
    soft[4, 4:36, 3] = 0.75
    assert window_share(a, soft).judged_pixels == (32 - 5) * (32 - 5 + 1)
