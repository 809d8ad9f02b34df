"""The environment turned about the up axis (issue 62 item 1): FrameSettings.environment_rotation_deg,
the command line's --env-rotation. The PEM set is not built again: its lights' directions turn and its
textures are read through the inverse turn (PEMSet.turned). Checked against the tracer under the same
map with its texels turned, and against a PEM set built from that turned map."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import CAM, balanced, balanced_pems, plane, sphere

from renderer.envmap.cube import texel_directions
from renderer.errors import InvalidInputError
from renderer.reference import relative_rmse
from renderer.reference.montecarlo import render_reference
from renderer.renderer import FrameSettings
from renderer.shading.material import Material

FACE = 64
SIZE = 64
MATERIALS = [Material((0.7, 0.6, 0.5), 0.3, 0.8), Material((0.5, 0.5, 0.5), 0.0, 0.3)]


def turn_y(degrees: float) -> np.ndarray:
    """The turn about +Y, counter-clockwise seen from above: +X goes to -Z at +90."""
    a = np.radians(degrees)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def studio(degrees: float = 0.0) -> np.ndarray:
    """A map with no symmetry about the up axis, turned `degrees`: a warm sun to the camera's right
    and above, a blue wall on its left, a dim sky, a dark floor (the radiance of direction d is the
    unturned map's at R^T d, so the turned cube is exact, not resampled)."""
    d = texel_directions(FACE).astype(np.float64) @ turn_y(degrees)   # rows: R^T d
    sun = np.array([0.8, 0.6, 0.3]) / np.linalg.norm([0.8, 0.6, 0.3])
    cube = np.where(d[..., 1:2] > 0.0, np.array([0.25, 0.3, 0.35]), np.array([0.05, 0.05, 0.05]))
    cube = np.where((d[..., 0:1] < -0.6) & (d[..., 1:2] > -0.2), np.array([0.1, 0.2, 0.9]), cube)
    cube = np.where((d @ sun)[..., None] > np.cos(np.radians(5.0)), np.array([300.0, 250.0, 180.0]), cube)
    return cube.astype(np.float32)


@pytest.fixture(scope="module")
def scene(renderer):
    s = renderer.create_scene([sphere(0.5, centre=(0.0, 0.5, 0.0)), plane(4.0, 0.0)], MATERIALS)
    yield s
    s.release()


@pytest.fixture(scope="module")
def pems(renderer):
    p = renderer.build_pems(studio(), balanced_pems())
    yield p
    p.release()


@pytest.mark.parametrize("degrees", [90.0, 200.0])
def test_a_turned_map_renders_as_the_tracer_draws_the_map_turned(renderer, scene, pems, degrees):
    """The sphere and its shadow on the floor under the map turned: as near the tracer's render of the
    turned texels as the unturned frame is to the unturned map's, and far from the unturned frame."""
    meshes = [sphere(0.5, centre=(0.0, 0.5, 0.0)), plane(4.0, 0.0)]
    turned = renderer.render(scene, pems, balanced(SIZE, SIZE, environment_rotation_deg=degrees), CAM).image
    still = renderer.render(scene, pems, balanced(SIZE, SIZE), CAM).image
    ref_turned = render_reference(meshes, MATERIALS, studio(degrees), CAM, SIZE, SIZE, spp=64).image
    ref_still = render_reference(meshes, MATERIALS, studio(), CAM, SIZE, SIZE, spp=64).image
    err, err_still = relative_rmse(turned, ref_turned), relative_rmse(still, ref_still)
    assert err < 0.2 and err < 1.5 * err_still + 0.02, (err, err_still)
    assert relative_rmse(still, ref_turned) > 3.0 * err   # the turn is seen: light, shadow and background


def test_turning_reads_the_set_as_a_set_built_from_the_turned_map_would(renderer, scene, pems):
    """A quarter turn: the turned view of one set and a set built anew from the turned texels give
    the same picture but for the median cut's own cuts (the two sets' regions differ); the view
    builds nothing, keeps its textures, and is the same object for the same angle."""
    quarter = pems.turned(90.0)
    assert quarter is pems.turned(450.0) and pems.turned(0.0) is pems and quarter.turned(0.0) is pems
    assert quarter.textures is pems.textures and quarter.regions.n_regions == pems.regions.n_regions
    np.testing.assert_allclose(quarter.regions.directions, pems.regions.directions @ turn_y(90.0).T, atol=1e-12)
    built = renderer.build_pems(studio(90.0), balanced_pems())
    try:
        anew = renderer.render(scene, built, balanced(SIZE, SIZE), CAM).image
    finally:
        built.release()
    viewed = renderer.render(scene, pems, balanced(SIZE, SIZE, environment_rotation_deg=90.0), CAM).image
    assert relative_rmse(viewed, anew) < 0.08
    with pytest.raises(InvalidInputError, match="released with the set"):
        quarter.release()


def test_a_rotation_is_an_angle_and_a_bad_one_is_refused():
    assert FrameSettings(environment_rotation_deg=-90.0).environment_rotation_deg == 270.0
    assert FrameSettings(environment_rotation_deg=720.0).environment_rotation_deg == 0.0
    for bad in (float("nan"), float("inf"), "90", True):
        with pytest.raises(InvalidInputError, match="environment rotation"):
            FrameSettings(environment_rotation_deg=bad)
