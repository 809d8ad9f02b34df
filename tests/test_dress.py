"""The sewn dress: its panels and seams, a whole drape on the mannequin (closed seams, bounded
stretch, no penetration, hanging from the shoulders, outward faces, determinism), the render mesh
it sews into, and the mannequin's smooth render mesh."""

from __future__ import annotations

import numpy as np
import pytest

from simulation import mannequin
from simulation.body_mesh import body_mesh, floor_mesh
from simulation.dress import drape
from simulation.panels import BACK, FRONT, dress

SPACING_M = 0.04  # coarse: the whole file runs in seconds
FRAMES = 60


def _face_normals(p: np.ndarray, f: np.ndarray) -> np.ndarray:
    return np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])


def _outward_share(p: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """Mean cosine between face normals and the horizontal direction away from the body's axis
    (the Y axis), and the share of faces with a positive one."""
    n = _face_normals(p, f)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = p[f].mean(axis=1)
    radial = c * [1.0, 0.0, 1.0]
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
    cos = np.einsum("ij,ij->i", n, radial)
    return float(cos.mean()), float(np.mean(cos > 0))


@pytest.fixture(scope="module")
def garment():
    return dress(SPACING_M)


@pytest.fixture(scope="module")
def draped():
    return drape(SPACING_M, frames=FRAMES)


def test_seam_edges_have_equal_vertex_counts_and_lengths(garment):
    """Each seam pairs a front edge with a back edge of as many vertices and the same length on
    the flat patterns, so sewing closes it without gathering either side."""
    assert set(garment.seam_pairs) == {"side +x", "side -x", "shoulder +x", "shoulder -x"}
    for name, pairs in garment.seam_pairs.items():
        assert pairs.shape[1] == 2 and len(pairs) >= 2, name
        assert np.all(garment.panel[pairs[:, 0]] == FRONT) and np.all(garment.panel[pairs[:, 1]] == BACK), name
        lengths = [np.linalg.norm(np.diff(garment.pattern[pairs[:, k]], axis=0), axis=1).sum() for k in (0, 1)]
        assert abs(lengths[0] - lengths[1]) < 1e-9, name
    every = np.concatenate(list(garment.seam_pairs.values())).reshape(-1)
    assert len(np.unique(every)) == len(every)  # no vertex in two seams
    # The placed panels start sewn and off the body (at least the cloth's thickness, 12 mm).
    p = garment.cloth.positions
    gaps = np.linalg.norm(p[garment.cloth.seams.pairs[:, 0]] - p[garment.cloth.seams.pairs[:, 1]], axis=1)
    assert gaps.max() < 1e-9
    assert mannequin().signed_distance(p).min() > 0.012


def test_springs_rest_on_the_flat_pattern_and_nothing_starts_stretched_much(garment):
    c = garment.cloth
    for springs in (c.structural, c.shear, c.bend):
        np.testing.assert_allclose(springs.rest_m, np.linalg.norm(
            garment.pattern[springs.pairs[:, 0]] - garment.pattern[springs.pairs[:, 1]], axis=1))
        assert springs.rest_m.min() > 0.2 * SPACING_M
    # The placement is the pattern wrapped around the body: almost everything at or below its rest
    # length (the development is exact on the skirt's cone, approximate on the bodice).
    st = c.structural
    stretch = np.linalg.norm(c.positions[st.pairs[:, 0]] - c.positions[st.pairs[:, 1]], axis=1) / st.rest_m - 1
    assert np.percentile(stretch, 95) < 0.02 and stretch.max() < 0.35
    # Tethers hang every vertex from the shoulder seams, no shorter than the cloth between.
    t = c.tethers
    assert len(np.unique(t.pairs[:, 0])) == len(t.pairs) and len(t.pairs) >= c.n_vertices - 4 * 8
    assert np.all(t.rest_m >= np.linalg.norm(garment.pattern[t.pairs[:, 0]] - garment.pattern[t.pairs[:, 1]],
                                             axis=1) - 1e-12)


def test_pattern_and_placed_faces_face_outward(garment):
    p, f = garment.cloth.positions, garment.cloth.faces
    q = garment.pattern
    e1, e2 = q[f[:, 1]] - q[f[:, 0]], q[f[:, 2]] - q[f[:, 0]]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)  # counter-clockwise on the pattern
    mean_cos, share = _outward_share(p, f)
    assert mean_cos > 0.5 and share > 0.97


def test_drape_closes_the_seams_and_keeps_the_cloth_whole(draped):
    last = draped.stats[-1]
    assert np.all(np.isfinite(draped.positions))
    assert last.max_seam_gap_m < 0.002
    # Inextensible up to the solver's convergence: the mean within 1 %, 99 % of the springs within
    # 8 %, the worst (at the straps' neckline edge, where the dress hangs on the shoulders) within 15 %.
    st = draped.garment.cloth.structural
    x = draped.positions
    stretch = np.linalg.norm(x[st.pairs[:, 0]] - x[st.pairs[:, 1]], axis=1) / st.rest_m - 1
    assert last.mean_stretch < 0.01 and np.percentile(stretch, 99) < 0.08
    assert draped.max_stretch < 0.15
    assert last.kinetic_j < 1e-3  # at rest


def test_drape_stays_out_of_the_body(draped):
    assert draped.max_penetration_m == 0.0
    sd = draped.body.signed_distance(draped.positions)
    thickness = draped.settings.thickness_m
    # Where the push out of one shape meets another (the armpit), a vertex may end a little short
    # of the thickness, never inside.
    assert sd.min() > 0.5 * thickness and np.mean(sd >= thickness - 1e-6) > 0.99


def test_drape_hangs_from_the_shoulders(draped):
    y = draped.positions[:, 1]
    shoulder_top = 1.41 + 0.07
    assert abs(y.max() - (shoulder_top + draped.settings.thickness_m)) < 0.015
    assert y.min() > 0.3  # the hem well above the floor, about knee height
    # The front hangs in front of the body and the back behind it.
    z = draped.positions[:, 2]
    panel = draped.garment.panel
    assert np.median(z[panel == FRONT]) > 0.05 and np.median(z[panel == BACK]) < -0.05


def test_sewn_mesh_merges_seams_and_winds_outward(draped):
    p, f, uv = draped.sewn()
    g = draped.garment
    assert p.dtype == np.float32 and f.dtype == np.int32 and uv.dtype == np.float32
    assert len(p) == g.cloth.n_vertices - len(g.cloth.seams.pairs) and len(f) == len(g.cloth.faces)
    assert f.min() == 0 and f.max() == len(p) - 1
    # Consistent winding across the seams: no directed edge twice (an edge shared by two faces is
    # walked once each way), and every seam edge is now shared.
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)
    mean_cos, share = _outward_share(p.astype(np.float64), f)
    assert mean_cos > 0.3 and share > 0.85
    assert np.all((uv >= 0) & (uv <= 1))


def test_drape_is_deterministic():
    a, b = drape(SPACING_M, frames=10), drape(SPACING_M, frames=10)
    assert np.array_equal(a.positions, b.positions)


def test_body_mesh_is_closed_outward_and_on_the_proxy():
    body = mannequin()
    p, f = body_mesh(body, blend_m=0.03, cell_m=0.02)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    # Closed and consistently wound: every directed edge once, and its reverse present.
    assert len(np.unique(directed, axis=0)) == len(directed)
    assert set(map(tuple, directed.tolist())) == set(map(tuple, directed[:, ::-1].tolist()))
    x = p.astype(np.float64)
    volume = np.einsum("ij,ij->i", x[f[:, 0]], np.cross(x[f[:, 1]], x[f[:, 2]])).sum() / 6
    assert volume > 0.05  # outward faces: a positive enclosed volume (the capsules' is about 0.07 m^3)
    sd = body.signed_distance(x)
    # On the proxy, except in the creases it fills (at most k / 4 per shape met): always less than
    # the cloth's thickness (12 mm), so the cloth never sinks into the drawn body.
    assert sd.min() > -1e-5 and sd.max() < 0.012 and np.median(np.abs(sd)) < 1e-4
    assert p[:, 1].min() > body.floor_y - 1e-6  # the floor is not part of it
    fp, ff = floor_mesh(body)
    n = _face_normals(fp.astype(np.float64), ff)
    assert np.all(n[:, 1] > 0) and np.allclose(fp[:, 1], body.floor_y)


@pytest.mark.system
def test_the_bundled_default_scene_is_the_drape_it_says_it_is():
    """renderer/data/default_scene.npz is what `python -m simulation.dress --store` makes now."""
    from renderer.procedural import default_scene
    from simulation.dress import default_scene_arrays, drape

    meshes, casters = default_scene()
    assert [m.name for m in meshes] == ["dress", "mannequin", "floor"] and casters == [True, True, False]
    made = default_scene_arrays(drape())
    for mesh, role in zip(meshes, ("garment", "body", "floor")):
        np.testing.assert_array_equal(mesh.faces, made[f"{role}_faces"])
        np.testing.assert_allclose(mesh.positions, made[f"{role}_positions"], atol=1e-4)   # 0.1 mm
    # The figure stands on the floor, facing +Z, the dress between its shoulders and its knees.
    dress_p, body_p, floor_p = (np.asarray(m.positions) for m in meshes)
    assert np.all(floor_p[:, 1] == 0.0) and body_p[:, 1].min() >= -0.01
    assert 1.3 < dress_p[:, 1].max() < 1.6 and 0.2 < dress_p[:, 1].min() < 0.7
