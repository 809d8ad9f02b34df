"""SH9 irradiance (renderer/lighting/sh.py) and its use for the lights without a shadow map."""

import numpy as np
import pytest
from conftest import CAM, plane, sphere, sun_sky_cube

from renderer.envmap.cube import cube_solid_angles, texel_directions
from renderer.lighting.pem import PEMSettings
from renderer.lighting.sh import irradiance, irradiance_coefficients, region_sh
from renderer.reference.montecarlo import primary_rays
from renderer.renderer import FrameSettings
from renderer.shading.material import Material


def _normals(k=40, seed=0):
    n = np.random.default_rng(seed).normal(size=(k, 3))
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_constant_map_gives_pi_times_radiance():
    cube = np.full((6, 16, 16, 3), 2.0)
    c = irradiance_coefficients(region_sh(cube, np.zeros((6, 16, 16), int), 1)[0])
    np.testing.assert_allclose(irradiance(c, _normals()), 2.0 * np.pi, rtol=1e-5)


def test_band_limited_map_is_exact():
    # A map of SH order <= 2 is represented exactly, so its SH9 irradiance is the cosine convolution
    # itself (here by brute force over the texels; the rest is the cube's discretization).
    n = 48
    d = texel_directions(n)
    cube = np.repeat((1.0 + 0.5 * d[..., 1] + 0.3 * d[..., 0] ** 2 - 0.2 * d[..., 0] * d[..., 2])[..., None], 3, -1)
    labels = np.arange(6)[:, None, None] * np.ones((6, n, n), int)  # six regions, summed
    c = irradiance_coefficients(region_sh(cube, labels, 6).sum(axis=0))
    normals = _normals()
    w, dirs, rad = cube_solid_angles(n).reshape(-1), d.reshape(-1, 3), cube.reshape(-1, 3)
    exact = np.array([(np.maximum(dirs @ m, 0.0)[:, None] * w[:, None] * rad).sum(axis=0) for m in normals])
    np.testing.assert_allclose(irradiance(c, normals), exact, rtol=2e-3)


@pytest.mark.parametrize("diffuse", ["pem", "lights", "mixed", "sh"])
def test_renderer_furnace_with_every_light_unshadowed_and_sh(renderer, diffuse):
    # Whatever the diffuse source, SH9 carries the unshadowed lights' diffuse term; the sphere has no
    # glossy lobe, so the lighting pass visits none of the 48 lights.
    scene = renderer.create_scene([sphere()], [Material((1.0, 1.0, 1.0), 0.0, 0.0)])
    pems = renderer.build_pems(np.full((6, 32, 32, 3), 2.5, np.float32), PEMSettings(48))
    try:
        frame = renderer.render(scene, pems, FrameSettings(64, 64, shadow_threshold=1.0, sh_unshadowed=True,
                                                           diffuse=diffuse), CAM)
    finally:
        pems.release()
        scene.release()
    assert frame.timings["shadowed_lights"] == 0
    assert frame.timings["sh_lights"] == 48 and frame.timings["sh_skipped_lights"] == 48
    px = frame.image[frame.image[..., 3] > 0.5][:, :3]
    assert px.size > 1000
    np.testing.assert_allclose(px, 2.5, rtol=1e-4)


@pytest.mark.parametrize("diffuse", ["pem", "lights"])
def test_sh_for_dim_lights_changes_the_image_a_little(renderer, diffuse):
    cube = sun_sky_cube(32, (1, 1, 0.3), sun_radiance=5e3, sun_radius_deg=3)
    scene = renderer.create_scene([sphere(0.4, centre=(0, 0.6, 0)), plane(4.0)],
                                  [Material((0.8, 0.3, 0.3), 0.4, 0.8), Material()])
    pems = renderer.build_pems(cube, PEMSettings(48))
    d = {"diffuse": diffuse}
    try:
        a = renderer.render(scene, pems, FrameSettings(64, 64, shadow_threshold=0.01, **d), CAM)
        b = renderer.render(scene, pems, FrameSettings(64, 64, shadow_threshold=0.01, sh_unshadowed=True, **d), CAM)
        full = renderer.render(scene, pems, FrameSettings(64, 64, **d), CAM)
        ignored = renderer.render(scene, pems, FrameSettings(64, 64, sh_unshadowed=True, **d), CAM)
    finally:
        pems.release()
        scene.release()
    assert 0 < b.timings["shadowed_lights"] < 48
    # The sphere is glossy: every light is still visited (for its glossy term).
    assert 0 < b.timings["sh_lights"] <= 48 - b.timings["shadowed_lights"] and b.timings["sh_skipped_lights"] == 0
    assert a.timings["sh_lights"] == 0 and ignored.timings["sh_lights"] == 0
    # The regions' SH9 is made by the first frame that sums it, in its own stage.
    assert "light_tables" in b.timings["wall_ms"] and "light_tables" not in a.timings["wall_ms"]
    m = a.image[..., 3] > 0.5
    change = np.abs(a.image - b.image)[m][:, :3].mean() / a.image[m][:, :3].mean()
    assert 0.0 < change < 0.01, change                # measured 0.3 % (pem), 0.016 % (lights)
    np.testing.assert_array_equal(ignored.image, full.image)  # no unshadowed light: nothing to replace


@pytest.mark.parametrize("diffuse, n_lights", [("pem", 48), ("lights", 48), ("lights", 384)])
def test_diffuse_only_scene_skips_the_sh_lights_for_the_same_image(renderer, diffuse, n_lights):
    # 384 lights: two PEM textures, whose loops are the shader's kinds 8-15.
    # No glossy lobe anywhere: the lights SH9 carries add nothing of their own, so the lighting pass
    # leaves them out (renderer.light_kinds); the image is the one where it visits them.
    cube = sun_sky_cube(32, (1, 1, 0.3), sun_radiance=5e3, sun_radius_deg=3)
    scene = renderer.create_scene([sphere(0.4, centre=(0, 0.6, 0)), plane(4.0)],
                                  [Material((0.8, 0.3, 0.3), 0.0, 0.8), Material()])
    pems = renderer.build_pems(cube, PEMSettings(n_lights))
    settings = FrameSettings(64, 64, shadow_threshold=0.01 * 48 / n_lights, sh_unshadowed=True, diffuse=diffuse)
    try:
        assert scene.has_glossy_lobe is False
        skipping = renderer.render(scene, pems, settings, CAM)
        scene.has_glossy_lobe = True   # as if some pixel had a glossy lobe: every light is visited
        visiting = renderer.render(scene, pems, settings, CAM)
    finally:
        pems.release()
        scene.release()
    # The large lights without a map (at 384 lights many regions are small and keep their own term).
    n_sh = skipping.timings["sh_lights"]
    assert 0 < n_sh <= n_lights - skipping.timings["shadowed_lights"]
    assert skipping.timings["sh_skipped_lights"] == n_sh and visiting.timings["sh_skipped_lights"] == 0
    assert (skipping.image[..., 3] > 0.5).mean() > 0.3
    np.testing.assert_allclose(skipping.image, visiting.image, rtol=1e-5, atol=1e-6)


def test_diffuse_sh_renders_a_band_limited_map_exactly(renderer):
    # diffuse="sh": every large light's diffuse term is its region's SH9 irradiance; unoccluded
    # (no-occlusion mode, a convex sphere) they sum to the map's own SH9 irradiance, which for a map
    # of order <= 2 is the exact cosine convolution (test_band_limited_map_is_exact).
    n = 32
    d = texel_directions(n)
    field = 1.0 + 0.5 * d[..., 1] + 0.3 * d[..., 0] ** 2 - 0.2 * d[..., 0] * d[..., 2]
    cube = np.repeat(field[..., None], 3, -1).astype(np.float32)
    from renderer.renderer import ShadingMode

    scene = renderer.create_scene([sphere()], [Material((1.0, 1.0, 1.0), 0.0, 0.0)])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        frame = renderer.render(scene, pems, FrameSettings(64, 64, diffuse="sh", mode=ShadingMode.NO_OCCLUSION), CAM)
        again = renderer.render(scene, pems, FrameSettings(64, 64, diffuse="sh", mode=ShadingMode.NO_OCCLUSION), CAM)
        small = int((np.sin(pems.regions.disc_radius_rad()) <= 0.1).sum())
    finally:
        pems.release()
        scene.release()
    assert small == 0   # every light here is large: all of them go through SH9
    # The lights' coefficients are made once per PEM set, in the first frame's own stage.
    assert "light_tables" in frame.timings["wall_ms"] and "light_tables" not in again.timings["wall_ms"]
    c = irradiance_coefficients(region_sh(cube.astype(np.float64), np.zeros((6, n, n), int), 1)[0])
    img, cov = frame.image, frame.image[..., 3] > 0.5
    assert cov.sum() > 1000
    # Each pixel against the irradiance along its own normal, from the analytic sphere (radius 0.5 at
    # the origin) hit by the pixel's ray; the mesh's interpolated normals differ from it by a little,
    # most at the silhouette, which is left out.
    o, d = primary_rays(CAM, 64, 64, np.zeros(3), 0.5)
    b = np.einsum("ij,ij->i", o, d)
    disc = b * b - (np.einsum("ij,ij->i", o, o) - 0.25)
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    nrm = (o + t[:, None] * d) / 0.5
    facing = hit & (-np.einsum("ij,ij->i", nrm, d) > 0.3) & cov.ravel()
    assert facing.sum() > 1000
    px = img.reshape(-1, 4)[facing, :3]
    want = irradiance(c, nrm[facing]) / np.pi
    rel = np.abs(px - want).max(axis=1) / want.max(axis=1)
    assert rel.max() < 0.01, rel.max()   # measured: 0.2 %


@pytest.mark.parametrize("diffuse", ["pem", "lights"])
def test_small_unshadowed_lights_keep_their_own_diffuse_term(renderer, diffuse):
    # Order 2 cannot hold a sun's shape (its SH9 irradiance rings): under a lone small sun with every
    # light unshadowed, sh_unshadowed leaves the sun's diffuse term as it was; the large regions it
    # carries are black. Measured with the sun in the sum: 15 % (pem) and 9 % (lights) of the mean apart.
    cube = sun_sky_cube(32, (1, 1, 0.3), sun_radiance=50.0, sun_radius_deg=3, sky=(0, 0, 0), ground=(0, 0, 0))
    scene = renderer.create_scene([sphere()], [Material((0.8, 0.8, 0.8), 0.0, 0.0)])
    pems = renderer.build_pems(cube, PEMSettings(48, whole_sources=True))
    try:
        plain, sh = (renderer.render(scene, pems, FrameSettings(64, 64, shadow_threshold=1.0, sh_unshadowed=on,
                                                                diffuse=diffuse), CAM)
                     for on in (False, True))
        small = int((np.sin(pems.regions.disc_radius_rad()) <= 0.1).sum())
    finally:
        pems.release()
        scene.release()
    assert small >= 1 and sh.timings["sh_lights"] == 48 - small
    m = plain.image[..., 3] > 0.5
    assert plain.image[m][:, :3].max() > 0
    np.testing.assert_allclose(sh.image, plain.image, rtol=1e-4, atol=1e-5 * plain.image[m][:, :3].max())
