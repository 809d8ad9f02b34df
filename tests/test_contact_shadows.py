"""Contact shadows (FrameSettings.contact_shadow_texels; lighting.frag): occluders closer to a surface
than a shadow map's bias, found in the geometry pass's positions along screen lines."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import CAM as FRONT
from conftest import covered, plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.cli import build_parser, resolve_quality
from renderer.config import MAX_CONTACT_TEXELS
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.reference import render_reference
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material

# A plate a little above a floor, lit by a sun 25 degrees above the horizon from the plate's side
# (straight across its edge, or turned by an azimuth): the plate's shadow reaches
# H cos(azimuth) / tan(25 deg) beyond its edge, a strip the shadow maps' normal offset (1.5 texels of a
# 64^2 map over the floor in view, 3-5 cm) lifts every lookup out of.
H, ELEVATION = 0.03, np.radians(25.0)
CAM = Camera((0.6, 0.5, 0.0), (0.0, 0.0, 0.0), fov_y_deg=40.0)
# 3 texels of 64^2 maps over all the casters (the search's unit, whatever part the camera frames):
# about 14 cm, the distance the presets search on the dress form (its eight steps a direction are
# spread over the radius: a much larger one steps over a 3 cm gap).
RADIUS = 3.0
# The search depends on the view: the edge seen from 40 degrees to the side, and from higher up.
SIDE = Camera((0.46, 0.5, 0.39), (0.0, 0.0, 0.0), fov_y_deg=40.0)
HIGH = Camera((0.5, 0.8, 0.0), (0.15, 0.0, 0.0), fov_y_deg=40.0)


def _sun(azimuth_deg: float) -> np.ndarray:
    a = np.radians(azimuth_deg)
    return np.array([-np.cos(ELEVATION) * np.cos(a), np.sin(ELEVATION), np.cos(ELEVATION) * np.sin(a)])


def _plate() -> Mesh:
    v = np.array([[-1.0, H, -0.5], [0.0, H, -0.5], [0.0, H, 0.5], [-1.0, H, 0.5]])
    return Mesh.from_arrays(v, np.array([[0, 2, 1], [0, 3, 2]]), name="plate")


def _floor_and_plate() -> Mesh:
    """The floor and the plate as one mesh: one shadow group, whose shadow on itself the maps' bias
    hides (a fold's lips, a collar over the neck of the same garment)."""
    floor, plate = plane(2.0), _plate()
    return Mesh.from_arrays(np.concatenate([floor.positions, plate.positions]),
                            np.concatenate([floor.faces, plate.faces + len(floor.positions)]), name="floor-and-plate")


def _floor_regions(renderer, width, height, azimuth_deg):
    """(a strip in the plate's shadow beyond its edge, open floor far from it): masks of the last
    frame's pixels, from the geometry pass's world positions."""
    pos = np.frombuffer(renderer._target.gbuf[0].read(), np.float32).reshape(height, width, 4)[::-1]
    floor = (pos[..., 1] < 1e-4) & (np.abs(pos[..., 2]) < 0.3)
    reach = H * np.cos(np.radians(azimuth_deg)) / np.tan(ELEVATION)
    strip = floor & (pos[..., 0] > 0.1 * reach) & (pos[..., 0] < 0.6 * reach)
    return strip, floor & (pos[..., 0] > 0.3)


# Straight across the edge (the light's screen direction on a slice), turned either way (between two
# slices, mirrored), on a square and a wide image, from three views.
@pytest.mark.parametrize("azimuth_deg, width, height, cam", [
    (0.0, 64, 64, CAM), (25.0, 96, 64, CAM), (-25.0, 64, 64, CAM), (25.0, 64, 64, CAM), (-25.0, 96, 64, CAM),
    (0.0, 64, 64, SIDE), (25.0, 64, 64, SIDE), (0.0, 64, 64, HIGH)])
def test_contact_shadows_darken_what_the_maps_bias_skips(renderer, azimuth_deg, width, height, cam):
    cube = sun_sky_cube(64, _sun(azimuth_deg), sun_radiance=5e3, sun_radius_deg=2, sky=(0.02, 0.02, 0.02),
                        ground=(0, 0, 0))
    meshes, materials = [_floor_and_plate()], [Material((0.8, 0.8, 0.8))]
    scene = renderer.create_scene(meshes, materials)
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        base = FrameSettings(width, height, shadow_size=64, diffuse="lights", background=Background.BLACK)
        off = renderer.render(scene, pems, dataclasses.replace(base, contact_shadow_texels=0.0), cam).image
        on = renderer.render(scene, pems, dataclasses.replace(base, contact_shadow_texels=RADIUS), cam).image
    finally:
        pems.release()
        scene.release()
    strip, open_floor = _floor_regions(renderer, width, height, azimuth_deg)
    assert strip.sum() > 40 and open_floor.sum() > 40
    ref = render_reference(meshes, materials, cube, cam, width, height, 16, seed=3).image
    lum = {k: img[..., :3].mean(axis=-1) for k, img in (("off", off), ("on", on), ("ref", ref))}
    lit = {k: float(v[open_floor].mean()) for k, v in lum.items()}
    shade = {k: float(v[strip].mean()) / lit[k] for k, v in lum.items()}
    # The truth: the strip is in the plate's shadow (only the dim sky reaches it).
    assert shade["ref"] < 0.05, shade
    # The maps alone light it as open floor: the case contact shadows are for.
    assert shade["off"] > 0.8, shade
    # With them it is dark, to 0.01-0.29 of open floor across these views and suns (the strip is its
    # part up to 0.6 of the reach; towards the far edge the plate rises barely above the sun, and the
    # light's ramp, the slices' interpolation and the search's steps let part of it through).
    assert shade["on"] < 0.35, shade
    # Open floor has nothing above its own plane within the radius: unchanged (to float32 rounding:
    # the two are different programs).
    np.testing.assert_allclose(on[open_floor], off[open_floor], rtol=1e-4)


@pytest.mark.parametrize("azimuth_deg", [0.0, 25.0])
def test_a_plate_of_its_own_shadows_the_floor_through_the_maps_alone(renderer, azimuth_deg):
    # The plate and the floor as two meshes: two shadow groups (renderer/scene.py). The floor is
    # compared with the plate's moments without the bias that hides a surface's own shadow, so the
    # strip the bias lifted every lookup out of (the test above) is in shadow without any contact search.
    cube = sun_sky_cube(64, _sun(azimuth_deg), sun_radiance=5e3, sun_radius_deg=2, sky=(0.02, 0.02, 0.02),
                        ground=(0, 0, 0))
    scene = renderer.create_scene([plane(2.0), _plate()], [Material((0.8, 0.8, 0.8)), Material((0.5, 0.5, 0.5))])
    pems = renderer.build_pems(cube, PEMSettings(24))
    try:
        # 256^2 maps: a texel of 8 mm against the shadow's 25 mm across in the light's view (a 64^2
        # map's 3 cm texel cannot resolve it).
        fs = FrameSettings(64, 64, shadow_size=256, diffuse="lights", contact_shadow_texels=0.0,
                           background=Background.BLACK)
        lum = renderer.render(scene, pems, fs, CAM).image[..., :3].mean(axis=-1)
    finally:
        pems.release()
        scene.release()
    strip, open_floor = _floor_regions(renderer, 64, 64, azimuth_deg)
    assert strip.sum() > 40 and open_floor.sum() > 40
    # Measured 0.008 and 0.022 of open floor; the truth (the test above) is under 0.05.
    assert float(lum[strip].mean()) < 0.05 * float(lum[open_floor].mean())


def test_a_convex_body_does_not_shadow_itself(renderer):
    cube = sun_sky_cube(32, (0.3, 0.2, 1.0), sun_radiance=1e3, sun_radius_deg=3)
    scene = renderer.create_scene([sphere(0.5, subdivisions=3)], [Material((0.7, 0.7, 0.7), 0.5, 0.6)])
    pems = renderer.build_pems(cube, PEMSettings(12))
    try:
        fs = FrameSettings(64, 64, shadow_size=64, background=Background.BLACK)
        off = renderer.render(scene, pems, dataclasses.replace(fs, contact_shadow_texels=0.0), FRONT)
        on = renderer.render(scene, pems, dataclasses.replace(fs, contact_shadow_texels=MAX_CONTACT_TEXELS), FRONT)
        assert covered(on).sum() > 100
        # Every neighbour on a convex body lies below the pixel's own triangle plane: unchanged (to
        # float32 rounding: the two are different programs).
        np.testing.assert_allclose(on.image, off.image, rtol=1e-4, atol=1e-6)
        # The frame reports the search's distance in world units: the knob times a main-map texel.
        half = renderer.render(scene, pems, dataclasses.replace(fs, contact_shadow_texels=MAX_CONTACT_TEXELS / 2), FRONT)
        assert off.settings["contact_radius"] == 0.0 and half.settings["contact_radius"] > 0.0
        assert on.settings["contact_radius"] == pytest.approx(2.0 * half.settings["contact_radius"])
    finally:
        pems.release()
        scene.release()


def test_contact_shadow_texels_is_a_bounded_number():
    for good in (0.0, MAX_CONTACT_TEXELS):
        assert FrameSettings(contact_shadow_texels=good).contact_shadow_texels == good
    for bad in (-0.5, MAX_CONTACT_TEXELS + 1, float("nan"), True):
        with pytest.raises(InvalidInputError, match="contact_shadow_texels"):
            FrameSettings(contact_shadow_texels=bad)


def test_the_command_line_names_the_knob():
    q = resolve_quality(build_parser().parse_args(["render", "--contact-shadow-texels", "3"]))
    assert q["contact_shadow_texels"] == 3.0
    q = resolve_quality(build_parser().parse_args(["render", "--preset", "fast", "--contact-shadow-texels", "0"]))
    assert q["contact_shadow_texels"] == 0.0 and q["shadow_size"] < 512   # the flag over the preset's value
