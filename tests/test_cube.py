import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from renderer.envmap.cube import (
    cube_solid_angles,
    dir_to_face_uv,
    dir_to_texel,
    face_uv_to_dir,
    neighbour_texel,
    sample_bilinear,
    texel_directions,
)


@pytest.mark.parametrize("n", [1, 2, 3, 16, 128, 1024])
def test_texel_solid_angles_sum_to_4pi(n):
    assert cube_solid_angles(n).sum() == pytest.approx(4 * np.pi, rel=1e-12)


def test_corner_texels_are_smaller_than_centre_texels():
    n = 64
    w = cube_solid_angles(n)[0]
    # Small texels have solid angle ~ area * (1 + u^2 + v^2)^(-3/2) at their centre (u, v).
    u_centre, u_corner = 1.0 / n, 1.0 - 1.0 / n
    expected = (1 + 2 * u_corner**2) ** 1.5 / (1 + 2 * u_centre**2) ** 1.5
    assert w[32, 32] / w[0, 0] == pytest.approx(expected, rel=1e-3)


unit = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)


@settings(max_examples=300, deadline=None)
@given(unit)
def test_direction_round_trip(v):
    d = np.asarray(v) / np.linalg.norm(v)
    face, u, w = dir_to_face_uv(d)
    assert -1 <= u <= 1 and -1 <= w <= 1
    back = face_uv_to_dir(face, u, w)
    np.testing.assert_allclose(back / np.linalg.norm(back), d, atol=1e-12)


@pytest.mark.parametrize("n", [1, 4, 33])
def test_texel_round_trip(n):
    f, r, c = dir_to_texel(texel_directions(n), n)
    F, R, C = np.meshgrid(np.arange(6), np.arange(n), np.arange(n), indexing="ij")
    assert (f == F).all() and (r == R).all() and (c == C).all()


def test_neighbour_across_edge_is_adjacent_on_sphere():
    n = 16
    d = texel_directions(n)
    # Angular spacing of texels at the middle of a face edge (about half that at the face centre).
    spacing = np.arccos(np.clip(d[4, 0, 8] @ d[4, 1, 8], -1, 1))
    for face in range(6):
        for row, col in [(-1, 5), (n, 5), (5, -1), (5, n), (-2, 7), (7, n + 1)]:
            f2, r2, c2 = neighbour_texel(face, row, col, n)
            assert f2 != face
            # The resolved texel lies about |offset| texel spacings from the edge texel it extends.
            inside = neighbour_texel(face, np.clip(row, 0, n - 1), np.clip(col, 0, n - 1), n)
            ang = np.arccos(np.clip(d[f2, r2, c2] @ d[inside], -1, 1))
            offset = max(row - (n - 1), -row, col - (n - 1), -col)
            assert ang == pytest.approx(offset * spacing, rel=0.15)


def test_bilinear_lookup_is_seamless_and_exact_at_texel_centres():
    rng = np.random.default_rng(1)
    cube = rng.random((6, 8, 8, 3))
    np.testing.assert_allclose(sample_bilinear(cube, texel_directions(8)), cube, atol=1e-12)
    # Along a path crossing the +X/+Z edge the lookup changes continuously.
    t = np.linspace(-0.2, 0.2, 2001)
    path = np.stack([np.ones_like(t) - t.clip(0), 0.1 + 0 * t, 1 + t.clip(max=0)], -1)
    vals = sample_bilinear(cube, path)
    assert np.abs(np.diff(vals, axis=0)).max() < 0.05
