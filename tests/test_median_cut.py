import numpy as np
import pytest
from conftest import sun_sky_cube
from hypothesis import given, settings
from hypothesis import strategies as st

from renderer.envmap.cube import cube_solid_angles, dir_to_texel
from renderer.errors import InvalidInputError
from renderer.lighting.median_cut import LUMINANCE_RGB, median_cut, median_cut_to, sub_lights


def _covered_once(rs, n):
    count = np.zeros((6, n, n), int)
    for face, r0, r1, c0, c1 in rs.rects:
        count[face, r0:r1, c0:c1] += 1
    return count


@settings(max_examples=25, deadline=None)
@given(k=st.integers(0, 5), n=st.sampled_from([8, 16, 32]), seed=st.integers(0, 2**31), power=st.floats(0, 12),
       whole_sources=st.booleans())
def test_partition_covers_every_texel_exactly_once(k, n, seed, power, whole_sources):
    n_lights = 6 * 2**k
    cube = (np.random.default_rng(seed).random((6, n, n, 3)) ** power).astype(np.float32)
    rs = median_cut(cube, n_lights, whole_sources)
    assert rs.n_regions == n_lights
    assert (_covered_once(rs, n) == 1).all()  # Eq. 1: union is the map, regions are disjoint
    assert set(np.unique(rs.labels)) == set(range(n_lights))
    # The labels and the rectangles describe the same partition.
    for rid, (face, r0, r1, c0, c1) in enumerate(rs.rects):
        assert (rs.labels[face, r0:r1, c0:c1] == rid).all()
    omega = cube_solid_angles(n)
    assert rs.solid_angle_sr.sum() == pytest.approx(4 * np.pi)
    assert rs.energy_rgb.sum(axis=0) == pytest.approx((cube * omega[..., None]).sum(axis=(0, 1, 2)), rel=1e-9)
    assert np.allclose(np.linalg.norm(rs.directions, axis=1), 1.0)


@settings(max_examples=25, deadline=None)
@given(count=st.integers(6, 100), n=st.sampled_from([8, 16]), seed=st.integers(0, 2**31), power=st.floats(0, 12),
       whole_sources=st.booleans())
def test_any_region_count_is_a_partition_that_halves_the_most_energetic_regions(count, n, seed, power,
                                                                                 whole_sources):
    cube = (np.random.default_rng(seed).random((6, n, n, 3)) ** power).astype(np.float32)
    rs = median_cut_to(cube, count, whole_sources)
    assert rs.n_regions == count and (_covered_once(rs, n) == 1).all()
    assert set(np.unique(rs.labels)) == set(range(count))
    for rid, (face, r0, r1, c0, c1) in enumerate(rs.rects):
        assert (rs.labels[face, r0:r1, c0:c1] == rid).all()
    omega = cube_solid_angles(n)
    assert rs.energy_rgb.sum(axis=0) == pytest.approx((cube * omega[..., None]).sum(axis=(0, 1, 2)), rel=1e-9)
    base_count = 6 * 2 ** ((count // 6).bit_length() - 1)
    base = median_cut(cube, base_count, whole_sources)
    if count == base_count:   # the median cut itself
        np.testing.assert_array_equal(rs.labels, base.labels)
        return
    # Each base region is kept or halved; the halved ones are the most energetic (among those of more
    # than one texel).
    lum = base.energy_rgb @ LUMINANCE_RGB
    halved = np.array([not np.array_equal(rs.rects[i], base.rects[i]) for i in range(base_count)])
    assert halved.sum() == count - base_count
    sizes = np.array([(r[2] - r[1]) * (r[4] - r[3]) for r in base.rects])
    assert lum[halved].min() >= lum[~halved & (sizes > 1)].max(initial=0.0)
    new = []
    for i in np.nonzero(halved)[0]:
        (kept, added) = np.unique(rs.labels[base.labels == i])
        assert kept == i and added >= base_count
        new.append(added)
    assert sorted(new) == list(range(base_count, count))


def test_regions_of_a_face_hold_equal_energy_and_lights_sit_in_their_regions():
    n = 64
    cube = sun_sky_cube(n, (1, 2, 0.5), sun_radiance=50.0, sun_radius_deg=10)
    rs = median_cut(cube, 96)
    per_face = rs.energy_luminance.reshape(6, 16)
    # Energy halves at every cut up to the granularity of one texel row.
    for face in range(6):
        e = per_face[face]
        assert e.max() <= 2.5 * e.min() + 1e-9, (face, e)
    face, row, col = dir_to_texel(rs.directions, n)
    assert (rs.labels[face, row, col] == np.arange(96)).all()


def test_bright_areas_get_small_regions():
    cube = sun_sky_cube(64, (0, 0, 1), sun_radiance=1e4, sun_radius_deg=4)
    rs = median_cut(cube, 48)
    sun_regions = rs.rects[:, 0] == 4  # the +Z face holds the sun
    assert rs.solid_angle_sr[sun_regions].min() < 0.2 * rs.solid_angle_sr[~sun_regions].min()


def _sun_share_of_regions(rs, cube, sun):
    """Each region's share of the sun's energy (the texels brighter than the sky), largest first."""
    omega = cube_solid_angles(cube.shape[1])
    e = np.where(sun, cube @ LUMINANCE_RGB * omega, 0.0)
    per_region = np.bincount(rs.labels.ravel(), e.ravel(), minlength=rs.n_regions)
    return np.sort(per_region)[::-1] / per_region.sum()


def test_whole_sources_keeps_a_sun_in_one_region():
    # A sun on the middle of the +Z face: the plain median cut's first cut of that face passes through it.
    cube = sun_sky_cube(64, (0, 0, 1), sun_radiance=1e4, sun_radius_deg=3)
    sun = cube[..., 0] > 100
    assert _sun_share_of_regions(median_cut(cube, 48), cube, sun)[0] < 0.5                      # in pieces
    assert _sun_share_of_regions(median_cut(cube, 48, whole_sources=True), cube, sun)[0] > 0.999  # whole


def test_whole_sources_leaves_no_part_of_a_sun_to_a_distant_light():
    # A small sun with a halo (1 degree Gaussian) in 20 random directions: the plain cut leaves parts
    # of it in large regions whose light sits at their energy centroid, degrees away from the sun.
    from renderer.envmap.cube import texel_directions

    n = 64
    d, omega = texel_directions(n), cube_solid_angles(n)
    rng = np.random.default_rng(1)
    far = {False: [], True: []}
    for _ in range(20):
        s = rng.normal(size=3)
        s /= np.linalg.norm(s)
        sun = 1e4 * np.exp(-0.5 * np.degrees(np.arccos(np.clip(d @ s, -1.0, 1.0))) ** 2)
        cube = (np.where(d[..., 1:2] > 0, [0.2, 0.3, 0.5], [0.1, 0.1, 0.1]) + sun[..., None]).astype(np.float32)
        for whole in far:
            rs = median_cut(cube, 48, whole_sources=whole)
            angle = np.degrees(np.arccos(np.clip((rs.directions[rs.labels] * d).sum(-1), -1.0, 1.0)))
            far[whole].append((sun * omega)[angle > 4.0].sum() / (sun * omega).sum())
    # The share of the sun's energy whose light is more than 4 degrees away (measured: plain 4.8 %
    # on average, 15 % at worst; whole 0.5 % and 2 %).
    assert np.mean(far[True]) < 0.25 * np.mean(far[False])
    assert max(far[True]) < 0.05 < max(far[False])


def _moved(profile, split):
    from renderer.lighting.median_cut import _beside_source

    p = np.asarray(profile, np.float64)
    return _beside_source(p, np.cumsum(p), split)


def test_a_cut_through_a_compact_source_moves_to_its_nearer_edge_and_only_then():
    sky = np.ones(32)
    spike = sky.copy()
    spike[15:17] = 60.0                  # two rows, 80 % of the energy: the median cut passes between them
    assert _moved(spike, 16) in (15, 17)
    off_centre = sky.copy()
    off_centre[20:22] = 60.0
    assert _moved(off_centre, 21) == 20  # the nearer edge in energy: rows 0..19 hold less than half
    wide = sky.copy()
    wide[11:21] = 12.0                   # ten rows (more than an eighth of 32): a bright area, not a source
    assert _moved(wide, 16) == 16
    weak = sky.copy()
    weak[15:17] = 6.0                    # compact but under half the region's energy
    assert _moved(weak, 16) == 16
    beside = sky.copy()
    beside[3:5] = 60.0                   # a source away from the cut line is not the cut's business
    assert _moved(beside, 16) == 16


@settings(max_examples=200, deadline=None)
@given(profile=st.lists(st.floats(0.0, 1e6), min_size=2, max_size=40), frac=st.floats(0.0, 1.0))
def test_a_moved_cut_never_empties_a_side(profile, frac):
    if sum(profile) <= 0:
        return
    split = min(max(int(frac * len(profile)), 1), len(profile) - 1)
    assert 1 <= _moved(profile, split) <= len(profile) - 1


def test_whole_sources_leaves_a_map_without_compact_sources_alone():
    from renderer.envmap.cube import texel_directions

    d = texel_directions(32)
    sky = (1.0 + 2.0 * np.clip(d[..., 1:2], 0, 1) + 0.5 * d[..., 0:1] ** 2) * np.array([0.3, 0.4, 0.6])
    cube = sky.astype(np.float32)
    for n_lights in (6, 48, 384):
        assert (median_cut(cube, n_lights, whole_sources=True).labels == median_cut(cube, n_lights).labels).all()


@pytest.mark.parametrize("bad", [0, 5, 7, 18, 30, -6])
def test_light_count_must_be_6_times_power_of_two(bad):
    with pytest.raises(InvalidInputError, match="6 \\* 2\\^k"):
        median_cut(np.ones((6, 8, 8, 3), np.float32), bad)


def test_too_many_lights_for_face_size_is_an_error():
    with pytest.raises(InvalidInputError, match="face"):
        median_cut(np.ones((6, 4, 4, 3), np.float32), 6 * 32)


def test_black_map_gives_geometric_partition():
    rs = median_cut(np.zeros((6, 16, 16, 3), np.float32), 24)
    assert (_covered_once(rs, 16) == 1).all()
    assert np.all(rs.energy_rgb == 0)
    assert np.allclose(rs.solid_angle_sr, 4 * np.pi / 24, rtol=0.3)
    assert LUMINANCE_RGB.sum() == pytest.approx(1.0, abs=1e-4)


def test_light_spread_follows_the_energy_not_the_region_outline():
    # A 2-degree sun inside a large, otherwise black region: the light is as small as the sun.
    cube = sun_sky_cube(128, (0.1, 0.2, 1.0), sun_radiance=1e4, sun_radius_deg=2, sky=(0, 0, 0), ground=(0, 0, 0))
    rs = median_cut(cube, 6)
    sun = int(np.argmax(rs.energy_luminance))
    assert rs.angular_radius_rad()[sun] > np.radians(30)
    assert rs.light_radius_rad()[sun] == pytest.approx(np.radians(2), rel=0.25)


@settings(max_examples=20, deadline=None)
@given(k=st.integers(0, 3), per=st.sampled_from([1, 2, 4, 8, 16]), n=st.sampled_from([4, 8, 16]), seed=st.integers(0, 2**31),
       power=st.floats(0, 12), whole_sources=st.booleans())
def test_sub_lights_split_each_region_and_keep_its_energy(k, per, n, seed, power, whole_sources):
    cube = (np.random.default_rng(seed).random((6, n, n, 3)) ** power).astype(np.float32)
    rs = median_cut(cube, 6 * 2**k, whole_sources)
    sub = sub_lights(cube, rs, per, whole_sources)
    assert sub.directions.shape == (rs.n_regions * per, 3) and sub.energy_rgb.shape == (rs.n_regions * per, 3)
    np.testing.assert_allclose(np.linalg.norm(sub.directions, axis=1), 1.0, rtol=1e-12)
    assert np.isfinite(sub.disc_radius_rad).all() and (sub.disc_radius_rad >= 0).all()
    # A region's discs carry its energy between them, whatever the padding of a one-texel region.
    np.testing.assert_allclose(sub.energy_rgb.reshape(rs.n_regions, per, 3).sum(axis=1), rs.energy_rgb,
                               rtol=1e-9, atol=1e-12 * max(rs.energy_rgb.max(), 1e-300))
    if per == 1:   # one disc per region: the region's own light
        np.testing.assert_allclose(sub.directions, rs.directions, atol=1e-12)
        np.testing.assert_allclose(sub.disc_radius_rad, rs.disc_radius_rad(), atol=1e-9)


def test_sub_lights_sit_where_their_part_of_the_region_is():
    # A region lit blue in one half and green in the other (the same luminance): its two discs take
    # the colours apart, and together they keep the region's energy-weighted direction.
    n = 16
    cube = np.zeros((6, n, n, 3), np.float32)
    cube[:, : n // 2] = (0.0, 0.0, 1.0 / LUMINANCE_RGB[2])
    cube[:, n // 2:] = (0.0, 1.0 / LUMINANCE_RGB[1], 0.0)
    rs = median_cut(cube, 6)
    sub = sub_lights(cube, rs, 2)
    for face in range(6):
        a, b = sub.energy_rgb[2 * face], sub.energy_rgb[2 * face + 1]
        assert (a[2] > 4 * a[1] and b[1] > 4 * b[2]) or (b[2] > 4 * b[1] and a[1] > 4 * a[2])
        mean = (sub.directions[2 * face:2 * face + 2] * (sub.energy_rgb[2 * face:2 * face + 2] @ LUMINANCE_RGB)[:, None]).sum(0)
        assert np.degrees(np.arccos(np.clip(mean / np.linalg.norm(mean) @ rs.directions[face], -1, 1))) < 3.0
    assert (sub.disc_radius_rad < rs.disc_radius_rad().repeat(2)).all()   # each half is the narrower disc


@pytest.mark.parametrize("bad", [0, 3, 6, -2])
def test_sub_lights_per_region_must_be_a_power_of_two(bad):
    cube = np.ones((6, 8, 8, 3), np.float32)
    with pytest.raises(InvalidInputError, match="power of two"):
        sub_lights(cube, median_cut(cube, 6), bad)


def test_a_pem_sets_median_cut_takes_any_count_and_is_the_uniform_cut_at_6_times_a_power_of_two():
    """light_regions (what a PEM set's regions come from) with lights_from median-cut: median_cut_to,
    so a preset may name 16 or 18 lights; at 6 * 2^k the paper's uniform cut, label for label."""
    from renderer.lighting.area_lights import light_regions

    cube = (np.random.default_rng(3).random((6, 16, 16, 3)) ** 6).astype(np.float32)
    for count in (16, 18, 20):
        rs = light_regions(cube, count, True, "median-cut")
        assert rs.n_regions == count and set(np.unique(rs.labels)) == set(range(count))
    np.testing.assert_array_equal(light_regions(cube, 24, True, "median-cut").labels, median_cut(cube, 24, True).labels)
