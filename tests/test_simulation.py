"""The cloth simulator's physics, without a server: analytic free fall, the spring layout and its
colouring, the body proxy's distances and mesh, and a whole drape (bounded energy and stretch, no
penetration of the proxy, finite state)."""

from __future__ import annotations

import numpy as np
import pytest

from simulation import BodyProxy, Capsule, ClothSettings, ClothSim, mannequin, sheet, sphere
from simulation.solver import colour_springs


def test_sheet_springs_have_grid_rest_lengths_and_faces_face_up():
    c = sheet(8, size_m=0.7, height_m=1.0)
    spacing = 0.7 / 7
    assert c.n_vertices == 64 and len(c.faces) == 2 * 49
    np.testing.assert_allclose(c.structural.rest_m, spacing)
    np.testing.assert_allclose(c.shear.rest_m, spacing * np.sqrt(2))
    np.testing.assert_allclose(c.bend.rest_m, 2 * spacing)
    assert len(c.structural.pairs) == 2 * 8 * 7 and len(c.shear.pairs) == 2 * 49 and len(c.bend.pairs) == 2 * 8 * 6
    p = c.positions
    n = np.cross(p[c.faces[:, 1]] - p[c.faces[:, 0]], p[c.faces[:, 2]] - p[c.faces[:, 0]])
    assert np.all(n[:, 1] > 0) and np.allclose(n[:, [0, 2]], 0)
    assert np.all(p[:, 1] == 1.0)


def test_sheet_hole_drops_vertices_and_every_spring_touching_them():
    c = sheet(16, size_m=1.0, hole_radius_m=0.2)
    r = np.hypot(c.positions[:, 0], c.positions[:, 2])
    assert r.min() >= 0.2 and c.n_vertices < 256
    for springs in (c.structural, c.shear, c.bend):
        assert springs.pairs.max() < c.n_vertices
        np.testing.assert_allclose(springs.rest_m, np.linalg.norm(
            c.positions[springs.pairs[:, 0]] - c.positions[springs.pairs[:, 1]], axis=1))


def test_spring_colouring_is_a_partition_without_shared_vertices():
    c = sheet(12)
    pairs = np.concatenate([c.structural.pairs, c.shear.pairs])
    groups = colour_springs(pairs, c.n_vertices)
    seen = np.concatenate(groups)
    assert np.array_equal(np.sort(seen), np.arange(len(pairs)))  # each spring in exactly one colour
    for g in groups:
        ends = pairs[g].reshape(-1)
        assert len(np.unique(ends)) == len(ends)  # no vertex twice in a colour


def test_free_fall_matches_semi_implicit_euler_and_keeps_the_sheet_undeformed():
    """No body, no floor, no damping: every vertex falls as semi-implicit Euler says,
    y_n = y_0 - g h^2 n (n + 1) / 2 after n substeps of length h, and no spring changes length."""
    c = sheet(10, height_m=2.0)
    s = ClothSettings(damping_per_s=0.0, drag_per_s=0.0, friction=0.0, substeps=8, frame_dt_s=1 / 30)
    sim = ClothSim(c, BodyProxy((), floor_y=None), s)
    for _ in range(6):
        stats = sim.step_frame()
    n = 6 * 8
    h = s.frame_dt_s / s.substeps
    np.testing.assert_allclose(sim.x[:, 1], 2.0 - 9.81 * h * h * n * (n + 1) / 2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sim.x[:, [0, 2]], c.positions[:, [0, 2]], atol=1e-12)
    assert stats.max_stretch < 1e-9


def test_proxy_signed_distance_is_exact_for_sphere_capsule_and_floor():
    body = BodyProxy((sphere((0, 1, 0), 0.2), Capsule((1, 1, 0), (1, 2, 0), 0.1)), floor_y=0.0)
    pts = np.array([[0, 1.5, 0], [0, 1, 0], [1.3, 1.5, 0], [1, 2.4, 0], [5, 0.25, 5], [5, -0.1, 5]])
    np.testing.assert_allclose(body.signed_distance(pts), [0.3, -0.2, 0.2, 0.3, 0.25, -0.1], atol=1e-12)


def test_push_out_leaves_every_point_at_least_the_margin_away():
    """Points up to 3 cm inside the mannequin (a cloth vertex moves about 1 cm per substep) and around it."""
    rng = np.random.default_rng(3)
    body = mannequin()
    pts = rng.uniform([-0.6, -0.1, -0.4], [0.6, 1.9, 0.4], size=(40000, 3))
    pts = pts[body.signed_distance(pts) > -0.03]
    moved, contact, normal = body.push_out(pts, 0.012)
    sd = body.signed_distance(moved)
    # Where shapes meet at a concave crease (arm and chest), pushes out of one and then the other
    # converge slowly: 0.12 % of these points stay short of the margin after 4 passes, none 5 mm inside.
    assert np.mean(sd >= 0.012 - 1e-9) > 0.998
    assert sd.min() > -0.005
    assert np.array_equal(contact, np.linalg.norm(moved - pts, axis=1) > 0)
    np.testing.assert_allclose(np.linalg.norm(normal[contact], axis=1), 1.0)


def test_proxy_mesh_lies_on_the_shapes_with_outward_faces():
    body = BodyProxy((sphere((0, 1, 0), 0.2), Capsule((0.5, 0.5, 0.1), (0.9, 1.2, -0.2), 0.07)), floor_y=None)
    p, f = body.mesh(n_lat=12, n_lon=16)
    assert np.abs(body.signed_distance(p)).max() < 1e-6
    centroid = p[f].mean(axis=1)
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    axis = body.closest_axis_points(centroid)
    part = np.argmin(np.abs(np.linalg.norm(centroid[:, None] - axis, axis=-1) - [0.2, 0.07]), axis=1)
    outward = centroid - axis[np.arange(len(f)), part]
    assert np.all(np.einsum("ij,ij->i", n, outward) > 0)


@pytest.fixture(scope="module")
def drape():
    """The demo's drape at a small size: a 32 x 32 sheet dropped on the mannequin, 75 frames (2.5 s)."""
    sim = ClothSim(sheet(32), mannequin())
    e0 = sim.stats().energy_j
    stats = [sim.step_frame() for _ in range(75)]
    return sim, e0, stats


def test_drape_state_is_finite_and_energy_never_grows(drape):
    sim, e0, stats = drape
    assert np.all(np.isfinite(sim.x)) and np.all(np.isfinite(sim.v))
    energy = np.array([s.energy_j for s in stats])
    # Damping, drag, friction and inelastic contacts remove energy: the total never exceeds the start.
    # Contacts can add a little in one frame (a vertex projected out of the body gains the velocity
    # of that move), measured up to 0.7 % of the start; never more than 1 %.
    assert energy.max() <= e0 * (1 + 1e-6)
    assert np.all(np.diff(energy) <= 0.01 * e0)
    assert stats[-1].kinetic_j < 0.01 * e0  # it comes to rest


def test_drape_stretch_is_bounded(drape):
    _, _, stats = drape
    # Structural springs are inextensible up to the solver's convergence: the mean stays within 2 %,
    # the worst spring (where the cloth's weight hangs on the head and shoulders) within 40 %.
    assert max(s.mean_stretch for s in stats) < 0.02
    assert max(s.max_stretch for s in stats) < 0.4


def test_drape_does_not_penetrate_the_body_and_stays_on_it(drape):
    sim, _, stats = drape
    assert max(s.max_penetration_m for s in stats) == 0.0
    # Every vertex keeps the cloth's thickness from the proxy (less round-off).
    assert sim.body.signed_distance(sim.x).min() >= sim.settings.thickness_m - 1e-9
    # It hangs from the head and shoulders: the top rests on the head, nothing reaches the floor.
    head_top = 1.64 + 0.10
    assert abs(sim.x[:, 1].max() - (head_top + sim.settings.thickness_m)) < 0.01
    assert sim.x[:, 1].min() > 0.4
    assert stats[-1].contacts > 0
