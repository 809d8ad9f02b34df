"""The error split's oracle: each light's visibility from rays, read by the lighting pass in place of
the shadow maps (renderer/reference/visibility.py, Renderer.render(visibility=))."""

import numpy as np
import pytest
from conftest import plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.reference import relative_rmse
from renderer.reference.visibility import ExactVisibility
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material

SUN = np.array([0.5, 1.0, 0.3]) / np.linalg.norm([0.5, 1.0, 0.3])
CAM = Camera((0.0, 4.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=50.0)


class Recording(ExactVisibility):
    def __call__(self, points, geometric, covered):
        self.got = super().__call__(points, geometric, covered)
        self.covered = covered
        return self.got


@pytest.fixture(scope="module")
def sun_scene(renderer):
    cube = sun_sky_cube(64, SUN, sun_radiance=5e3, sun_radius_deg=2, sky=(0.1, 0.1, 0.1), ground=(0, 0, 0))
    meshes = [sphere(0.4, centre=(0.0, 0.8, 0.0)), plane(6.0)]
    scene = renderer.create_scene(meshes, [Material((0.5, 0.5, 0.5)), Material((0.8, 0.8, 0.8))])
    pems = renderer.build_pems(cube, PEMSettings(24))
    yield meshes, cube, scene, pems
    pems.release()
    scene.release()


def test_exact_visibility_shades_as_the_shadow_maps_where_they_are_right(renderer, sun_scene):
    """A sphere over a floor under a sun: the oracle's frame is the maps' frame up to the maps' own
    error, the sun's shadow dark under both, and the oracle sees the shadow where the maps do."""
    meshes, cube, scene, pems = sun_scene
    fs = FrameSettings(96, 96, background=Background.BLACK, blur_scale=0.0)
    maps = renderer.render(scene, pems, fs, CAM).image
    oracle = Recording(meshes, cube, pems.regions, rays_per_light=16)
    exact = renderer.render(scene, pems, fs, CAM, visibility=oracle).image
    mask = maps[..., 3] > 0.5
    assert relative_rmse(exact, maps, mask) < 0.2
    sun = int(np.argmax(pems.regions.energy_luminance))
    vis = oracle.got[sun]
    # Rows of the gbuffer are bottom-up: some floor pixels see no sun, most see all of it.
    covered = oracle.covered
    assert 0.005 < (vis[covered] < 0.1).mean() < 0.5 and (vis[covered] > 0.9).mean() > 0.5
    # Where the oracle says the sun is hidden the frame is far darker than where it is seen.
    lum = exact[::-1, :, :3].mean(axis=-1)   # back to the gbuffer's rows
    floor = covered & (lum > 0)
    assert lum[floor & (vis < 0.1)].mean() < 0.3 * lum[floor & (vis > 0.9)].mean()


def test_a_convex_object_alone_sees_every_light(renderer):
    cube = sun_sky_cube(32, SUN, sky=(0.3, 0.3, 0.3))
    meshes = [sphere(0.5)]
    scene = renderer.create_scene(meshes, [Material((0.5, 0.5, 0.5))])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        oracle = Recording(meshes, cube, pems.regions, rays_per_light=8)
        renderer.render(scene, pems, FrameSettings(48, 48), Camera((0.0, 0.3, 2.0), (0.0, 0.0, 0.0), fov_y_deg=40.0),
                        visibility=oracle)
    finally:
        pems.release()
        scene.release()
    assert oracle.covered.sum() > 300
    assert np.array_equal(oracle.got[:, oracle.covered], np.ones_like(oracle.got[:, oracle.covered]))


def test_an_oracle_of_the_wrong_shape_is_refused(renderer, sun_scene):
    _, _, scene, pems = sun_scene
    with pytest.raises(InvalidInputError, match="shape"):
        renderer.render(scene, pems, FrameSettings(32, 32), CAM, visibility=lambda p, g, c: np.ones((3, 32, 32)))


def test_the_oracle_needs_the_regions_own_cube(sun_scene):
    meshes, cube, _, pems = sun_scene
    with pytest.raises(InvalidInputError, match="faces"):
        ExactVisibility(meshes, cube[:, :32, :32], pems.regions)
