"""Arbree, Walter and Bala's light finding (renderer/lighting/area_lights.py): discs on black, the
Weber stop, energy conservation, a uniform map, a sun on a sky."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import balanced, balanced_pems, sun_sky_cube

from renderer.envmap.cube import cube_solid_angles, texel_directions
from renderer.lighting.area_lights import INNER_RATIO, decompose, outer_radii
from renderer.lighting.median_cut import LUMINANCE_RGB

N = 128


def _discs(specs, n=N, background=0.0):
    """A cube with uniform discs (direction, radius in degrees, radiance) on a constant background;
    returns the cube and each disc's energy (radiance times its texels' solid angle)."""
    d = texel_directions(n)
    cube = np.full((6, n, n, 3), background)
    energies = []
    for direction, radius_deg, radiance in specs:
        u = np.asarray(direction, float) / np.linalg.norm(direction)
        inside = d @ u >= np.cos(np.radians(radius_deg))
        cube[inside] += radiance
        energies.append(float(cube_solid_angles(n)[inside].sum() * radiance))
    return cube, energies


DISCS = [((1, 1, 0), 5.0, 100.0), ((-1, 0.3, 0.2), 10.0, 20.0), ((0, -0.5, -1), 3.0, 500.0)]


def test_separated_discs_on_black_are_found_at_their_centres_with_their_energies():
    cube, energies = _discs(DISCS)
    dec = decompose(cube)
    assert len(dec.lights) == len(DISCS)
    bank = INNER_RATIO * outer_radii()
    for (direction, radius_deg, _), energy in zip(DISCS, energies):
        u = np.asarray(direction, float) / np.linalg.norm(direction)
        light = max(dec.lights, key=lambda lt: float(np.dot(lt.direction, u)))
        # Within a search texel (1.4 degrees at 64^2 faces) of the centre; the whole disc's energy;
        # the bank's smallest inner radius that holds the disc plus a search texel.
        assert np.degrees(np.arccos(min(1.0, float(np.dot(light.direction, u))))) < 1.5
        assert light.energy_rgb[0] == pytest.approx(energy, rel=1e-6)
        assert np.radians(radius_deg) <= light.radius_rad <= bank[np.searchsorted(bank, np.radians(radius_deg + 1.5))]
    assert dec.ambient_share == pytest.approx(0.0, abs=1e-12)


def test_the_weber_stop_leaves_out_a_disc_at_one_percent_of_the_others():
    cube, energies = _discs(DISCS[:2])
    total = sum(energies)
    faint = ((0.0, 1.0, 0.0), 4.0, 1.0)
    _, (e_faint,) = _discs([faint])
    scale = 0.01 * total / e_faint
    cube, _ = _discs(DISCS[:2] + [(faint[0], faint[1], scale)])
    dec = decompose(cube)
    assert len(dec.lights) == 2 and dec.stopped_by == "weber"
    # At 3 % it is a light.
    cube, _ = _discs(DISCS[:2] + [(faint[0], faint[1], 3.0 * scale)])
    assert len(decompose(cube).lights) == 3


@pytest.mark.parametrize("cube", [
    _discs(DISCS, background=0.3)[0],
    sun_sky_cube(N, (1, 1, 0.5), sun_radiance=300.0, sun_radius_deg=2),
], ids=["discs-on-grey", "sun-on-sky"])
def test_lights_and_ambient_are_the_map(cube):
    dec = decompose(cube)
    omega = cube_solid_angles(N)[..., None]
    total = (cube * omega).reshape(-1, 3).sum(axis=0)
    found = np.sum([lt.energy_rgb for lt in dec.lights], axis=0) + (dec.ambient * omega).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(found, total, rtol=1e-5)
    assert sum(lt.share for lt in dec.lights) + dec.ambient_share == pytest.approx(1.0, abs=1e-5)


def test_a_uniform_map_has_no_area_light():
    dec = decompose(np.full((6, N, N, 3), 0.7))
    assert dec.lights == () and dec.ambient_share == pytest.approx(1.0) and dec.stopped_by == "no response"


def test_a_sun_gives_one_small_light_where_it_is():
    sun = np.array([1.0, 1.0, 0.5]) / np.linalg.norm([1.0, 1.0, 0.5])
    dec = decompose(sun_sky_cube(N, sun, sun_radiance=300.0, sun_radius_deg=2))
    assert len(dec.lights) == 1
    (light,) = dec.lights
    assert np.degrees(light.radius_rad) < 6.0
    assert np.degrees(np.arccos(min(1.0, float(np.dot(light.direction, sun))))) < 1.5
    assert light.share > 0.2
    lum = float(np.asarray(light.energy_rgb) @ LUMINANCE_RGB)
    assert lum == pytest.approx(light.share * dec.total_luminance, rel=1e-9)


@pytest.mark.parametrize("per_region", [1, 2])
def test_an_area_lights_closed_form_disc_is_where_its_light_is(per_region):
    # A half-degree sun is found as a disc of a few degrees (the smallest filter is 4.5 degrees): the
    # glossy term's discs (sub_lights) must keep the sun's own direction and half-degree radius, as
    # the median cut's region around it does, or a glossy floor's highlight is spread over the disc.
    from renderer.lighting.area_lights import area_regions
    from renderer.lighting.median_cut import median_cut, sub_lights

    sun = np.array([0.0, np.sin(0.6), -np.cos(0.6)])
    cube = sun_sky_cube(N, sun, sun_radiance=1e5, sun_radius_deg=0.5)
    area, _ = area_regions(cube, 48)
    assert area.area_mask.sum() == 1
    for regions in (area, median_cut(cube[..., :3], 48, True)):
        sub = sub_lights(cube[..., :3], regions, per_region, True)
        i = int(np.argmax(sub.energy_rgb @ LUMINANCE_RGB))
        assert np.degrees(np.arccos(min(1.0, float(sub.directions[i] @ sun)))) < 0.3   # texels of 0.7 degrees
        assert 0.4 < np.degrees(sub.disc_radius_rad[i]) < 0.7


def test_an_area_pem_set_has_a_region_per_light_and_keeps_the_energy(renderer):
    from renderer.lighting.pem import PEMSet, PEMSettings

    cube, energies = _discs(DISCS[:2], n=64, background=0.2)
    settings = balanced_pems(lights=24, lights_from="area")
    pems = renderer.build_pems(cube.astype(np.float32), settings)
    try:
        regions = pems.regions
        assert regions.area.sum() == 2 and regions.n_regions == 24   # the remainder takes the other 22
        omega = cube_solid_angles(64)[..., None]
        np.testing.assert_allclose(regions.energy_rgb.sum(axis=0), (cube * omega).reshape(-1, 3).sum(axis=0), rtol=1e-5)
        s = pems.summary()
        assert s["lights_from"] == "area" and len(s["area_lights"]) == 2
        assert s["ambient_share"] == pytest.approx(1.0 - sum(x["energy_share"] for x in s["area_lights"]), abs=1e-4)
        # The closed forms' discs: an area light is one, the remainder's regions are cut without it.
        discs = np.frombuffer(pems.sub_lights_bytes(2), np.float32).reshape(-1, 2, 4)
        np.testing.assert_allclose(discs[:, 1, :3].sum(axis=0), regions.energy_rgb.sum(axis=0), rtol=1e-4)
        # A stored set comes back with its area lights.
        restored = PEMSet(renderer.gl, cube.astype(np.float32), settings, stored=dict(pems.export()))
        try:
            np.testing.assert_array_equal(restored.regions.area, regions.area)
            np.testing.assert_array_equal(restored.regions.labels, regions.labels)
        finally:
            restored.release()
    finally:
        pems.release()
    assert PEMSettings(lights_from="area").key() != PEMSettings().key()


def test_a_frame_lit_by_area_lights_matches_the_reference(renderer):
    """Two discs over a dim grey map: the area decomposition's frame against the Monte Carlo
    reference of the same map, as close as the median cut's at the same light budget. Measured:
    0.107 with 14 lights (2 discs + 12 remainder regions) against the median cut's 0.165 with 24
    (the reference's noise floor 0.07)."""
    from conftest import CAM, sphere

    from renderer.reference import relative_rmse, render_reference
    from renderer.shading.material import Material

    cube, _ = _discs([((1, 1, 1), 8.0, 40.0), ((-1, 0.6, 0.3), 12.0, 10.0)], n=64, background=0.1)
    cube = cube.astype(np.float32)
    material = Material((0.7, 0.6, 0.5), 0.2, 0.6)
    floor = _plane()
    ref = render_reference([sphere(), floor], [material, Material((0.5, 0.5, 0.5))], cube, CAM, 48, 48, spp=64)
    errors = {}
    for lights_from in ("median-cut", "area"):
        pems = renderer.build_pems(cube, balanced_pems(lights=24, lights_from=lights_from))
        scene = renderer.create_scene([sphere(), floor], [material, Material((0.5, 0.5, 0.5))])
        try:
            frame = renderer.render(scene, pems, balanced(48, 48), CAM)
            assert frame.settings["pems"]["lights_from"] == lights_from
            errors[lights_from] = relative_rmse(frame.image, ref.image)
        finally:
            scene.release()
            pems.release()
    assert errors["area"] < 0.25 and errors["area"] < 1.5 * errors["median-cut"], errors


def _plane():
    from renderer.mesh import Mesh

    p = np.array([[-1.5, -0.5, -1.5], [1.5, -0.5, -1.5], [1.5, -0.5, 1.5], [-1.5, -0.5, 1.5]])
    return Mesh.from_arrays(p, np.array([[0, 2, 1], [0, 3, 2]]), name="floor")


def test_the_area_lights_command_reports_and_previews_a_map(tmp_path):
    from conftest import asset

    from renderer.cli import main

    path = asset("hdri", "openexr_StageEnvLatLong.exr")
    assert main(["area-lights", "--env", str(path), "--face-size", "64", "--out", str(tmp_path)]) == 0
    import json

    rep = json.loads((tmp_path / "area_lights.json").read_text())["openexr_StageEnvLatLong.exr"]
    assert rep["lights"] and 0.0 < rep["ambient_share"] < 1.0
    assert rep["ambient_share"] + sum(x["energy_share"] for x in rep["lights"]) == pytest.approx(1.0, abs=1e-3)
    assert (tmp_path / "openexr_StageEnvLatLong.png").stat().st_size > 10_000


def test_auto_takes_area_lights_where_none_is_too_wide_and_the_budget_holds():
    from renderer.lighting.area_lights import MAX_PIECE_RADIUS_DEG, area_regions, auto_regions

    discs, _ = _discs(DISCS, n=64, background=0.05)
    regions, dec, used = auto_regions(discs, 24)
    assert used == "area" and regions.area.sum() == 3
    # A window-sized source (a 25 degree disc): wider than the limit, so the median cut.
    window, _ = _discs([((0, 0.2, 1), 25.0, 20.0)], n=64, background=0.05)
    regions, dec, used = auto_regions(window, 24)
    assert max(np.degrees(lt.radius_rad) for lt in dec.lights) > MAX_PIECE_RADIUS_DEG
    assert used == "median-cut" and regions.area is None and regions.n_regions == 24
    # No light at all (a uniform map): the median cut.
    regions, dec, used = auto_regions(np.ones((6, 64, 64, 3)), 24)
    assert used == "median-cut" and regions.area is None and regions.n_regions == 24
    # Twelve discs and a budget of 12: the six remainder regions leave room for the six strongest.
    many = [((np.cos(a), 0.3 * np.sin(3 * a), np.sin(a)), 4.0, 50.0 + 10 * k)
            for k, a in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False))]
    regions, dec = area_regions(_discs(many, n=64)[0], 12)
    assert regions.n_regions == 12 and regions.area.sum() == 6 and dec.stopped_by == "max lights"


@pytest.mark.parametrize("radiance", [20.0, 0.5])
def test_a_wide_light_is_cut_into_pieces_no_wider_than_the_limit_each_with_its_shadow(radiance):
    """A window found as one light wider than the limit becomes as many regions as the median cut
    would give its energy (its share of the budget), at least ceil((radius / limit)^2), within the
    budget: each piece of its disc a region of its own (its own shadow map), together the light's
    texels and energy."""
    from renderer.lighting.area_lights import INNER_RATIO, MAX_PIECE_RADIUS_DEG, MIN_OUTER_DEG, area_regions

    window, _ = _discs([((0, 0.2, 1), 25.0, radiance)], n=64, background=0.05)
    regions, dec = area_regions(window, 24)
    (light,) = dec.lights
    by_width = int(np.ceil((light.radius_rad / np.radians(MAX_PIECE_RADIUS_DEG)) ** 2))
    by_energy = min(round(light.share * 24), int((np.degrees(light.radius_rad) / (MIN_OUTER_DEG * INNER_RATIO)) ** 2))
    pieces = min(max(by_width, by_energy), 24 - 6)
    assert pieces >= 2 and regions.area.sum() == pieces and regions.n_regions == 24
    area_ids = np.flatnonzero(regions.area)
    taken = np.isin(regions.labels, area_ids)
    np.testing.assert_array_equal(taken, dec.owner == 0)   # the pieces are the light's disc, no more
    omega = cube_solid_angles(64)
    lum = window @ LUMINANCE_RGB
    assert regions.energy_luminance[area_ids].sum() == pytest.approx(float((lum * omega)[taken].sum()), rel=1e-9)
    # Each piece is narrower than the light, and they sit apart across it.
    assert np.all(regions.disc_radius_rad()[area_ids] < light.radius_rad)
    cos = regions.directions[area_ids] @ regions.directions[area_ids].T
    assert cos[~np.eye(pieces, dtype=bool)].max() < np.cos(np.radians(3.0))
    # A light within the limit stays one region.
    small, _ = _discs([((0, 0.2, 1), 10.0, 20.0)], n=64, background=0.05)
    assert area_regions(small, 24)[0].area.sum() == 1


def test_the_edge_table_counts_edges_above_a_cosine_as_a_search_does():
    """The table that bins texels by their angle to a candidate gives np.searchsorted's count for
    every float32 cosine, the edges themselves and their float32 neighbours included."""
    from renderer.lighting.area_lights import _EdgeTable

    radii = np.concatenate([INNER_RATIO * outer_radii(), outer_radii()])
    edges = np.cos(np.sort(radii))
    rng = np.random.default_rng(3)
    near = edges.astype(np.float32)
    cos = np.concatenate([rng.uniform(edges[-1], 1.0, 200_000).astype(np.float32), near,
                          np.nextafter(near, np.float32(1)), np.nextafter(near, np.float32(0)),
                          np.float32([1.0, np.nextafter(np.float32(1), np.float32(2))])])
    cos = cos[cos > edges[-1]]
    assert np.array_equal(_EdgeTable(edges)(cos), np.searchsorted(-edges, -cos, side="left"))


def test_the_tiled_search_sums_what_comparing_every_texel_sums(monkeypatch):
    """The first search compares each group of candidates with the tiles within reach of it alone; its
    integrals are those of comparing every candidate with every texel (to rounding), on a sun-and-sky
    map and on discs, so the lights found are the same."""
    import renderer.lighting.area_lights as area

    for cube in (sun_sky_cube(64, (0.3, 0.8, 0.5)), _discs(DISCS, n=64, background=0.05)[0]):
        lum = cube @ LUMINANCE_RGB
        tiled = area._Search(lum)
        monkeypatch.setattr(area, "_TILED_PAIRS", np.inf)
        whole = area._Search(lum)
        monkeypatch.undo()
        assert len(tiled.candidates) > 1000
        np.testing.assert_allclose(tiled.inner, whole.inner, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(tiled.outer_sum, whole.outer_sum, rtol=1e-12, atol=1e-15)
        assert tiled.best()[:2] == whole.best()[:2]
