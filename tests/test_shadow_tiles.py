"""Small lights' tiled shadow maps (FrameSettings.small_light_tiles): a k x k grid of layers, each a
k-th of the light's footprint per axis, so a sun's shadow gets k times the texels per axis."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import plane, sphere, sun_sky_cube
from renderer.camera import Camera
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material
from renderer.shadows.lights import plan_layers, tile_margin_scale


def test_small_lights_come_first_with_k_squared_layers():
    layers = np.array([0, 1, -1, 2, 3], np.int32)      # light 2 has no shadow map
    small = np.array([False, True, True, False, True])
    plan = plan_layers(layers, small, 3)
    assert list(plan.tiles) == [1, 3, 1, 1, 3]
    assert plan.n_sharp_layers == 18 and plan.n_layers == 20
    assert list(plan.first_layer) == [18, 0, -1, 19, 9]
    assert list(plan.layer_light) == [1] * 9 + [4] * 9 + [0, 3]
    flat = plan_layers(layers, small, 1)
    assert list(flat.first_layer) == [0, 1, -1, 2, 3] and flat.n_sharp_layers == 0 and flat.n_layers == 4
    # size 100, margin ceil(3) + 2 = 5 texels a side: the tile itself has 90 texels.
    assert list(tile_margin_scale(np.array([0.0, 1.0]), np.array([1, 2]), 100)) == [1.0, 100 / 90]


def test_tiles_must_be_a_small_whole_number():
    for bad in (0, 9, 1.5, "2"):
        with pytest.raises(InvalidInputError, match="small_light_tiles"):
            FrameSettings(small_light_tiles=bad)


@pytest.fixture(scope="module")
def sun_scene(renderer):
    sun = np.array([0.4, 1.0, 0.3])
    cube = sun_sky_cube(64, sun / np.linalg.norm(sun), sun_radiance=5e3, sun_radius_deg=2, sky=(0.02, 0.02, 0.02),
                        ground=(0, 0, 0))
    scene = renderer.create_scene([sphere(0.4, (0.0, 0.8, 0.0)), plane(3.0)],
                                  [Material((0.5, 0.5, 0.5)), Material((0.8, 0.8, 0.8))])
    pems = renderer.build_pems(cube, PEMSettings(24))
    yield scene, pems
    pems.release()
    scene.release()


def test_a_tiled_map_matches_an_untiled_map_of_k_times_the_size(renderer, sun_scene):
    scene, pems = sun_scene
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)

    def lum(size, k):
        fs = FrameSettings(160, 160, shadow_size=size, small_light_tiles=k, blur_scale=0.0,
                           background=Background.BLACK)
        f = renderer.render(scene, pems, fs, cam)
        assert np.isfinite(f.image).all()
        return f, f.image[..., :3].mean(axis=-1)

    coarse_f, coarse = lum(32, 1)
    tiled_f, tiled = lum(32, 4)
    _, fine = lum(128, 1)
    assert tiled_f.timings["shadow_layers"] > coarse_f.timings["shadow_layers"]
    # The sun's shadow of the sphere is there in every version...
    dark = fine < 0.3 * np.percentile(fine, 95)
    assert dark.sum() > 100
    # ... and the tiled 32^2 map draws it as the untiled 128^2 map does, not as the 32^2 one: no
    # seams where the tiles meet (the shadow crosses the footprint's middle), and sharper edges.
    err_tiled = np.abs(tiled - fine).sum() / fine.sum()
    err_coarse = np.abs(coarse - fine).sum() / fine.sum()
    assert err_tiled < 0.02 and err_tiled < 0.5 * err_coarse, (err_tiled, err_coarse)
