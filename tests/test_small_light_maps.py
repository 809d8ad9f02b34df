"""Small lights' larger shadow maps (FrameSettings.small_light_scale): a sun's map k times the shadow-map
size per side, in an array of its own, drawn at full caster detail."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material
from renderer.shadows.lights import SMALL_LIGHT_MAX_SIN, plan_layers


def test_small_lights_get_layers_of_the_sharp_array():
    layers = np.array([0, 1, -1, 2, 3], np.int32)      # light 2 has no shadow map
    small = np.array([False, True, True, False, True])
    plan = plan_layers(layers, small, 3)
    assert list(plan.sharp) == [False, True, False, False, True]
    assert list(plan.layer) == [0, 0, -1, 1, 1]
    assert list(plan.main_lights) == [0, 3] and list(plan.sharp_lights) == [1, 4] and plan.n_layers == 4
    flat = plan_layers(layers, small, 1)
    assert list(flat.layer) == [0, 1, -1, 2, 3] and not flat.sharp.any() and len(flat.sharp_lights) == 0


def test_the_scale_must_be_a_small_whole_number():
    for bad in (0, 9, 1.5, "2", True):
        with pytest.raises(InvalidInputError, match="small_light_scale"):
            FrameSettings(small_light_scale=bad)
    with pytest.raises(InvalidInputError, match="8192"):
        FrameSettings(shadow_size=4096, small_light_scale=4)


@pytest.fixture(scope="module")
def sun_scene(renderer):
    sun = np.array([0.4, 1.0, 0.3])
    cube = sun_sky_cube(64, sun / np.linalg.norm(sun), sun_radiance=5e3, sun_radius_deg=2, sky=(0.02, 0.02, 0.02),
                        ground=(0, 0, 0))
    scene = renderer.create_scene([sphere(0.4, centre=(0.0, 0.8, 0.0)), plane(3.0)],
                                  [Material((0.5, 0.5, 0.5)), Material((0.8, 0.8, 0.8))])
    pems = renderer.build_pems(cube, PEMSettings(24))
    yield scene, pems
    pems.release()
    scene.release()


def _ball_and_ground() -> Mesh:
    """The sun scene's sphere and plane as one mesh: one shadow group (renderer/scene.py), so that the
    ball's shadow on the ground goes through the maps' bias as a surface's shadow on itself does."""
    ball, ground = sphere(0.4, centre=(0.0, 0.8, 0.0)), plane(3.0)
    return Mesh.from_arrays(np.concatenate([ball.positions, ground.positions]),
                            np.concatenate([ball.faces, ground.faces + len(ball.positions)]), name="ball-and-ground")


def test_a_small_lights_map_at_k_times_the_size_matches_a_map_of_that_size(renderer, sun_scene):
    scene, pems = sun_scene
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)

    def lum(size, k):
        # No contact shadows: their radius is in main-map texels, which differ between the three.
        fs = FrameSettings(160, 160, shadow_size=size, small_light_scale=k, blur_scale=0.0,
                           contact_shadow_texels=0.0, background=Background.BLACK)
        f = renderer.render(scene, pems, fs, cam)
        assert np.isfinite(f.image).all()
        return f, f.image[..., :3].mean(axis=-1)

    coarse_f, coarse = lum(32, 1)
    sharp_f, sharp = lum(32, 4)
    _, fine = lum(128, 1)
    # The same layers, but the small lights' in a 128^2 array: more memory.
    assert sharp_f.timings["shadow_layers"] == coarse_f.timings["shadow_layers"]
    assert sharp_f.settings["shadow_bytes"] > coarse_f.settings["shadow_bytes"]
    # The sun's shadow of the sphere is there in every version...
    dark = fine < 0.3 * np.percentile(fine, 95)
    assert dark.sum() > 100
    # ... and with the sun's map at 128^2 (4 x 32) it is drawn as with 128^2 maps, not as with 32^2 ones
    # (the sky's lights keep 32^2 maps: the sky is dim here).
    err_sharp = np.abs(sharp - fine).sum() / fine.sum()
    err_coarse = np.abs(coarse - fine).sum() / fine.sum()
    assert err_sharp < 0.02 and err_sharp < 0.5 * err_coarse, (err_sharp, err_coarse)


def test_only_small_lights_with_enough_of_the_energy_get_sharp_maps(renderer, sun_scene):
    from renderer.shadows.lights import SMALL_LIGHT_MAX_SIN

    scene, pems = sun_scene
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    regions = pems.regions
    relative = regions.energy_luminance / regions.energy_luminance.mean()   # x the mean light's energy
    small = np.sin(regions.disc_radius_rad()) <= SMALL_LIGHT_MAX_SIN

    def frame(k, min_energy):
        fs = FrameSettings(64, 64, shadow_size=32, small_light_scale=k, small_light_min_energy=min_energy)
        return renderer.render(scene, pems, fs, cam)

    assert small.sum() >= 2 and relative[small].max() > 4.0     # the sun, split into small regions
    assert frame(4, 0.0).timings["sharp_layers"] == small.sum()
    top = np.sort(relative[small])
    assert top[-1] > top[-2]
    assert frame(4, float(top[-1] + top[-2]) / 2).timings["sharp_layers"] == 1   # between the two largest
    # No light with that much energy: every map in the main array, the image of scale 1 exactly.
    none = frame(4, float(relative.max()) * 1.01)
    assert none.timings["sharp_layers"] == 0
    np.testing.assert_array_equal(none.image, frame(1, 0.0).image)
    for bad in (-1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="small_light_min_energy"):
            FrameSettings(small_light_min_energy=bad)


def test_bright_large_lights_join_the_sharp_maps_only_when_asked(renderer, sun_scene):
    from renderer.shadows.lights import SMALL_LIGHT_MAX_SIN

    scene, pems = sun_scene
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    regions = pems.regions
    relative = regions.energy_luminance / regions.energy_luminance.mean()
    small = np.sin(regions.disc_radius_rad()) <= SMALL_LIGHT_MAX_SIN
    cut = float(np.median(relative[~small]))      # about half of the large lights are that bright

    def sharp_layers(min_energy, large):
        fs = FrameSettings(64, 64, shadow_size=32, small_light_scale=2, small_light_min_energy=min_energy,
                           sharp_large_lights=large)
        return renderer.render(scene, pems, fs, cam).timings["sharp_layers"]

    assert sharp_layers(cut, False) == int((small & (relative >= cut)).sum())
    assert sharp_layers(cut, True) == int((relative >= cut).sum()) > sharp_layers(cut, False)
    assert sharp_layers(0.0, True) == sharp_layers(0.0, False) == int(small.sum())   # without a threshold: small ones only


def test_sharp_lights_close_together_share_one_map():
    from renderer.shadows.lights import share_sharp_maps

    def unit(deg_x, deg_y=0.0):
        v = np.array([np.tan(np.radians(deg_x)), np.tan(np.radians(deg_y)), 1.0])
        return v / np.linalg.norm(v)

    # Lights 0, 1, 3 small and bright (0 and 3 a degree apart, 1 twenty degrees away), 2 a large light, 4
    # without a shadow map.
    directions = np.array([unit(0.0), unit(20.0), unit(0.0, 30.0), unit(1.0), unit(-40.0)])
    energy = np.array([4.0, 3.0, 1.0, 2.0, 0.5])
    plan = plan_layers(np.array([0, 1, 2, 3, -1], np.int32), np.array([True, True, False, True, False]), 4)
    assert list(plan.sharp_lights) == [0, 1, 3]

    same, dirs = share_sharp_maps(plan, directions, energy, 0.0)
    assert same is plan and np.array_equal(dirs, directions)

    shared, dirs = share_sharp_maps(plan, directions, energy, np.radians(2.0))
    assert list(shared.sharp_lights) == [0, 1]            # the brightest light leads its group
    assert list(shared.layer) == [0, 1, 0, 0, -1] and list(shared.sharp) == [True, True, False, True, False]
    assert list(shared.main_lights) == [2]
    mean = (4.0 * directions[0] + 2.0 * directions[3]) / np.linalg.norm(4.0 * directions[0] + 2.0 * directions[3])
    np.testing.assert_allclose(dirs[0], mean)
    np.testing.assert_allclose(dirs[3], mean)
    np.testing.assert_array_equal(dirs[[1, 2, 4]], directions[[1, 2, 4]])   # alone, or not sharp: their own

    # With the lights' angular radii: lights 0 and 3 (a degree apart) share only if their discs overlap.
    points, _ = share_sharp_maps(plan, directions, energy, np.radians(2.0), radii=np.full(5, np.radians(0.3)))
    assert list(points.sharp_lights) == [0, 1, 3]                 # 0.3 + 0.3 < 1 degree: a map each
    discs, _ = share_sharp_maps(plan, directions, energy, np.radians(2.0), radii=np.full(5, np.radians(0.6)))
    assert list(discs.sharp_lights) == [0, 1] and list(discs.layer) == list(shared.layer)
    # Members that cancel (opposite, equally bright) leave the map along the brightest light's direction.
    opposite = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    both = plan_layers(np.array([0, 1], np.int32), np.array([True, True]), 4)
    _, dirs = share_sharp_maps(both, opposite, np.array([1.0, 1.0]), np.pi)
    np.testing.assert_array_equal(dirs, [opposite[0], opposite[0]])


def test_a_suns_regions_sharing_one_map_shade_as_with_their_own(renderer, sun_scene, request):
    from renderer.shadows.lights import SMALL_LIGHT_MAX_SIN

    _, pems = sun_scene
    scene = renderer.create_scene([_ball_and_ground()], [Material((0.8, 0.8, 0.8))])
    request.addfinalizer(scene.release)
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    small = np.sin(pems.regions.disc_radius_rad()) <= SMALL_LIGHT_MAX_SIN

    def frame(**kw):
        fs = FrameSettings(160, 160, shadow_size=32, small_light_scale=4, blur_scale=0.0,
                           background=Background.BLACK, **kw)
        f = renderer.render(scene, pems, fs, cam)
        assert np.isfinite(f.image).all()
        return f

    own = frame()
    shared = frame(sharp_share_deg=10.0)     # the sun's disc is 2 degrees in radius: its regions are closer
    assert own.timings["sharp_layers"] == int(small.sum()) >= 2
    assert shared.timings["sharp_layers"] == 1
    # Every light keeps its shadow; the shared map is drawn once.
    assert shared.timings["shadowed_lights"] == own.timings["shadowed_lights"]
    assert shared.timings["shadow_layers"] == own.timings["shadow_layers"] - (int(small.sum()) - 1)
    assert shared.settings["shadow_bytes"] < own.settings["shadow_bytes"]
    lum = [f.image[..., :3].mean(axis=-1) for f in (own, shared)]
    dark = lum[0] < 0.3 * np.percentile(lum[0], 95)
    assert dark.sum() > 100                  # the sphere's shadow is in the image
    # One map along the sun's energy-weighted direction draws that shadow as the regions' own maps do.
    err_shared = np.abs(lum[1] - lum[0]).sum() / lum[0].sum()
    assert err_shared < 0.01, err_shared
    for bad in (-1.0, 31.0, float("nan"), True):
        with pytest.raises(InvalidInputError, match="sharp_share_deg"):
            FrameSettings(sharp_share_deg=bad)


def test_lights_sharing_a_map_look_it_up_through_the_projection_it_was_drawn_with(renderer, sun_scene):
    from renderer.shadows.lights import LIGHT_DTYPE

    scene, pems = sun_scene
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    # A blur: each light's fitted footprint is widened by its own blur width.
    fs = FrameSettings(64, 64, shadow_size=32, small_light_scale=4, blur_scale=1.0, sharp_share_deg=10.0)
    f = renderer.render(scene, pems, fs, cam)
    assert f.timings["sharp_layers"] == 1
    lights = np.frombuffer(renderer._buffers["lights"].read(), LIGHT_DTYPE)[:f.timings["n_lights"]]   # then the block's room
    shared = lights[lights["shadow"][:, 1] > 0.5]
    assert len(shared) >= 2 and np.all(shared["shadow"][:, 0] == 0)
    assert len(np.unique(shared["params"][:, 0])) > 1            # different blur widths...
    assert np.all(shared["view_proj"] == shared["view_proj"][0])  # ... one projection


def test_shadow_bias_is_a_bounded_number_of_texels():
    for name in ("normal_offset_texels", "min_sigma_texels"):
        for good in (0.0, 16.0):
            assert getattr(FrameSettings(**{name: good}), name) == good
        for bad in (-0.5, 16.5, float("nan"), True):
            with pytest.raises(InvalidInputError, match=name):
                FrameSettings(**{name: bad})


def test_each_shadow_bias_knob_reaches_the_shadow_test(renderer, sun_scene):
    _, pems = sun_scene
    # One shadow group, whose shadow on itself the bias decides (between two meshes' groups no bias applies).
    scene = renderer.create_scene([_ball_and_ground()], [Material((0.8, 0.8, 0.8))])
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    try:
        # The sun's map is a main map at scale 1 and a sharp one at scale 4.
        for name, value, scale in (("normal_offset_texels", 8.0, 1), ("min_sigma_texels", 12.0, 1),
                                   ("normal_offset_texels", 8.0, 4)):
            base = FrameSettings(64, 64, shadow_size=64, small_light_scale=scale)
            ref = renderer.render(scene, pems, base, cam).image
            img = renderer.render(scene, pems, dataclasses.replace(base, **{name: value}), cam).image
            assert np.abs(img - ref)[..., :3].max() > 1e-3, name
    finally:
        scene.release()


def test_shadow_size_is_a_whole_number_of_texels_from_16():
    for bad in (0, 8, 15, 256.0, True):
        with pytest.raises(InvalidInputError, match="shadow_size"):
            FrameSettings(shadow_size=bad)



def test_sharp_maps_draw_the_casters_at_full_detail_and_the_main_maps_the_proxy(renderer):
    """A sun's and a lamp's sharp maps both from the full meshes, whatever caster_detail; the main
    maps from the proxy: the frame's triangle count says which were drawn."""
    from renderer.envmap.cube import texel_directions

    d = texel_directions(64)
    cube = np.where(d[..., 1:2] > 0, 0.02, 0.0).astype(np.float32) * np.ones(3, np.float32)
    for direction, radius, radiance in (((0.4, 1.0, 0.3), 1.0, 2e4), ((-0.5, 1.0, -0.2), 4.0, 1e3)):
        s = np.asarray(direction) / np.linalg.norm(direction)
        cube[(d @ s) > np.cos(np.radians(radius))] = radiance
    scene = renderer.create_scene([sphere(0.4, centre=(0.0, 0.8, 0.0), subdivisions=5), plane(3.0)],
                                  [Material((0.5, 0.5, 0.5)), Material((0.8, 0.8, 0.8))])
    pems = renderer.build_pems(cube, PEMSettings(48, whole_sources=True))
    cam = Camera((0.0, 3.0, 2.5), (0.0, 0.2, 0.0), fov_y_deg=50.0)
    try:
        def frame(detail):
            fs = FrameSettings(48, 48, shadow_size=32, small_light_scale=2, small_light_min_energy=1.0,
                               caster_detail=detail)
            f = renderer.render(scene, pems, fs, cam)
            return f, renderer._shadow_maps["sharp"].read().copy()

        (full, m_full), (coarse, m_coarse) = frame(1.0), frame(0.25)
        full_tris = scene.meshes[0].shadow_triangles(1.0) + scene.meshes[1].shadow_triangles(1.0)
        proxy_tris = scene.meshes[0].shadow_triangles(0.25) + scene.meshes[1].shadow_triangles(0.25)
    finally:
        pems.release()
        scene.release()
    radius = np.degrees(pems.regions.disc_radius_rad())
    relative = pems.regions.energy_luminance / pems.regions.energy_luminance.mean()
    sharp = (np.sin(np.radians(radius)) <= SMALL_LIGHT_MAX_SIN) & (relative >= 1.0)
    assert (sharp & (radius <= 2.0)).any() and (sharp & (radius > 2.0)).any()   # the sun's and the lamp's
    n_sharp = coarse.timings["sharp_layers"]
    assert n_sharp == full.timings["sharp_layers"] == m_full.shape[0] >= 2
    np.testing.assert_array_equal(m_coarse, m_full)            # the sharp maps never see the proxy
    n_main = coarse.timings["shadowed_lights"] - int(sharp.sum())
    assert proxy_tris < full_tris
    assert coarse.timings["shadow_triangles"] == n_sharp * full_tris + n_main * proxy_tris

