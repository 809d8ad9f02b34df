"""Mesh validation, vertex order, normals and loading (numpy only, no GPU)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from renderer.errors import InvalidInputError, MeshError
from renderer.mesh import (
    FALLBACK_NORMAL,
    MAX_COORDINATE,
    Mesh,
    bounding_sphere,
    bounds,
    box,
    load_mesh,
    vertex_normals,
    z_up_to_y_up,
)
from renderer.procedural import uv_sphere

ASSETS = Path(__file__).resolve().parents[1].parent / "shared" / "assets"
needs_assets = pytest.mark.skipif(
    not ASSETS.is_dir(), reason=f"shared test assets not found at {ASSETS} (they live outside the repository)"
)
SHIRT_OBJ = ASSETS / "meshes" / "newton_unisex_shirt.obj"
SIM_NPZ = ASSETS / "sim" / "newton_shirt_drape_60f.npz"

QUAD_P = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])


def raw_obj_vertices(path: Path) -> np.ndarray:
    """The 'v' lines of an OBJ in file order: the reference the loader must reproduce."""
    with open(path) as f:
        return np.array([line.split()[1:4] for line in f if line.startswith("v ")], np.float64)


def reference_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Slow, obvious area-weighted normals: one face at a time."""
    acc = np.zeros((len(positions), 3))
    for f in faces:
        a, b, c = positions[f].astype(np.float64)
        n = np.cross(b - a, c - a)
        for i in f:
            acc[i] += n
    out = np.tile(np.array(FALLBACK_NORMAL), (len(positions), 1))
    length = np.linalg.norm(acc, axis=1)
    ok = length > 0
    out[ok] = acc[ok] / length[ok, None]
    return out


# --- construction and validation ---------------------------------------------------------------


def test_from_arrays_stores_read_only_copies_of_the_right_dtypes():
    p, f = QUAD_P.copy(), QUAD_F.copy()
    uv = p[:, :2].copy()
    m = Mesh.from_arrays(p, f, uv, name="quad")
    assert m.positions.dtype == np.float32 and m.positions.shape == (4, 3)
    assert m.faces.dtype == np.int32 and m.faces.shape == (2, 3)
    assert m.uvs.dtype == np.float32 and m.uvs.shape == (4, 2)
    for a in (m.positions, m.faces, m.uvs):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0] = 0
    p[0] = 99.0  # the caller's arrays stay theirs
    f[0] = 3
    assert m.positions[0, 0] == 0.0 and m.faces[0, 1] == 1
    assert (m.n_vertices, m.n_faces, m.name) == (4, 2, "quad")


def test_mesh_cannot_bypass_validation():
    with pytest.raises(TypeError, match="from_arrays"):
        Mesh(QUAD_P.astype(np.float32), QUAD_F.astype(np.int32))


def _nan_positions():
    p = np.zeros((10, 3))
    p[3, 1] = np.nan
    p[7, 2] = np.inf
    return p


@pytest.mark.parametrize(
    "positions, faces, uvs, fragments",
    [
        (np.zeros((4, 2)), QUAD_F, None, ["positions must have shape (V, 3)", "(4, 2)"]),
        (np.zeros(12), QUAD_F, None, ["reshape(-1, 3)"]),
        (QUAD_P.astype(np.complex64), QUAD_F, None, ["real numeric", "complex64"]),
        (np.array([["a", "b", "c"]] * 4), QUAD_F, None, ["real numeric"]),
        (QUAD_P, QUAD_F.astype(np.float32), None, ["integer", "float32"]),
        (QUAD_P, np.zeros((2, 4), int), None, ["shape (F, 3)", "triangulate"]),
        (np.zeros((0, 3)), QUAD_F, None, ["empty", "0 vertices"]),
        (QUAD_P, np.zeros((0, 3), int), None, ["empty", "0 faces"]),
        (_nan_positions(), np.array([[0, 1, 2]]), None, ["NaN/Inf in 2 of 10 vertices", "first at vertex 3"]),
        (np.full((3, 3), 1e39), np.array([[0, 1, 2]]), None, ["NaN/Inf", "float32 range"]),
        (QUAD_P, np.array([[0, 1, 2], [0, -2, 3]]), None, ["negative", "face 1", "4 vertices"]),
        (QUAD_P, np.array([[0, 1, 2], [0, 2, 7]]), None, ["past the 4 vertices", "largest index 7", "face 1"]),
        (QUAD_P, np.array([[1, 2, 3], [1, 3, 4]]), None, ["1-based"]),
        (QUAD_P, QUAD_F, np.zeros((3, 2)), ["uvs must be per-vertex", "(4, 2)"]),
        (QUAD_P, QUAD_F, np.array([[0, 0], [0, np.nan], [0, 0], [0, 0]]), ["uvs", "vertex 1"]),
    ],
)
def test_from_arrays_rejects_with_actionable_message(positions, faces, uvs, fragments):
    with pytest.raises(MeshError) as info:
        Mesh.from_arrays(positions, faces, uvs, name="garment")
    message = str(info.value)
    assert "garment" in message
    for fragment in fragments:
        assert fragment in message


def test_mesh_error_is_an_invalid_input_error():
    with pytest.raises(InvalidInputError):
        Mesh.from_arrays(np.zeros((0, 3)), QUAD_F)
    with pytest.raises(ValueError):  # callers that only know ValueError still catch it
        Mesh.from_arrays(np.zeros((0, 3)), QUAD_F)


def test_more_than_2_pow_31_indices_is_rejected_without_touching_the_data():
    # A zero-stride view: 2**31 indices of shape, 12 bytes of memory. The check must use the shape only.
    faces = np.broadcast_to(np.array([[0, 1, 2]], np.int32), (2**31 // 3 + 1, 3))
    with pytest.raises(MeshError, match="split the mesh"):
        Mesh.from_arrays(QUAD_P, faces)


def test_degenerate_triangles_and_duplicate_vertices_are_kept_and_counted():
    p = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 0, 0], [5, 5, 5]], np.float32
    )  # 4 duplicates 1; 5 is unreferenced
    f = np.array(
        [
            [0, 1, 2],  # fine
            [0, 1, 3],  # collinear: zero area
            [2, 2, 0],  # repeated index
            [1, 4, 1],  # all three at one point
        ]
    )
    m = Mesh.from_arrays(p, f)
    s = m.stats()
    assert (s.n_vertices, s.n_faces) == (6, 4)
    assert s.n_degenerate == 3
    assert s.n_duplicate_vertices == 1
    assert s.n_unreferenced == 1
    assert s.bounds == ((0.0, 0.0, 0.0), (5.0, 5.0, 5.0))


# --- frames of positions -----------------------------------------------------------------------


def test_with_positions_keeps_topology_and_converts_dtype():
    m = Mesh.from_arrays(QUAD_P, QUAD_F, QUAD_P[:, :2])
    new = QUAD_P * 2.0  # float64 in
    m2 = m.with_positions(new)
    assert m2.faces is m.faces and m2.uvs is m.uvs and m2.name == m.name
    assert m2.positions.dtype == np.float32 and not m2.positions.flags.writeable
    np.testing.assert_array_equal(m2.positions, new.astype(np.float32))
    np.testing.assert_array_equal(m.positions, QUAD_P.astype(np.float32))  # the old frame is untouched


@pytest.mark.parametrize(
    "new, fragments",
    [
        (np.zeros((5, 3)), ["5 vertices but the mesh has 4", "vertex count and order"]),
        (np.zeros((4, 2)), ["shape (V, 3)"]),
        (np.array([[0, 0, 0], [0, 0, 0], [np.nan, 0, 0], [0, 0, 0]]), ["NaN/Inf in 1 of 4", "vertex 2"]),
    ],
)
def test_with_positions_rejects_bad_frames(new, fragments):
    m = Mesh.from_arrays(QUAD_P, QUAD_F, name="shirt")
    with pytest.raises(MeshError) as info:
        m.with_positions(new)
    for fragment in fragments:
        assert fragment in str(info.value)


def test_positions_from_bytes_round_trip_and_with_positions_accepts_bytes():
    m = Mesh.from_arrays(QUAD_P, QUAD_F)
    frame = (QUAD_P + 0.5).astype("<f4")
    decoded = Mesh.positions_from_bytes(frame.tobytes(), 4)
    assert decoded.dtype == np.float32 and decoded.shape == (4, 3) and not decoded.flags.writeable
    np.testing.assert_array_equal(decoded, frame)
    np.testing.assert_array_equal(m.with_positions(bytearray(frame.tobytes())).positions, frame)


@pytest.mark.parametrize(
    "nbytes, fragments",
    [
        (47, ["needs 48 bytes", "got 47 bytes"]),
        (96, ["needs 48 bytes", "float64"]),
        (36, ["that is 3 vertices"]),
    ],
)
def test_positions_from_bytes_names_the_expected_byte_count(nbytes, fragments):
    with pytest.raises(MeshError) as info:
        Mesh.positions_from_bytes(b"\0" * nbytes, 4)
    for fragment in fragments:
        assert fragment in str(info.value)


def test_positions_from_bytes_rejects_nan_and_non_bytes():
    with pytest.raises(MeshError, match="vertex 1"):
        Mesh.positions_from_bytes(np.array([[0, 0, 0], [np.nan, 0, 0]], "<f4").tobytes(), 2)
    with pytest.raises(MeshError, match="bytes-like"):
        Mesh.positions_from_bytes("not bytes", 1)


@settings(max_examples=50, deadline=None)
@given(hnp.arrays(np.float32, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=40).map(
    lambda s: (s[0], 3)), elements=st.floats(-MAX_COORDINATE, MAX_COORDINATE, width=32)))
def test_bytes_round_trip_is_exact(frame):
    data = frame.astype("<f4").tobytes()
    if len(frame) > 1 and (frame == frame[0]).all():   # a frame collapsed to one point is refused by name
        with pytest.raises(MeshError, match="coincide"):
            Mesh.positions_from_bytes(data, len(frame))
        return
    np.testing.assert_array_equal(Mesh.positions_from_bytes(data, len(frame)), frame)


# --- normals -------------------------------------------------------------------------------------


def test_sphere_normals_point_outward():
    centre = np.array([0.3, -1.0, 2.0])
    s = uv_sphere(radius=0.7, n_lat=24, n_lon=48, centre=centre)
    n = vertex_normals(s.positions, s.faces)
    radial = s.positions - centre
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert n.dtype == np.float32 and n.shape == (s.n_vertices, 3)
    assert np.einsum("ij,ij->i", n, radial).min() > 0.99


def test_normals_match_the_slow_reference_and_are_unit_length():
    rng = np.random.default_rng(7)
    p = rng.normal(size=(60, 3)).astype(np.float32)
    f = rng.integers(0, 50, size=(200, 3))  # vertices 50..59 are isolated
    n = vertex_normals(p, f)
    np.testing.assert_allclose(n, reference_normals(p, f), atol=2e-5)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)


def test_normals_are_area_weighted():
    # Vertex 0 is shared by a 1 x 1 triangle facing +Z and a 0.1 x 0.1 one facing +X.
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0.1, 0], [0, 0, 0.1]], np.float32)
    f = np.array([[0, 1, 2], [0, 3, 4]])
    n0 = vertex_normals(p, f)[0]
    expected = np.array([0.01, 0.0, 1.0]) / np.hypot(0.01, 1.0)
    np.testing.assert_allclose(n0, expected, atol=1e-6)


def test_degenerate_and_isolated_vertices_get_the_fallback_never_nan():
    p = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [9, 9, 9], [0, 0, 1], [0, 1, 1]], np.float32)
    f = np.array([[0, 1, 2], [4, 4, 4], [0, 1, 5]])  # collinear; one point; one real triangle
    n = vertex_normals(p, f)
    assert np.isfinite(n).all()
    np.testing.assert_array_equal(n[[2, 3, 4]], [FALLBACK_NORMAL] * 3)  # only zero-area faces, or none
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)


def test_opposite_faces_that_cancel_give_the_fallback():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 1]])  # the same triangle both ways round
    np.testing.assert_array_equal(vertex_normals(p, f), [FALLBACK_NORMAL] * 3)


def test_reversed_winding_reverses_normals():
    s = uv_sphere(n_lat=8, n_lon=12)
    np.testing.assert_allclose(
        vertex_normals(s.positions, s.faces[:, ::-1]), -vertex_normals(s.positions, s.faces), atol=1e-6
    )


# --- bounds --------------------------------------------------------------------------------------


def test_bounds_and_bounding_sphere_cover_every_mesh():
    a = uv_sphere(radius=1.0, centre=(0, 0, 0), n_lat=8, n_lon=8)
    b = Mesh.from_arrays(QUAD_P + [3, 0, 0], QUAD_F)
    lo, hi = bounds([a, b])
    np.testing.assert_allclose(lo, [-1, -1, -1], atol=1e-6)
    np.testing.assert_allclose(hi, [4, 1, 1], atol=1e-6)
    centre, radius = bounding_sphere([a, b])
    for m in (a, b):
        assert np.linalg.norm(m.positions - centre, axis=1).max() <= radius + 1e-9
    assert radius <= 0.5 * np.linalg.norm(hi - lo) + 1e-9
    np.testing.assert_array_equal(bounds(b)[0], [3, 0, 0])  # a single Mesh works too


@settings(max_examples=50, deadline=None)
@given(hnp.arrays(np.float32, st.tuples(st.integers(1, 50), st.just(3)),
                  elements=st.floats(-1e6, 1e6, allow_nan=False, width=32)))
def test_box_is_the_per_axis_min_and_max(points):
    lo, hi = box(points)
    assert lo.dtype == hi.dtype == np.float64
    np.testing.assert_array_equal(lo, points.min(axis=0))
    np.testing.assert_array_equal(hi, points.max(axis=0))


def test_a_scenes_bounds_follow_every_frames_positions(renderer):
    a = uv_sphere(radius=1.0, centre=(0, 0, 0), n_lat=8, n_lon=8)
    b = Mesh.from_arrays(QUAD_P + [3, 0, 0], QUAD_F)
    scene = renderer.create_scene([a, b])
    try:
        np.testing.assert_array_equal(scene.bounds(), bounds([a, b]))
        scene.set_positions([a.positions * 2.0, None])
        lo, hi = scene.bounds()
        np.testing.assert_allclose(lo, [-2, -2, -2], atol=1e-6)
        np.testing.assert_allclose(hi, [4, 2, 2], atol=1e-6)
    finally:
        scene.release()


def test_bounding_sphere_of_a_single_point_has_positive_radius():
    point = Mesh.from_arrays([[1e3, 0, 0]], [[0, 0, 0]])
    centre, radius = bounding_sphere(point)
    np.testing.assert_array_equal(centre, [1e3, 0, 0])
    assert radius == pytest.approx(1e-3)
    _, r0 = bounding_sphere(Mesh.from_arrays([[0, 0, 0]], [[0, 0, 0]]))
    assert r0 == pytest.approx(1e-6)


def test_bounds_of_nothing_is_an_error():
    with pytest.raises(InvalidInputError, match="at least one mesh"):
        bounds([])
    with pytest.raises(InvalidInputError, match="Mesh"):
        bounding_sphere([np.zeros((3, 3))])


# --- loading ---------------------------------------------------------------------------------------


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_load_obj_up_axis_and_scale(tmp_path):
    obj = _write(tmp_path / "tri.obj", "v 1 2 3\nv 4 5 6\nv 1 2 4\nf 1 2 3\n")
    y = load_mesh(obj)
    np.testing.assert_array_equal(y.positions, [[1, 2, 3], [4, 5, 6], [1, 2, 4]])
    z = load_mesh(obj, up="z", scale=0.5)
    np.testing.assert_allclose(z.positions, [[0.5, 1.5, -1.0], [2.0, 3.0, -2.5], [0.5, 2.0, -1.0]])
    assert z.name == "tri"
    # A proper rotation: the face normal turns with the geometry instead of flipping.
    n_y = vertex_normals(y.positions, y.faces)[0]
    np.testing.assert_allclose(vertex_normals(z.positions, z.faces)[0], z_up_to_y_up(n_y), atol=1e-6)


def test_z_up_to_y_up_is_a_right_handed_rotation():
    np.testing.assert_array_equal(z_up_to_y_up(np.eye(3)), [[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert np.linalg.det(z_up_to_y_up(np.eye(3))) == pytest.approx(1.0)


@pytest.mark.parametrize("ext", ["ply", "stl", "glb"])
def test_load_other_formats(tmp_path, ext):
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    path = tmp_path / f"box.{ext}"
    box.export(path)
    m = load_mesh(path)
    assert m.n_faces == 12
    np.testing.assert_allclose(bounds(m)[0], [-0.5, -1.0, -1.5], atol=1e-6)
    if ext == "ply":  # PLY keeps shared vertices in file order
        np.testing.assert_allclose(m.positions, box.vertices, atol=1e-6)
    # Outward normals survive the round trip (box centred on the origin).
    n = vertex_normals(m.positions, m.faces)
    assert (np.einsum("ij,ij->i", n, m.positions) > 0).all()


def test_load_scene_concatenates_geometries_with_their_transforms(tmp_path):
    import trimesh

    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="a")
    mirror_and_shift = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror_and_shift[:3, 3] = (5.0, 0.0, 0.0)
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="b", transform=mirror_and_shift)
    path = tmp_path / "two.glb"
    scene.export(path)
    m = load_mesh(path)
    assert m.n_faces == 24
    lo, hi = bounds(m)
    np.testing.assert_allclose(lo, [-0.5, -0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi, [5.5, 0.5, 0.5], atol=1e-6)
    # The mirrored copy's faces were flipped back: every normal points out of its own box.
    n = vertex_normals(m.positions, m.faces)
    centres = np.where(m.positions[:, :1] > 2.5, [[5.0, 0, 0]], [[0.0, 0, 0]])
    assert (np.einsum("ij,ij->i", n, m.positions - centres) > 0).all()


def test_load_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.obj"
    with pytest.raises(MeshError, match="nope.obj.*no such file"):
        load_mesh(missing)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01")
    with pytest.raises(MeshError, match="garbage.ply"):
        load_mesh(garbage)
    empty = _write(tmp_path / "empty.obj", "# nothing here\n")
    with pytest.raises(MeshError, match="empty.obj"):
        load_mesh(empty)
    with pytest.raises(MeshError, match="unsupported extension.*\\.obj"):
        load_mesh(tmp_path / "mesh.fbx")
    nan = _write(tmp_path / "nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="nan.obj.*vertex 1"):
        load_mesh(nan)


def test_load_rejects_bad_parameters(tmp_path):
    obj = _write(tmp_path / "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InvalidInputError, match="up must be one of"):
        load_mesh(obj, up="x")
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="scale"):
            load_mesh(obj, scale=bad)


@needs_assets
def test_load_preserves_obj_vertex_order():
    m = load_mesh(SHIRT_OBJ)
    raw = raw_obj_vertices(SHIRT_OBJ)
    assert m.n_vertices == len(raw) == 6436 and m.n_faces == 12736
    np.testing.assert_allclose(m.positions, raw, rtol=0, atol=1e-4)  # cm, float32


@needs_assets
def test_multi_material_obj_keeps_one_vertex_list():
    # trimesh splits this file at every `usemtl`; the loader must re-join the chunks in file order.
    path = ASSETS / "meshes" / "diffavatar_polo.obj"
    m = load_mesh(path, scale=0.01)
    raw = raw_obj_vertices(path)
    assert m.n_vertices == len(raw) == 3314 and m.n_faces == 6508
    np.testing.assert_allclose(m.positions, raw * 0.01, atol=1e-6)


@needs_assets
def test_obj_with_uvs_and_asset_quirks():
    dress = load_mesh(ASSETS / "meshes" / "diffavatar_dress_draped.obj", scale=0.01)
    assert dress.uvs is not None and dress.uvs.shape == (dress.n_vertices, 2) == (10709, 2)
    teapot = load_mesh(ASSETS / "meshes" / "utah-teapot.obj")
    assert teapot.stats().n_duplicate_vertices > 0  # patch seams, kept as they are
    bunny = load_mesh(ASSETS / "meshes" / "stanford-bunny.obj")
    raw = raw_obj_vertices(ASSETS / "meshes" / "stanford-bunny.obj")
    assert bunny.n_vertices == len(raw)  # unreferenced vertices stay, so indices stay valid
    assert bunny.stats().n_unreferenced == len(raw) - len(np.unique(bunny.faces))
    assert np.isfinite(vertex_normals(bunny.positions, bunny.faces)).all()


@needs_assets
def test_newton_sim_frames_convert_from_z_up_and_match_the_rest_mesh():
    sim = np.load(SIM_NPZ)
    frames, triangles = sim["positions"], sim["triangles"]
    assert frames.shape == (61, 6436, 3)
    # Frame 0 is the rest state: the cm, Y-up OBJ in metres, Z-up.
    rest = load_mesh(SHIRT_OBJ, scale=0.01)
    np.testing.assert_array_equal(rest.faces, triangles)
    np.testing.assert_allclose(z_up_to_y_up(frames[0]), rest.positions, atol=1e-5)

    m = rest
    for frame in frames:
        m = m.with_positions(z_up_to_y_up(frame))
        assert np.isfinite(vertex_normals(m.positions, m.faces)).all()
    # The shirt fell onto the dress form: Y (height) went down, and the last frame's OBJ
    # (metres, Z-up) loads to the same positions.
    assert m.positions[:, 1].max() < rest.positions[:, 1].max()
    last = load_mesh(ASSETS / "sim" / "newton_shirt_drape_f060.obj", up="z")
    np.testing.assert_allclose(last.positions, m.positions, atol=1e-5)
    # Streaming the raw bytes of a Z-up frame gives the same result as the array path.
    streamed = rest.with_positions(z_up_to_y_up(frames[-1]).astype("<f4").tobytes())
    np.testing.assert_array_equal(streamed.positions, m.positions)


def test_a_stray_vertex_is_named_and_a_wide_mesh_is_not_one():
    """One vertex of a frame 30 km off the rest (a solver's blow-up) is refused with its index and
    distance; a mesh whose far vertices are many (a floor with a figure on it) is not."""
    import trimesh

    from renderer.errors import MeshError
    from renderer.mesh import Mesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    mesh = Mesh.from_arrays(np.asarray(s.vertices), np.asarray(s.faces), name="ball")
    stray = mesh.positions.copy()
    stray[11] = (30_000.0, 0.0, 0.0)
    with pytest.raises(MeshError, match=r"1 of 642 vertices .* vertex 11 at \(30000\.0, 0\.0, 0\.0\)"):
        mesh.with_positions(stray)
    wide = np.concatenate([mesh.positions, mesh.positions * 2000.0])
    faces = np.concatenate([mesh.faces, mesh.faces + len(mesh.positions)])
    assert Mesh.from_arrays(wide, faces, name="figure-and-floor").n_vertices == 2 * 642
