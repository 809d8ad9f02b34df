"""The GPU PEM build against the numpy reference, and its invariants."""

import numpy as np
import pytest

from renderer.lighting.filters import Filter, taps_1d
from renderer.lighting.pem import PEMSettings
from renderer.lighting.pem_reference import pem_chain

from conftest import sun_sky_cube

HALF_EPS = 2.0**-10  # relative precision of RGBA16F storage


@pytest.mark.parametrize("kind", list(Filter))
def test_taps_are_normalized_and_symmetric(kind):
    t = taps_1d(kind)
    assert t.sum() == pytest.approx(1.0)
    assert np.allclose(t, t[::-1]) and (t >= 0).all()


@pytest.mark.parametrize("kind", [Filter.SQRT_COSINE, Filter.BOX, Filter.NONE])
def test_gpu_chain_matches_numpy_reference_per_region(renderer, kind):
    rng = np.random.default_rng(3)
    cube = (rng.random((6, 16, 16, 3)) ** 4 * 5).astype(np.float32)
    pems = renderer.build_pems(cube, PEMSettings(24, kind))
    try:
        for region in (0, 7, 23):
            masked = np.where((pems.regions.labels == region)[..., None], cube, 0.0)
            ref = pem_chain(masked, kind)
            assert len(ref) == pems.levels
            for level, expect in enumerate(ref):
                got = pems.read_level(level)[region]
                tol = 2 * HALF_EPS * max(float(pems.scale[region]), 1e-30)
                np.testing.assert_allclose(got, expect, atol=tol, err_msg=f"region {region} level {level}")
    finally:
        pems.release()


@pytest.mark.parametrize("n_lights", [6, 48, 384])
def test_pems_sum_to_the_filtered_full_map_at_every_level(renderer, n_lights):
    cube = sun_sky_cube(32, (1, 1, 0.3), sun_radiance=5e3)
    pems = renderer.build_pems(cube, PEMSettings(n_lights))
    try:
        ref = pem_chain(cube, Filter.SQRT_COSINE)
        for level in range(pems.levels):
            total = pems.read_level(level).astype(np.float64).sum(axis=0)
            # Each region is stored with its own scale, so the error bound is per region, summed.
            tol = 2 * HALF_EPS * pems.scale.sum() / np.sqrt(n_lights) + 1e-6
            np.testing.assert_allclose(total, ref[level], atol=tol, err_msg=f"level {level}")
    finally:
        pems.release()


def test_sun_beyond_half_float_range_stays_finite(renderer):
    # A 1e6 sun overflows RGBA16F (max 65504) unless regions are stored scaled.
    cube = sun_sky_cube(32, (0.2, 1, 0.1), sun_radiance=1e6, sun_radius_deg=2)
    pems = renderer.build_pems(cube, PEMSettings(48))
    try:
        for level in range(pems.levels):
            data = pems.read_level_raw(level)
            assert np.isfinite(data).all() and data.max() <= 1.0 + HALF_EPS
        total0 = pems.read_level(0).sum(axis=0)
        assert total0.max() == pytest.approx(1e6, rel=HALF_EPS)
    finally:
        pems.release()


def test_memory_matches_the_paper_figure_8(renderer):
    # Paper Fig. 8: 48 PEMs of 128^2 faces, RGBA16F with MIP maps, take 48 MB.
    pems = renderer.build_pems(np.ones((6, 128, 128, 3), np.float32), PEMSettings(48))
    try:
        assert pems.nbytes / 2**20 == pytest.approx(48.0, rel=0.01)
    finally:
        pems.release()


def test_build_is_deterministic(renderer):
    cube = sun_sky_cube(16, (0, 1, 1))
    a = renderer.build_pems(cube, PEMSettings(12))
    b = renderer.build_pems(cube, PEMSettings(12))
    try:
        for level in range(a.levels):
            assert np.array_equal(a.read_level_raw(level), b.read_level_raw(level))
    finally:
        a.release()
        b.release()


def test_exported_set_restores_bit_identical_without_rebuilding(renderer, tmp_path):
    cube = sun_sky_cube(16, (1, 1, 0), sun_radiance=1e5)
    built = renderer.build_pems(cube, PEMSettings(24))
    path = tmp_path / "pems.npz"
    np.savez(path, **built.export())
    with np.load(path) as stored:
        restored = type(built)(renderer.gl, cube, PEMSettings(24), stored=dict(stored))
    try:
        for level in range(built.levels):
            assert np.array_equal(built.read_level_raw(level), restored.read_level_raw(level))
        assert np.array_equal(built.scale, restored.scale)
        assert np.array_equal(built.regions.labels, restored.regions.labels)
    finally:
        built.release()
        restored.release()


@pytest.mark.parametrize("where", ["face centre", "edge", "corner"])
def test_solid_angle_weighting_keeps_a_small_light_energy_wherever_it_sits(where):
    # A one-texel light's energy after filtering, relative to its own, at every level. The unweighted
    # texel-space chain keeps 39 % of a face-centre light and gives a corner light 2.3x its energy at a
    # 64^2 map's deep levels (measured); the solid-angle weighted chain stays within [0.6, 1.2].
    from renderer.envmap.cube import texel_solid_angles
    from renderer.lighting.pem_reference import unweighted_chain

    n = 64
    row, col = {"face centre": (n // 2, n // 2), "edge": (0, n // 2), "corner": (0, 0)}[where]
    impulse = np.zeros((6, n, n, 1))
    impulse[4, row, col] = 1.0
    own = texel_solid_angles(n)[row, col]

    def energies(chain):
        return np.array([(lv[..., 0] * texel_solid_angles(lv.shape[1])[None]).sum() / own for lv in chain])

    weighted = energies(pem_chain(impulse, Filter.SQRT_COSINE))
    plain = energies(unweighted_chain(impulse, Filter.SQRT_COSINE))
    assert weighted[0] == pytest.approx(1.0)
    assert np.all((weighted > 0.6) & (weighted < 1.2)), weighted
    assert np.abs(np.log(weighted)).max() < np.abs(np.log(plain)).max(), (weighted, plain)


def test_weighted_chain_keeps_a_constant_map_constant():
    cube = np.full((6, 32, 32, 3), 2.5)
    for level in pem_chain(cube, Filter.SQRT_COSINE):
        np.testing.assert_allclose(level, 2.5, rtol=1e-12)
