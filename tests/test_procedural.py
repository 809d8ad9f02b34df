"""The procedural garment, body, sphere and floor: shape, orientation, determinism (no GPU)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from renderer.errors import InvalidInputError
from renderer.mesh import Mesh, bounds, vertex_normals
from renderer.procedural import ground_plane, procedural_body, procedural_garment, uv_sphere


def as_trimesh(m: Mesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(m.positions, m.faces, process=False)


@pytest.fixture(scope="module")
def garment() -> Mesh:
    return procedural_garment()


@pytest.fixture(scope="module")
def body() -> Mesh:
    return procedural_body()


def test_garment_is_a_finite_open_surface_about_a_metre_tall(garment):
    assert np.isfinite(garment.positions).all()
    tm = as_trimesh(garment)
    assert not tm.is_watertight  # open at the waistband and the hem
    assert tm.is_winding_consistent
    lo, hi = bounds(garment)
    assert 0.5 <= hi[1] - lo[1] <= 1.5
    assert lo[1] > 0.0  # Y-up: hangs above the floor
    assert garment.stats().n_degenerate == 0


def test_garment_waistband_is_centred_and_is_the_top(garment):
    top = garment.positions[np.isclose(garment.positions[:, 1], garment.positions[:, 1].max())]
    assert len(top) > 8  # the whole waistband ring sits at one height
    ring = np.unique(top, axis=0)  # the seam vertex is there twice
    np.testing.assert_allclose(ring[:, [0, 2]].mean(axis=0), 0.0, atol=1e-6)
    lo, hi = bounds(garment)
    assert np.abs(0.5 * (lo + hi)[[0, 2]]).max() < 0.1  # the drape swings it only slightly off-centre


def test_garment_has_unit_uvs_and_folds_that_grow_towards_the_hem(garment):
    assert garment.uvs is not None and garment.uvs.shape == (garment.n_vertices, 2)
    assert garment.uvs.min() == 0.0 and garment.uvs.max() == 1.0
    # Radial deviation from each ring's mean radius: zero at the waistband, largest near the hem.
    rings = garment.positions.reshape(-1, 64 + 1, 3)[:, :-1]  # rows of the grid, seam copy dropped
    centre_x = rings[:, :, 0].mean(axis=1, keepdims=True)
    r = np.hypot(rings[:, :, 0] - centre_x, rings[:, :, 2])
    spread = r.max(axis=1) - r.min(axis=1)
    assert spread[0] < 1e-6
    assert spread[-1] > 0.05 and spread[-1] > spread[len(spread) // 2]


def test_garment_normals_point_away_from_the_axis(garment):
    n = vertex_normals(garment.positions, garment.faces)
    radial = garment.positions * [1, 0, 1]
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert (np.einsum("ij,ij->i", n, radial) > 0.5).all()


def test_garment_is_deterministic_and_scales_with_resolution():
    a, b = procedural_garment(32), procedural_garment(32)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.faces, b.faces)
    fine = procedural_garment(128)
    assert fine.n_faces == 16 * a.n_faces  # 4x around and 4x down
    np.testing.assert_allclose(bounds(fine)[1][1], bounds(a)[1][1])


@pytest.mark.parametrize("bad", [4, 0, -3, 12.5, "64", True])
def test_garment_rejects_bad_resolution(bad):
    with pytest.raises(InvalidInputError, match="resolution"):
        procedural_garment(bad)


def test_body_is_a_union_of_closed_outward_parts(body):
    parts = as_trimesh(body).split(only_watertight=False)
    assert len(parts) >= 5
    for part in parts:
        assert part.is_watertight and part.is_winding_consistent
        assert part.volume > 0  # positive volume: faces wind outward
    lo, hi = bounds(body)
    assert lo[1] == pytest.approx(0.0, abs=1e-6)
    assert 1.5 < hi[1] < 2.0


def test_garment_hangs_outside_the_body(garment, body):
    # No garment vertex inside any closed body part: it hangs on the body, not through it.
    points = garment.positions.astype(np.float64)
    for part in as_trimesh(body).split(only_watertight=False):
        lo, hi = part.bounds
        candidates = points[np.all((points >= lo) & (points <= hi), axis=1)]
        if len(candidates):
            assert not part.contains(candidates).any()


def test_uv_sphere_is_watertight_round_and_outward():
    centre = np.array([0.0, 1.5, -0.25])
    s = uv_sphere(radius=0.3, n_lat=16, n_lon=32, centre=centre)
    tm = as_trimesh(s)
    assert tm.is_watertight and tm.volume > 0
    assert tm.volume == pytest.approx(4 / 3 * np.pi * 0.3**3, rel=0.03)
    np.testing.assert_allclose(np.linalg.norm(s.positions - centre, axis=1), 0.3, rtol=1e-6)
    assert s.n_vertices == (16 - 1) * 32 + 2


def test_ground_plane_faces_up_at_its_height():
    g = ground_plane(size=3.0, y=-0.5, subdivisions=4)
    np.testing.assert_array_equal(g.positions[:, 1], -0.5)
    np.testing.assert_allclose(vertex_normals(g.positions, g.faces), [[0, 1, 0]] * g.n_vertices, atol=1e-6)
    lo, hi = bounds(g)
    np.testing.assert_allclose(lo[[0, 2]], -1.5)
    np.testing.assert_allclose(hi[[0, 2]], 1.5)
    assert g.n_faces == 2 * 4 * 4 and g.uvs.min() == 0.0 and g.uvs.max() == 1.0


def test_sphere_above_a_plane():
    # The scene shadow tests build: the sphere's lowest point clears the floor.
    floor = ground_plane(size=4.0, y=0.0)
    ball = uv_sphere(radius=0.5, centre=(0.0, 0.75, 0.0))
    assert bounds(ball)[0][1] == pytest.approx(0.25, abs=1e-6) and bounds(floor)[1][1] == 0.0


@pytest.mark.parametrize(
    "call",
    [
        lambda: uv_sphere(radius=0.0),
        lambda: uv_sphere(n_lat=1),
        lambda: uv_sphere(n_lon=2),
        lambda: ground_plane(size=-1.0),
        lambda: ground_plane(y=float("nan")),
        lambda: ground_plane(subdivisions=0),
    ],
)
def test_helpers_reject_bad_parameters(call):
    with pytest.raises(InvalidInputError):
        call()
