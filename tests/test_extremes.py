"""The extremes of issue 3: each gives a finite, plausible image or, for invalid input, a clear error."""

import numpy as np
import pytest

from renderer.envmap import environment_from_array
from renderer.errors import EnvironmentMapError, MeshError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.procedural import ground_plane, uv_sphere
from renderer.renderer import Background, FrameSettings
from renderer.shading.material import Material

from conftest import sun_sky_cube

SMALL = FrameSettings(48, 48, shadow_size=64)


def _frame(renderer, meshes, cube, materials=None, settings=SMALL, n_lights=24):
    scene = renderer.create_scene(meshes, materials or [Material((0.8, 0.4, 0.3), 0.5, 0.8)] * len(meshes))
    pems = renderer.build_pems(cube, PEMSettings(n_lights))
    try:
        return renderer.render(scene, pems, settings)
    finally:
        pems.release()
        scene.release()


def _ok(frame):
    assert np.isfinite(frame.image).all()
    assert (frame.image[..., :3] >= 0).all()
    return frame.image


@pytest.mark.parametrize("source", ["pem", "mixed"])
def test_sun_far_beyond_half_float_range(renderer, source):
    # Suns of 1e5 and 1e6 (half floats end at 65504): images are finite and scale with the light,
    # through the PEMs and through the small lights' closed forms (diffuse and glossy "mixed").
    meshes = [uv_sphere(0.5, 16, 32, (0, 0.6, 0)), ground_plane(3.0)]
    images = []
    for sun in (1e5, 1e6):
        cube = sun_sky_cube(32, (0.3, 1.0, 0.4), sun_radiance=sun, sun_radius_deg=3, sky=(0, 0, 0), ground=(0, 0, 0))
        assert cube.max() == sun
        fs = FrameSettings(48, 48, shadow_size=64, background=Background.BLACK, diffuse=source, glossy=source)
        frame = _frame(renderer, meshes, cube, settings=fs)
        images.append(_ok(frame)[..., :3])
    np.testing.assert_allclose(images[1], 10.0 * images[0], rtol=5e-3, atol=1e-3 * images[1].max())


def test_glossy_discs_at_the_extremes(renderer):
    # sub_lights (each region's glossy term from up to 16 discs of its texels): a sun of 1e5 and 1e6
    # scales the image linearly; a black map stays black; a map of one-texel regions (4x4 faces, 96
    # lights) pads every region's extra discs with no energy, and the image is the one disc's.
    meshes = [uv_sphere(0.5, 16, 32, (0, 0.6, 0)), ground_plane(3.0)]
    wide = dict(background=Background.BLACK, diffuse="lights", glossy="wide")
    images = []
    for sun in (1e5, 1e6):
        cube = sun_sky_cube(32, (0.3, 1.0, 0.4), sun_radiance=sun, sun_radius_deg=3, sky=(0, 0, 0), ground=(0, 0, 0))
        frame = _frame(renderer, meshes, cube, settings=FrameSettings(48, 48, shadow_size=64, sub_lights=16, **wide))
        images.append(_ok(frame)[..., :3])
    np.testing.assert_allclose(images[1], 10.0 * images[0], rtol=5e-3, atol=1e-3 * images[1].max())
    black = _frame(renderer, meshes, np.zeros((6, 16, 16, 3), np.float32),
                   settings=FrameSettings(48, 48, shadow_size=64, sub_lights=4, **wide))
    assert _ok(black)[..., :3].max() == 0.0
    tiny = np.random.default_rng(3).random((6, 4, 4, 3)).astype(np.float32)
    one, sixteen = (_ok(_frame(renderer, meshes, tiny, n_lights=96,
                               settings=FrameSettings(48, 48, shadow_size=64, sub_lights=k, **wide)))
                    for k in (1, 16))
    np.testing.assert_allclose(sixteen, one, rtol=1e-5, atol=1e-7)


def test_all_black_map_renders_black(renderer):
    img = _ok(_frame(renderer, [uv_sphere(0.5, 16, 32)], np.zeros((6, 16, 16, 3), np.float32)))
    assert img[..., :3].max() == 0.0


def test_constant_map(renderer):
    img = _ok(_frame(renderer, [uv_sphere(0.5, 16, 32)], np.full((6, 16, 16, 3), 0.7, np.float32),
                     [Material((1, 1, 1), 0.0, 0.0)]))
    cov = img[..., 3] > 0.5
    assert img[cov][:, :3].mean() == pytest.approx(0.7, rel=0.1)


def test_one_by_two_latlong_map(renderer):
    env = environment_from_array(np.array([[[1.0, 0.5, 0.2], [0.2, 0.5, 1.0]]], np.float32), "latlong", 16, "1x2")
    _ok(_frame(renderer, [uv_sphere(0.5, 16, 32)], env.cube))


def test_nan_and_inf_texels_are_an_error_or_repaired():
    img = np.ones((16, 32, 3), np.float32)
    img[2, 3] = np.nan
    img[5, 7, 1] = np.inf
    with pytest.raises(EnvironmentMapError, match="NaN"):
        environment_from_array(img, "latlong", 16, "bad")
    env = environment_from_array(img, "latlong", 16, "bad", repair=True)
    assert np.isfinite(env.cube).all()
    assert env.texel_report.n_nan == 3 and env.texel_report.repaired


def test_one_triangle_mesh(renderer):
    tri = Mesh.from_arrays(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
    img = _ok(_frame(renderer, [tri], sun_sky_cube(16, (0, 1, 1))))
    assert (img[..., 3] > 0.5).sum() > 50


def test_degenerate_zero_area_and_duplicate_geometry(renderer):
    s = uv_sphere(0.5, 12, 24)
    p = np.concatenate([s.positions, s.positions[:10]])          # duplicate vertices
    f = np.concatenate([s.faces, [[0, 0, 0], [1, 2, 2]],           # zero-area triangles
                        [[len(s.positions), len(s.positions) + 1, len(s.positions) + 2]]])
    p[len(s.positions) + 1] = p[len(s.positions)]                 # a degenerate one on duplicates
    mesh = Mesh.from_arrays(p, f)
    assert mesh.stats().n_degenerate >= 3
    _ok(_frame(renderer, [mesh], sun_sky_cube(16, (0, 1, 1))))


def test_flipped_winding_renders_the_same(renderer):
    # Cloth is two-sided: the normal is turned towards the camera, so winding does not matter.
    s = uv_sphere(0.5, 16, 32)
    flipped = Mesh.from_arrays(s.positions, s.faces[:, ::-1])
    cube = sun_sky_cube(16, (0.2, 1, 0.7))
    a = _ok(_frame(renderer, [s], cube))
    b = _ok(_frame(renderer, [flipped], cube))
    np.testing.assert_allclose(a, b, atol=1e-4 * a[..., :3].max())


def test_invalid_positions_are_rejected_with_the_reason():
    s = uv_sphere(0.5, 8, 16)
    bad = s.positions.copy()
    bad[3, 1] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        s.with_positions(bad)
    with pytest.raises(MeshError):
        s.with_positions(s.positions[:-1])


def test_two_million_triangles(renderer):
    s = uv_sphere(0.5, 1000, 1000, (0, 0.6, 0))
    assert s.n_faces >= 1_990_000
    img = _ok(_frame(renderer, [s, ground_plane(3.0)], sun_sky_cube(16, (0.3, 1, 0.2)),
                     settings=FrameSettings(64, 64, shadow_size=64), n_lights=6))
    assert (img[..., 3] > 0.5).sum() > 500
