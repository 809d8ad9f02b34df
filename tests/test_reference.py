"""The Monte Carlo reference: analytic cases (furnaces, a plane under a sun), its noise estimate, its
determinism, the metrics, and agreement with the GPU renderer where the PEM approximation is exact
enough (a smooth map, no occlusion)."""

import numpy as np
import pytest
from conftest import CAM, covered, plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.envmap.cube import cube_solid_angles, texel_directions
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.reference import (
    EnvironmentSampler,
    ReferenceFrame,
    artefact_share,
    mean_flip,
    noise_floor,
    relative_rmse,
    relative_squared_errors,
    render_reference,
)
from renderer.renderer import FrameSettings, ShadingMode
from renderer.shading.material import Material

WHITE_DIFFUSE = Material((1.0, 1.0, 1.0), 0.0, 0.5)


def mean_and_error(frame: ReferenceFrame, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean RGB over the mask and its standard error (pixels are independent)."""
    px, se = frame.image[mask][:, :3].astype(np.float64), frame.noise_std[mask].astype(np.float64)
    return px.mean(axis=0), np.sqrt((se ** 2).sum(axis=0)) / len(px)


# A map linear in the direction per channel, L(w) = a + B w (0.2 .. 1.8): its cosine convolution is
# known in closed form, integral (a + B w) max(0, n.w) / pi dw = a + (2/3) B n.
GRADIENT_A = np.array([1.0, 1.0, 1.0])
GRADIENT_B = np.array([[0.2, 0.6, 0.0], [0.0, 0.7, -0.1], [0.0, 0.8, 0.2]])


def gradient_cube(face_size: int) -> np.ndarray:
    return (GRADIENT_A + texel_directions(face_size) @ GRADIENT_B.T).astype(np.float32)


def soft_sky_cube(face_size: int) -> np.ndarray:
    """A smooth sky: linear from the horizon (0.8, 0.85, 0.9) up to a blue zenith and down to a grey ground."""
    y = texel_directions(face_size)[..., 1:2]
    horizon, zenith, ground = np.array([0.8, 0.85, 0.9]), np.array([0.5, 0.7, 1.1]), np.array([0.5, 0.45, 0.4])
    return np.where(y > 0, horizon + (zenith - horizon) * y, horizon - (ground - horizon) * y).astype(np.float32)


# --- environment sampling ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def sun_sampler():
    return EnvironmentSampler(sun_sky_cube(16, (0.4, 1.0, 0.3), sun_radiance=500.0, sun_radius_deg=8.0))


def test_environment_pdf_integrates_to_one(sun_sampler):
    # Midpoint rule on a 4x finer cube: the density is smooth within each coarse texel.
    fine = 4 * sun_sampler.face_size
    integral = (sun_sampler.pdf(texel_directions(fine)) * cube_solid_angles(fine)).sum()
    assert integral == pytest.approx(1.0, abs=1e-4)


def test_environment_samples_carry_their_own_density(sun_sampler):
    dirs, pdf = sun_sampler.sample(20000, np.random.default_rng(3))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(pdf, sun_sampler.pdf(dirs), rtol=1e-9)
    assert np.all(sun_sampler.pdf(-dirs) > 0)  # the uniform floor: black or dim texels stay reachable


def test_environment_sampling_is_unbiased(sun_sampler):
    # E[L(w) / p(w)] = integral of L over the sphere, per channel.
    dirs, pdf = sun_sampler.sample(200000, np.random.default_rng(4))
    ratio = sun_sampler.radiance(dirs) / pdf[:, None]
    mean, se = ratio.mean(axis=0), ratio.std(axis=0, ddof=1) / np.sqrt(len(ratio))
    assert np.all(np.abs(mean - sun_sampler.integral()) < 3.0 * se)


def test_black_map_falls_back_to_uniform_by_solid_angle():
    s = EnvironmentSampler(np.zeros((6, 4, 4, 3)))
    np.testing.assert_allclose(s.texel_prob, cube_solid_angles(4) / cube_solid_angles(4).sum())


# --- analytic cases ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def white_furnace():
    return render_reference([sphere()], [WHITE_DIFFUSE], np.full((6, 8, 8, 3), 2.5, np.float32), CAM, 32, 32, 64,
                            seed=1)


def test_furnace_white_diffuse_sphere_reflects_the_environment(white_furnace):
    # A closed convex white Lambertian object in a uniform environment L reflects exactly L: every
    # direction above the tangent plane sees the map, every one below is blocked by the object and has
    # no cosine weight (up to the facet-vs-shading-normal mismatch, ~delta^2 / 4 ~ 1e-4 here).
    L = 2.5
    mask = covered(white_furnace)
    mean, se = mean_and_error(white_furnace, mask)
    assert mask.sum() > 250
    assert np.all(np.abs(mean - L) < 3.0 * se + 1e-4 * L)
    assert np.all(np.abs(mean - L) < 0.02 * L)
    # Per pixel: the noise estimate describes the spread (8 batches: Student t with 7 dof, so ~2 %
    # of |z| exceed 3 even for a perfect estimate).
    z = (white_furnace.image[mask][:, :3] - L) / white_furnace.noise_std[mask]
    assert np.mean(np.abs(z) < 3.0) > 0.93
    assert abs(float(z.mean())) < 0.2


def glossy_visible_fraction(cos_view: np.ndarray, s: float) -> np.ndarray:
    """Share of the normalized Phong lobe around r = reflect(-v, n) above the tangent plane of n, where
    the angle a between r and n is that between v and n. With w at polar angle t and azimuth phi around
    r, n.w > 0 iff cos(phi) > -cot(a) cot(t): a share acos(clip(-cot a cot t)) / pi of each ring, so
        F(a) = integral_0^(pi/2) (s + 1) cos^s(t) sin(t) acos(clip(-cot a cot t, -1, 1)) / pi dt,
    with F(0) = 1 and F(pi/2) = 1/2."""
    t = (np.arange(4000) + 0.5) * (np.pi / 2 / 4000)
    a = np.arccos(np.clip(cos_view, 1e-9, 1.0 - 1e-12))[:, None]
    ring = np.arccos(np.clip(-np.cos(a) / np.sin(a) * np.cos(t) / np.sin(t), -1.0, 1.0)) / np.pi
    return ((s + 1.0) * np.cos(t) ** s * np.sin(t) * ring).sum(axis=1) * (np.pi / 2 / 4000)


def analytic_sphere(camera: Camera, w: int, h: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(unit normal, unit view direction) per pixel of the exact sphere at the origin, NaN normals where
    the ray misses; the rays come from the camera's own basis, an independent check of the reference's
    primary rays too."""
    eye = np.asarray(camera.eye, np.float64)
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan_half = np.tan(np.radians(camera.fov_y_deg) / 2)
    y, x = np.meshgrid(1 - (np.arange(h) + 0.5) / h * 2, (np.arange(w) + 0.5) / w * 2 - 1, indexing="ij")
    d = fwd + (x * tan_half * w / h)[..., None] * right + (y * tan_half)[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ eye
    disc = b * b - (eye @ eye - radius * radius)
    t = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    return (eye + t[..., None] * d) / radius, d


def test_furnace_glossy_sphere_loses_the_lobe_below_the_surface():
    # Albedo 0, specular 1, g = 0.8 (s = 5) in a uniform map: the normalized lobe around r integrates
    # to 1, but on a closed object the part of it below the tangent plane is blocked by the object
    # itself (the renderer without occlusion returns L exactly). The expected pixel is L * F(view
    # angle) (see glossy_visible_fraction): 1 facing the camera, 1/2 at grazing view.
    L, g = 1.5, 0.8
    frame = render_reference([sphere(0.5, subdivisions=5)], [Material((0.0, 0.0, 0.0), 1.0, g)], np.full((6, 8, 8, 3), L),
                             CAM, 32, 32, 32, seed=2)
    normal, view = analytic_sphere(CAM, 32, 32, 0.5)
    cos_view = -np.einsum("hwc,hwc->hw", normal, view)
    mask = covered(frame) & np.isfinite(cos_view)
    expected = L * glossy_visible_fraction(cos_view[mask], 1.0 / (1.0 - g))
    mean, se = mean_and_error(frame, mask)
    # This image's expected loss (~ 8 %) is far beyond the noise: the occlusion is really modelled.
    assert expected.mean() < 0.95 * L
    # Facets vs the exact sphere at 1.5k pixels: < 0.5 % on the mean.
    assert np.all(np.abs(mean - expected.mean()) < 3.0 * se + 0.005 * L)
    # Per pixel, against the analytic sphere: 90 % within 3 sigma + 2 %; silhouette pixels differ most.
    err = np.abs(frame.image[mask][:, :3] - expected[:, None])
    assert np.mean(err < 3.0 * frame.noise_std[mask] + 0.02 * L) > 0.9


def test_light_behind_an_open_sheet_does_not_reach_the_side_the_camera_sees():
    # One plane (an open sheet, as cloth is) seen from above at a grazing angle, with a wide glossy lobe
    # (g = 0: s = 1) around the reflection vector, which reaches below the plane. Light only from
    # below: it would have to pass through the sheet, so the image is black. The same light above the
    # plane lights it (the lobe is really there).
    d = texel_directions(16)
    below = np.where(d[..., 1:2] < -0.05, 1.0, 0.0).repeat(3, -1)
    above = np.where(d[..., 1:2] > 0.05, 1.0, 0.0).repeat(3, -1)
    glossy = [Material((0.0, 0.0, 0.0), 1.0, 0.0)]
    dark = render_reference([plane()], glossy, below, CAM, 16, 16, 16, seed=1)
    lit = render_reference([plane()], glossy, above, CAM, 16, 16, 16, seed=1)
    mask = covered(dark)
    assert mask.sum() > 50
    assert np.all(dark.image[mask][:, :3] == 0.0)
    assert lit.image[mask][:, :3].min() > 0.1


def test_mirror_sphere_reflects_the_environment_without_noise():
    L = 0.7
    frame = render_reference([sphere()], [Material((0.0, 0.0, 0.0), 1.0, 1.0)], np.full((6, 4, 4, 3), L), CAM,
                             16, 16, 4)
    mask = covered(frame)
    px = frame.image[mask][:, :3]
    # Visible (r above the facet) everywhere except possibly at grazing silhouette pixels.
    assert np.mean(np.isclose(px, L, rtol=1e-6)) > 0.9
    assert np.all(frame.noise_std == 0)


def test_plane_under_a_sun_matches_the_analytic_irradiance():
    # An unoccluded white Lambertian plane (normal +Y) reflects E / pi with E = sum over texels of
    # L_t * integral_t max(0, w.y) dw, the cosine integrated on a 8x finer grid of each texel.
    f = 16
    cube = sun_sky_cube(f, (0.4, 1.0, 0.3), sun_radiance=200.0, sun_radius_deg=10.0)
    k = 8
    d = texel_directions(f * k)
    cos_omega = np.maximum(d[..., 1], 0.0) * cube_solid_angles(f * k)
    coarse = np.repeat(np.repeat(cube.astype(np.float64), k, axis=1), k, axis=2)
    expected = (coarse * cos_omega[..., None]).sum(axis=(0, 1, 2)) / np.pi

    cam = Camera((0.0, 2.0, 2.0), (0.0, 0.0, 0.0), fov_y_deg=40.0)
    frame = render_reference([plane()], [WHITE_DIFFUSE], cube, cam, 24, 24, 64, seed=3)
    mask = covered(frame)
    assert mask.mean() > 0.9
    mean, se = mean_and_error(frame, mask)
    assert np.all(np.abs(mean - expected) < 3.0 * se)
    np.testing.assert_allclose(mean, expected, rtol=0.01)


def test_diffuse_sphere_under_a_linear_map_matches_the_closed_form():
    # Per pixel, against a + (2/3) B n on the exact sphere's normal: the reference is unbiased (mean)
    # and its noise estimate is its actual error (rel. RMSE ~ its relative noise).
    albedo = np.array([0.8, 0.7, 0.6])
    frame = render_reference([sphere()], [Material(albedo, 0.0, 0.5)], gradient_cube(32), CAM, 32, 32, 128, seed=6)
    normal, _ = analytic_sphere(CAM, 32, 32, 0.5)
    expected = albedo * (GRADIENT_A + normal @ GRADIENT_B.T * (2.0 / 3.0))
    mask = covered(frame) & np.isfinite(normal[..., 0])
    assert mask.sum() > 280
    mean, se = mean_and_error(frame, mask)
    assert np.all(np.abs(mean - expected[mask].mean(axis=0)) < 3.0 * se + 0.002 * mean)
    exact = np.dstack([expected, np.ones((32, 32))])
    assert relative_rmse(frame.image, exact, mask) < 1.3 * frame.noise_floor_rel() + 0.005


def sun_only_cube(face_size: int, sun_dir, radiance: float = 300.0, radius_deg: float = 10.0) -> np.ndarray:
    return sun_sky_cube(face_size, sun_dir, sun_radiance=radiance, sun_radius_deg=radius_deg, sky=(0, 0, 0),
                        ground=(0, 0, 0))


def cosine_integral(cube: np.ndarray, normals: np.ndarray, k: int = 4) -> np.ndarray:
    """integral L(w) max(0, n.w) / pi dw of a piecewise-constant cube for normals (..., 3), on a k x k
    finer grid of every texel (only the texels that are not black)."""
    f = cube.shape[1]
    coarse = np.repeat(np.repeat(cube.astype(np.float64), k, axis=1), k, axis=2)
    lit = coarse.max(axis=-1) > 0
    d, omega = texel_directions(f * k)[lit], cube_solid_angles(f * k)[lit]
    cos = np.maximum(np.nan_to_num(normals) @ d.T, 0.0)
    return cos @ (coarse[lit] * omega[:, None]) / np.pi


@pytest.mark.parametrize("sun", [(1.0, 0.3, 0.4), (-1.0, 0.6, -0.3)])
def test_diffuse_sphere_under_a_sun_matches_the_cosine_integral_per_pixel(sun):
    # Pins the orientation of everything (cube convention, camera, pixel rows, normals): the lit side,
    # the terminator and the dark side all land where the exact sphere says.
    cube = sun_only_cube(16, sun)
    frame = render_reference([sphere()], [WHITE_DIFFUSE], cube, CAM, 32, 32, 32, seed=9)
    normal, _ = analytic_sphere(CAM, 32, 32, 0.5)
    expected = cosine_integral(cube, normal)
    mask = covered(frame) & np.isfinite(normal[..., 0])
    mean, se = mean_and_error(frame, mask)
    assert np.all(np.abs(mean - expected[mask].mean(axis=0)) < 3.0 * se + 0.003 * mean)
    peak = expected[mask].max()
    err = np.abs(frame.image[mask][:, :3] - expected[mask])
    assert np.mean(err < 3.0 * frame.noise_std[mask] + 0.02 * peak) > 0.9
    dark = expected[mask][:, 0] == 0  # facing away from every sun texel: exactly black
    assert dark.sum() > 20 and np.all(frame.image[mask][dark][:, :3] < 0.01 * peak)


def test_texture_maps_are_looked_up_at_the_hit_uv_in_gl_convention():
    # uv (0, 0) is the bottom-left of an image whose row 0 is its top (as the GPU scene uploads it):
    # v = 0.9 on a 2-row map is 0.7 of the top row and 0.3 of the bottom one (repeat wrapping). The
    # estimator is linear in the albedo with the same random stream, so the two renders agree exactly.
    top_red_bottom_green = np.array([[[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]])
    p = plane()
    textured = Mesh.from_arrays(p.positions, p.faces, np.tile([0.5, 0.9], (4, 1)), name="textured")
    cam = Camera((0.0, 2.0, 2.0), (0.0, 0.0, 0.0), fov_y_deg=40.0)
    cube = sun_sky_cube(8, (0.3, 1.0, 0.2))
    a = render_reference([textured], [Material((1.0, 1.0, 1.0), 0.0, 0.5, albedo_map=top_red_bottom_green)], cube,
                         cam, 8, 8, 4)
    b = render_reference([p], [Material((0.7, 0.3, 0.0), 0.0, 0.5)], cube, cam, 8, 8, 4)
    np.testing.assert_allclose(a.image, b.image, rtol=1e-5, atol=1e-6)


def test_background_pixels_show_the_environment_with_zero_alpha():
    cube = sun_sky_cube(8, (0.0, 1.0, 0.0))
    frame = render_reference([sphere(0.1, subdivisions=2)], [WHITE_DIFFUSE], cube, CAM, 16, 16, 1)
    bg = ~covered(frame)
    assert bg.sum() > 200 and np.all(frame.image[bg][:, 3] == 0)
    top, bottom = frame.image[0, 8, :3], frame.image[-1, 8, :3]  # camera looks slightly down
    np.testing.assert_allclose(top, (0.2, 0.3, 0.5), rtol=1e-6)
    np.testing.assert_allclose(bottom, (0.1, 0.1, 0.1), rtol=1e-6)


# --- the estimator's bookkeeping ---------------------------------------------------------------


def sun_scene(spp: int, seed: int, batches: int = 8) -> ReferenceFrame:
    cube = sun_sky_cube(16, (0.5, 1.0, 0.6), sun_radiance=300.0, sun_radius_deg=6.0)
    return render_reference([sphere(0.5, subdivisions=3), plane()], [Material((0.8, 0.6, 0.4), 0.5, 0.7), WHITE_DIFFUSE],
                            cube, Camera((0.0, 1.2, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0), 24, 24, spp, seed,
                            batches)


def test_without_occlusion_every_direction_is_visible():
    # The sphere's shadow on the plane (and its self-shadowing) are gone: without occlusion the image
    # is everywhere at least as bright, strictly brighter where the shadow was, and no ray is cast
    # beyond the primary ones.
    cube = sun_sky_cube(16, (0.3, 1.0, -0.8), sun_radiance=300.0, sun_radius_deg=6.0)  # shadow towards the camera
    args = ([sphere(0.5, subdivisions=3), plane()], [WHITE_DIFFUSE, WHITE_DIFFUSE], cube,
            Camera((0.0, 1.2, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0), 24, 24, 16)
    shadowed = render_reference(*args, seed=3)
    free = render_reference(*args, seed=3, occlusion=False)
    mask = covered(shadowed)
    a, b = shadowed.image[mask][:, :3].mean(axis=1), free.image[mask][:, :3].mean(axis=1)
    assert free.rays_cast == 24 * 24
    assert np.all(b >= a - 3.0 * shadowed.noise_std[mask].max(axis=1) - 1e-6)
    assert np.sum(b > 2.0 * a) > 5   # the sun's shadow on the plane


def test_per_pixel_errors_average_to_the_relative_mse(white_furnace):
    img = white_furnace.image.copy()
    img[..., :3] *= np.linspace(0.5, 1.5, img.shape[1])[None, :, None]
    per_px = relative_squared_errors(img, white_furnace.image)
    assert per_px.shape == (covered(white_furnace).sum(),)
    assert np.sqrt(per_px.mean()) == pytest.approx(relative_rmse(img, white_furnace.image), rel=1e-12)


def test_same_seed_gives_identical_images_and_other_seeds_do_not():
    a, b, c = sun_scene(4, 7), sun_scene(4, 7), sun_scene(4, 8)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.noise_std, b.noise_std)
    assert a.rays_cast == b.rays_cast
    assert not np.array_equal(a.image, c.image)
    assert a.image.dtype == np.float32 and a.image.shape == (24, 24, 4) and a.noise_std.shape == (24, 24, 3)


def test_noise_estimate_falls_as_one_over_sqrt_spp():
    # One sample per batch: no stratification, so plain Monte Carlo: 4x the samples, half the noise.
    lo, hi = sun_scene(8, 11, batches=8), sun_scene(32, 12, batches=32)
    assert lo.noise_floor_rel() / hi.noise_floor_rel() == pytest.approx(2.0, rel=0.15)
    # With the default 8 batches the samples within a batch are stratified: it falls faster
    # (measured 2.35 .. 2.46 for 4x the samples on this scene).
    lo8, hi8 = sun_scene(8, 11), sun_scene(32, 12)
    assert lo8.noise_floor_rel() / hi8.noise_floor_rel() > 2.0
    # ... and the estimate describes the actual difference between independent renders.
    for a, b in ((lo, hi), (lo8, hi8)):
        mask = covered(a)
        diff = (a.image - b.image)[mask][:, :3]
        predicted = np.sqrt(a.noise_std[mask] ** 2 + b.noise_std[mask] ** 2)
        assert np.sqrt(np.mean(diff ** 2)) == pytest.approx(np.sqrt(np.mean(predicted ** 2)), rel=0.2)


def test_fewer_samples_than_batches_give_nan_noise_only_for_one_sample():
    one = sun_scene(1, 1)
    assert np.all(np.isnan(one.noise_std[covered(one)])) and np.isnan(one.noise_floor_rel())
    two = sun_scene(2, 1)
    assert np.all(np.isfinite(two.noise_std))


@pytest.mark.parametrize("kwargs", [{"spp": 0}, {"width": 0}, {"batches": 0}, {"seed": -1}])
def test_invalid_counts_are_rejected(kwargs):
    args = {"width": 8, "height": 8, "spp": 1, "seed": 0, "batches": 8, **kwargs}
    with pytest.raises(InvalidInputError):
        render_reference([sphere(0.5, subdivisions=1)], [WHITE_DIFFUSE], np.ones((6, 4, 4, 3)), CAM, **args)


# --- metrics ----------------------------------------------------------------------------------


def test_metrics_of_identical_images_are_zero(white_furnace):
    img = white_furnace.image
    assert relative_rmse(img, img) == 0.0
    assert mean_flip(img, img) < 1e-6


def test_relative_rmse_is_scale_invariant_and_matches_a_uniform_error(white_furnace):
    img = white_furnace.image.astype(np.float64)
    off = img.copy()
    off[..., :3] *= 1.05
    # (t - r)^2 / (r^2 + eps) on images normalized to mean 1 with r ~ 1 everywhere: ~0.05 / sqrt(1.01).
    assert relative_rmse(off, img) == pytest.approx(0.05 / np.sqrt(1.0 + 0.01), rel=0.02)
    scaled, scaled_off = img.copy(), off.copy()
    scaled[..., :3] *= 1000.0
    scaled_off[..., :3] *= 1000.0
    assert relative_rmse(scaled_off, scaled) == pytest.approx(relative_rmse(off, img), rel=1e-9)


def test_noise_floor_of_two_seeds_is_small_but_not_zero():
    a, b = sun_scene(16, 21), sun_scene(16, 22)
    floor = noise_floor(a, b)
    assert 0.0 < floor.relative_rmse < 0.3
    assert 0.0 < floor.mean_flip < 0.2
    # The rel. RMSE of two independent renders is ~ sqrt(2) x each one's relative noise.
    assert floor.relative_rmse == pytest.approx(np.sqrt(2) * a.noise_floor_rel(), rel=0.25)


def _grey(values, alpha=None) -> np.ndarray:
    v = np.asarray(values, np.float64)
    img = np.zeros((*v.shape, 4))
    img[..., :3] = v[..., None]
    img[..., 3] = 1.0 if alpha is None else alpha
    return img


def test_artefact_share_counts_pixels_beyond_twice_or_half_the_truth():
    truth = _grey(np.ones((10, 10)))
    test = truth.copy()
    test[0, :3, :3] = 2.5    # three too bright
    test[1, :2, :3] = 0.3    # two too dark
    test[2, :, :3] = 1.9     # within 2x: not counted
    test[3, :, :3] = 0.55    # within 0.5x: not counted
    found = artefact_share(test, truth, truth)
    assert (found.too_bright, found.too_dark, found.judged_pixels) == (3, 2, 100)
    assert found.share == pytest.approx(0.05)
    assert found.judged == 1.0
    # RMSE spreads the same five pixels over the image; the share does not depend on the rest.
    assert artefact_share(truth, truth, truth).share == 0.0


def test_artefact_share_sees_a_leak_into_a_black_fold_but_not_dark_noise():
    values = np.ones((10, 10))
    values[5:, :] = 0.0   # half the object is black in truth: the floor is 2 % of the mean 0.5 = 0.01
    truth = _grey(values)
    test = truth.copy()
    test[5, :4, :3] = 0.05    # a leak of 10 % of the mean into the black half: counted
    test[6, :4, :3] = 0.005   # half the floor: invisible, not counted
    found = artefact_share(test, truth, truth)
    assert (found.too_bright, found.too_dark) == (4, 0)


def test_artefact_share_skips_pixels_where_the_two_references_disagree():
    a = _grey(np.ones((4, 4)))
    b = a.copy()
    b[0, :, :3] = 2.0          # the reference's own noise: these four pixels are not judged
    test = a.copy()
    test[0, :, :3] = 10.0      # wrong there, and wrong in one judged pixel
    test[1, 0, :3] = 10.0
    found = artefact_share(test, a, b)
    assert found.judged_pixels == 12 and found.judged == pytest.approx(0.75)
    assert found.too_bright == 1 and found.share == pytest.approx(1 / 12)
    # Only object pixels count: the background (alpha 0) is judged on its own.
    a[..., 3] = 0.0
    a[1, 0, 3] = 1.0
    assert artefact_share(test, a, a).judged_pixels == 1


# --- against the GPU renderer -----------------------------------------------------------------


@pytest.mark.gpu
def test_gpu_renderer_without_occlusion_agrees_with_the_reference_on_a_smooth_sky(renderer):
    # A convex diffuse sphere sees no self-occlusion, so without shadows the renderer differs from the
    # truth only by the PEM approximation: the filtered MIP lookup at the calibrated s = 1 level
    # instead of the cosine lobe. Measured against a 2048-spp reference (48x48, 24 lights, face 32):
    # 2.8 % rel. RMSE on this soft sky; the PEM lobe acts wider than the cosine (it damps gradients
    # by ~25 %), so darker grounds give more: 5.1 % with a ground at 0.15, 6.7 % on the 0.2 .. 1.8
    # linear map above; and a glossy lobe differs far more, because the reference blocks the part
    # of the lobe below the surface (8 % for specular 0.5, g = 0.6), which needs shadows.
    cube = soft_sky_cube(32)
    material = Material((0.8, 0.7, 0.6), 0.0, 0.5)
    scene = renderer.create_scene([sphere()], [material])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        frame = renderer.render(scene, pems, FrameSettings(48, 48, mode=ShadingMode.NO_OCCLUSION), CAM)
    finally:
        pems.release()
        scene.release()
    ref = render_reference([sphere()], [material], cube, CAM, 48, 48, 256, seed=5)
    both = covered(frame) & covered(ref)
    assert both.sum() >= 0.97 * max(covered(frame).sum(), covered(ref).sum())  # same framing and pixel centres
    err = relative_rmse(frame.image, ref.image, both)
    assert err < 0.05, f"PEM vs reference rel. RMSE {err:.4f} (reference noise {ref.noise_floor_rel():.4f})"


@pytest.mark.gpu
def test_gpu_many_light_baseline_agrees_with_the_reference_under_a_sun(renderer):
    # The many-light baseline shades with the median-cut lights themselves (no PEMs): for a convex
    # diffuse sphere under a lone sun split into a few regions it is nearly exact, an independent
    # code path (GPU, the lights' energies and centroids) that checks the reference's directions and
    # energy. The PEM modes are not: their diffuse lookup is a prefiltered MIP level whose lobe is far
    # wider than the cosine, which on this map dims the lit side's peak ~3x and lights the dark side
    # (measured with NO_OCCLUSION: rel. RMSE 1.4 and 0.70x the mean; here 0.03 and 1.00x).
    cube = sun_only_cube(32, (1.0, 0.3, 0.4), radius_deg=6.0)
    scene = renderer.create_scene([sphere()], [WHITE_DIFFUSE])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        frame = renderer.render(scene, pems, FrameSettings(32, 32, mode=ShadingMode.MANY_LIGHTS), CAM)
    finally:
        pems.release()
        scene.release()
    ref = render_reference([sphere()], [WHITE_DIFFUSE], cube, CAM, 32, 32, 64, seed=10)
    both = covered(frame) & covered(ref)
    assert relative_rmse(frame.image, ref.image, both) < 0.05
    mean_ratio = frame.image[both][:, :3].mean() / ref.image[both][:, :3].mean()
    assert mean_ratio == pytest.approx(1.0, abs=0.02)


@pytest.mark.gpu
def test_gpu_glossy_term_of_small_lights_in_closed_form_matches_the_reference(renderer):
    # glossy="wide": a small light's glossy term is its disc seen through the Phong lobe in closed
    # form. A glossy sphere (g = 0.9: s = 10) under a lone 3-degree sun, without occlusion on both
    # sides: the closed form agrees with the reference, the PEM lookup (the paper's, a prefiltered
    # MIP kernel instead of the lobe) does not.
    cube = sun_only_cube(64, (1.0, 0.6, 0.8), radius_deg=3.0)
    material = Material((0.0, 0.0, 0.0), 1.0, 0.9)
    scene = renderer.create_scene([sphere()], [material])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        small = int((np.sin(pems.regions.disc_radius_rad()) <= 0.1).sum())
        frames = {g: renderer.render(scene, pems, FrameSettings(48, 48, mode=ShadingMode.NO_OCCLUSION, glossy=g), CAM)
                  for g in ("pem", "wide")}
    finally:
        pems.release()
        scene.release()
    assert small >= 1
    ref = render_reference([sphere()], [material], cube, CAM, 48, 48, 256, seed=11, occlusion=False)
    both = covered(ref) & covered(frames["wide"])
    err = {g: relative_rmse(f.image, ref.image, both) for g, f in frames.items()}
    assert err["wide"] < 0.03 and err["wide"] < 0.2 * err["pem"], err   # measured: 0.004 and 0.31


@pytest.mark.gpu
def test_gpu_wide_lobes_of_large_lights_in_closed_form_match_the_reference_better(renderer):
    # glossy="wide": a large light's glossy term from its disc through the Phong lobe wherever the lobe
    # is wider than the disc. A glossy sphere under a soft sky (large regions only), no occlusion on
    # either side: at g = 0.6 (s = 2.5, every lobe wide) the closed forms are closer to the reference
    # than the PEM's coarse MIP levels; at g = 1 no lobe is wide and "wide" is "pem", pixel for pixel.
    cube = soft_sky_cube(32)
    scene = renderer.create_scene([sphere()], [Material((0.0, 0.0, 0.0), 1.0, 0.6)])
    mirror = renderer.create_scene([sphere()], [Material((0.0, 0.0, 0.0), 1.0, 1.0)])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        assert (np.sin(pems.regions.disc_radius_rad()) > 0.1).all()      # no small light
        frames = {g: renderer.render(scene, pems, FrameSettings(48, 48, mode=ShadingMode.NO_OCCLUSION, glossy=g), CAM)
                  for g in ("pem", "wide")}
        at_one = [renderer.render(mirror, pems, FrameSettings(32, 32, glossy=g), CAM).image for g in ("pem", "wide")]
    finally:
        pems.release()
        scene.release()
        mirror.release()
    np.testing.assert_array_equal(at_one[0], at_one[1])
    ref = render_reference([sphere()], [Material((0.0, 0.0, 0.0), 1.0, 0.6)], cube, CAM, 48, 48, 256, seed=12,
                           occlusion=False)
    both = covered(ref) & covered(frames["wide"])
    err = {g: relative_rmse(f.image, ref.image, both) for g, f in frames.items()}
    assert err["wide"] < 0.02 and err["wide"] < 0.85 * err["pem"], err   # measured: 0.013 and 0.019


def _sky_over_grass(face_size: int) -> np.ndarray:
    """A blue sky, brighter towards +x, over green grass: colour that a region's one light averages away."""
    d = texel_directions(face_size)
    sky = np.array([0.3, 0.5, 1.6]) * (1.0 + 0.8 * d[..., 0:1])
    return np.where(d[..., 1:2] > 0, sky, np.array([0.25, 0.9, 0.15])).astype(np.float32)


@pytest.mark.gpu
def test_gpu_sub_lights_bring_the_glossy_term_closer_to_the_reference(renderer):
    # sub_lights: each region's glossy term in closed form from k discs of its own texels. A glossy
    # sphere (g = 0.8, s = 5, every lobe wide) under a sky over grass, no occlusion on either side:
    # 24 lights with 4 discs each are closer to the reference than with one, and 6 lights with 4
    # discs each are the 24 lights' image (the same median cut, two levels further).
    cube = _sky_over_grass(32)
    material = Material((0.0, 0.0, 0.0), 1.0, 0.8)
    scene = renderer.create_scene([sphere()], [material])
    frames = {}
    try:
        for n_lights in (6, 24):
            pems = renderer.build_pems(cube, PEMSettings(n_lights))
            try:
                for k in (1, 4):
                    settings = FrameSettings(48, 48, mode=ShadingMode.NO_OCCLUSION, glossy="wide", sub_lights=k)
                    frames[n_lights, k] = renderer.render(scene, pems, settings, CAM).image
            finally:
                pems.release()
    finally:
        scene.release()
    np.testing.assert_allclose(frames[6, 4], frames[24, 1], rtol=1e-4, atol=1e-6)
    assert np.abs(frames[6, 4] - frames[6, 1]).max() > 0.1 * frames[6, 1].max()   # the discs do change it
    ref = render_reference([sphere()], [material], cube, CAM, 48, 48, 1024, seed=13, occlusion=False)
    both = covered(ref) & (frames[24, 1][..., 3] > 0.5)
    err = {k: relative_rmse(frames[24, k], ref.image, both) for k in (1, 4)}
    # measured: 0.079 and 0.024, the reference's own noise (one half against the other) 0.010
    assert err[4] < 0.05 and err[4] < 0.6 * err[1], (err, ref.noise_floor_rel())



def test_reference_command_draws_the_background_it_is_asked_for(tmp_path):
    # `garment-render reference --background black` leaves nothing behind the object, as `render` does.
    import OpenEXR
    from PIL import Image

    from renderer.cli import main

    def read_rgba(path):
        ch = OpenEXR.File(str(path), separate_channels=True).channels()
        return np.stack([ch[c].pixels for c in "RGBA"], axis=-1).astype(np.float64)

    images = {}
    for background in ("env", "black"):
        out = tmp_path / background
        rc = main(["reference", "--size", "24x24", "--spp", "2", "--face-size", "16", "--background", background,
                   "--exr", f"{out}.exr", "--out", f"{out}.png"])
        assert rc == 0
        images[background] = (read_rgba(f"{out}.exr"), np.asarray(Image.open(f"{out}.png")))
    (env_exr, env_png), (black_exr, black_png) = images["env"], images["black"]
    # Each pixel's area (4 x 4 strata by default): alpha is the covered share; over black the colour is
    # premultiplied by it, over the map the map fills the rest.
    alpha = env_exr[..., 3]
    empty, full, part = alpha == 0, alpha == 1, (alpha > 0) & (alpha < 1)
    assert empty.any() and full.any() and part.any()
    np.testing.assert_array_equal(black_exr[..., 3], alpha)
    assert env_exr[empty][:, :3].max() > 0 and black_exr[empty][:, :3].max() == 0
    assert np.array_equal(env_exr[full], black_exr[full])
    assert (env_exr[part][:, :3] > black_exr[part][:, :3]).all()
    # The PNG is transparent where nothing is drawn, opaque over the map.
    assert black_png.shape[2] == 4 and black_png[empty][:, 3].max() == 0
    assert env_png.shape[2] == 3 or env_png[empty | part][:, 3].min() == 255
