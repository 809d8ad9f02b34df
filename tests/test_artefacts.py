"""Approximations that draw visible artefacts, each against the Monte Carlo reference at every preset
(issue: accurate on light it has never seen). The scenes are small and synthetic so that the truth
is exact enough per pixel at a few samples."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import plane, sun_sky_cube
from renderer import presets as presets_mod
from renderer.camera import Camera
from renderer.reference import render_reference
from renderer.renderer import Background
from renderer.shading.material import Material

PRESETS = ("fast", "balanced", "accurate")
SUN_ELEVATION = np.radians(35.0)


def _preset_frame(renderer, preset, cube, meshes, materials, camera, size):
    knobs = presets_mod.merge_knobs(presets_mod.DEFAULT_PRESETS[preset], {})
    scene = renderer.create_scene(meshes, materials)
    pems = renderer.build_pems(cube, presets_mod.pem_settings(knobs, "sqrt-cosine", None, materials))
    try:
        fs = presets_mod.frame_settings(knobs, size, size, background=Background.BLACK)
        return renderer.render(scene, pems, fs, camera).image
    finally:
        pems.release()
        scene.release()


@pytest.fixture(scope="module")
def sun_over_glossy_floor():
    # A hot sun (1e5 against a sky of 0.3, 0.5 degrees) and a camera at its mirror direction: the
    # highlight on the floor is resolved by the pixels (the reflected direction moves 0.23 degrees a
    # pixel), so its energy and its peak can be compared pixel by pixel.
    sun = (0.0, np.sin(SUN_ELEVATION), -np.cos(SUN_ELEVATION))
    cube = sun_sky_cube(128, sun, sun_radiance=1e5, sun_radius_deg=0.5)
    camera = Camera((0.0, 2 * np.sin(SUN_ELEVATION), 2 * np.cos(SUN_ELEVATION)), (0.0, 0.0, 0.0), fov_y_deg=30.0)
    return cube, camera


@pytest.mark.gpu
@pytest.mark.parametrize("g", [0.9, 0.99, 0.999])
@pytest.mark.parametrize("preset", PRESETS)
def test_a_sun_highlight_keeps_its_energy_and_shape_as_g_tends_to_one(renderer, sun_over_glossy_floor, preset, g):
    # The glossy term of a sun from a PEM lookup draws the texels of its MIP level: at g = 0.999 a
    # square of light 10-13x the true peak, and at g = 0.9 a third too much light; every preset takes
    # a small light's glossy term in closed form instead.
    cube, camera = sun_over_glossy_floor
    size = 96
    meshes, materials = [plane(3.0, 0.0)], [Material((0.0, 0.0, 0.0), 1.0, g)]
    truth = render_reference(meshes, materials, cube, camera, size, size, 32, seed=3).image
    image = _preset_frame(renderer, preset, cube, meshes, materials, camera, size)
    covered = truth[..., 3] > 0.5
    t, f = truth[covered][:, :3].astype(np.float64), image[covered][:, :3].astype(np.float64)
    assert f.sum() == pytest.approx(t.sum(), rel=0.02)
    assert 0.67 < f.max() / t.max() < 1.5
