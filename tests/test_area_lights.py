"""Arbree, Walter and Bala's light finding (renderer/lighting/area_lights.py): discs on black, the
Weber stop, energy conservation, a uniform map, a sun on a sky."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import sun_sky_cube

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
