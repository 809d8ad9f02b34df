"""Anti-aliasing (FrameSettings.aa_samples; renderer.py _coverage_pass and _edges_pass, shaders/edges/):
each pixel's coverage in alpha and its colour the mean over its area of the surfaces it shows,
against the coverage of the projected geometry computed exactly on the CPU."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from renderer.camera import Camera, bounds_sphere
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.renderer import Background, FrameSettings, ShadingMode
from renderer.shading.material import Material

SIZE = 48
CAM = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)
# A quad turned in its plane (its edges cross the pixel grid at every phase), in front of a wider one.
FRONT = np.array([[-0.45, -0.3, 0.0], [0.35, -0.42, 0.0], [0.42, 0.38, 0.0], [-0.3, 0.45, 0.0]])
BACK = np.array([[-2.0, -2.0, -0.5], [2.0, -2.0, -0.5], [2.0, 2.0, -0.5], [-2.0, 2.0, -0.5]])
RED, BLUE = (0.8, 0.1, 0.1), (0.1, 0.2, 0.8)


def _quad(corners: np.ndarray, name: str) -> Mesh:
    return Mesh.from_arrays(corners, np.array([[0, 1, 2], [0, 2, 3]]), name=name)


def _coverage(scene, corners: np.ndarray, n: int = 32) -> np.ndarray:
    """The share of each pixel (row 0 at the top) inside the projected convex quad, from n x n points."""
    lo, hi = scene.bounds()
    vp = CAM.view_proj(1.0, *bounds_sphere(lo, hi))
    clip = np.c_[corners, np.ones(4)] @ vp.T
    ndc = clip[:, :2] / clip[:, 3:]
    corners_px = np.stack([(ndc[:, 0] + 1) / 2 * SIZE, (1 - ndc[:, 1]) / 2 * SIZE], axis=1)
    t = (np.arange(SIZE * n) + 0.5) / n
    x, y = np.meshgrid(t, t)
    inside = np.ones(x.shape, bool)
    for a, b in zip(corners_px, np.roll(corners_px, -1, axis=0)):
        cross = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
        inside &= cross <= 0 if _clockwise(corners_px) else cross >= 0
    return inside.reshape(SIZE, n, SIZE, n).mean(axis=(1, 3))


def _clockwise(p: np.ndarray) -> bool:
    area = np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    return area < 0


@pytest.fixture(scope="module")
def uniform_pems(renderer):
    pems = renderer.build_pems(np.ones((6, 16, 16, 3), np.float32), PEMSettings(6))
    yield pems
    pems.release()


def _render(renderer, pems, meshes, materials, aa_samples, background=Background.BLACK):
    scene = renderer.create_scene(meshes, materials)
    try:
        fs = FrameSettings(SIZE, SIZE, mode=ShadingMode.NO_OCCLUSION, aa_samples=aa_samples, background=background)
        return renderer.render(scene, pems, fs, camera=CAM).image, _coverage(scene, meshes[0].positions)
    finally:
        scene.release()


def test_alpha_is_each_pixels_coverage_and_the_colour_is_premultiplied(renderer, uniform_pems):
    """A uniformly lit quad over nothing: alpha follows the exact coverage at its edges (4 samples: within
    their quantisation, where one sample a pixel is 0 or 1), and the colour is the quad's radiance
    times alpha."""
    errors = {}
    for n in (1, 4):
        image, exact = _render(renderer, uniform_pems, [_quad(FRONT, "front")], [Material(RED, specular=0.0)], n)
        edge = (exact > 0.02) & (exact < 0.98)
        assert edge.sum() > 40
        errors[n] = float(np.abs(image[..., 3] - exact)[edge].mean())
        inside = exact == 1.0
        radiance = np.median(image[inside][:, :3], axis=0)
        np.testing.assert_allclose(radiance, RED, rtol=0.05)
        np.testing.assert_allclose(image[..., :3], image[..., 3:4] * radiance, atol=2e-3 * radiance.max())
    assert set(np.unique(image[..., 3])) <= {0.0, 0.25, 0.5, 0.75, 1.0}
    assert errors[4] < 0.11 < 0.2 < errors[1], errors


def test_a_surface_over_another_is_mixed_by_its_coverage(renderer, uniform_pems):
    """A red quad in front of a blue one that fills the view: every pixel is covered (alpha 1) and its
    colour is red and blue in the red quad's share, found for the samples of the other surface in the
    neighbouring pixels that shaded it."""
    errors = {}
    for n in (1, 4):
        image, exact = _render(renderer, uniform_pems, [_quad(FRONT, "front"), _quad(BACK, "back")],
                               [Material(RED, specular=0.0), Material(BLUE, specular=0.0)], n)
        np.testing.assert_array_equal(image[..., 3], 1.0)
        red, blue = np.asarray(RED), np.asarray(BLUE)
        share = (image[..., :3] - blue) @ (red - blue) / np.dot(red - blue, red - blue)
        edge = (exact > 0.02) & (exact < 0.98)
        errors[n] = float(np.abs(share - exact)[edge].mean())
        np.testing.assert_allclose(share[(exact == 0) | (exact == 1)], exact[(exact == 0) | (exact == 1)], atol=0.03)
    assert errors[4] < 0.11 < 0.2 < errors[1], errors


def test_the_background_goes_under_the_edges(renderer):
    """With the map behind the garment, an edge pixel is its premultiplied colour over black plus the
    background in the share its surfaces leave uncovered; alpha stays the coverage."""
    cube = np.ones((6, 16, 16, 3), np.float32) * np.array([0.3, 0.6, 0.9], np.float32)
    pems = renderer.build_pems(cube, PEMSettings(6))
    try:
        over_black, _ = _render(renderer, pems, [_quad(FRONT, "front")], [Material(RED, specular=0.0)], 4)
        over_env, exact = _render(renderer, pems, [_quad(FRONT, "front")], [Material(RED, specular=0.0)], 4,
                                  Background.ENVIRONMENT)
    finally:
        pems.release()
    np.testing.assert_array_equal(over_env[..., 3], over_black[..., 3])
    behind = over_env[..., :3] - over_black[..., :3]
    np.testing.assert_allclose(behind, (1.0 - over_black[..., 3:4]) * np.array([0.3, 0.6, 0.9]), atol=0.02)
    assert ((over_black[..., 3] > 0) & (over_black[..., 3] < 1)).sum() > 40


def test_samples_beyond_the_driver_are_refused_naming_the_limit(renderer, uniform_pems):
    with pytest.raises(InvalidInputError, match="aa_samples must be"):
        FrameSettings(8, 8, aa_samples=3)
    most = renderer.gl.ctx.max_samples
    if most >= 8:
        pytest.skip(f"this GL renderer takes {most} samples a pixel: nothing in the setting's range is beyond it")
    scene = renderer.create_scene([_quad(FRONT, "front")], [Material(RED)])
    try:
        with pytest.raises(InvalidInputError, match=f"at most {most} on this GL renderer"):
            renderer.render(scene, uniform_pems, dataclasses.replace(FrameSettings(8, 8), aa_samples=8), camera=CAM)
    finally:
        scene.release()


@pytest.mark.parametrize("aa_samples", [1, 4])
def test_a_garment_edge_over_the_body_darkens_nothing_the_light_reaches(renderer, aa_samples):
    """Issue 59's 'dark line where the neckline crosses the body': a garment's edge 15 mm in front of the
    body, lit by a sun behind the camera, whose shadow so falls wholly behind the garment: the body's
    pixels beside the edge are lit as in the truth on the balanced preset's path (the shadow maps see the
    garment's edge over the body; the edges pass mixes the two surfaces there). On the bundled dress the
    line is the neckline's true shadow, 12-27 mm of cloth off the body under the studio's key light: the
    reference draws it at the same place, width and depth."""
    from conftest import balanced, balanced_pems, sun_sky_cube

    from renderer.reference import render_reference

    body = _quad(np.array([[-0.7, -0.7, 0.0], [0.7, -0.7, 0.0], [0.7, 0.7, 0.0], [-0.7, 0.7, 0.0]]), "body")
    garment = _quad(FRONT + np.array([0.0, 0.0, 0.015]), "garment")
    meshes, materials = [garment, body], [Material(RED, specular=0.0), Material((0.6, 0.6, 0.6), specular=0.0)]
    cube = sun_sky_cube(64, CAM.eye, sun_radiance=2e3, sun_radius_deg=3.0, sky=(0.02, 0.02, 0.02), ground=(0, 0, 0))
    pems = renderer.build_pems(cube, balanced_pems())
    scene = renderer.create_scene(meshes, materials)
    try:
        image = renderer.render(scene, pems, balanced(SIZE, SIZE, background=Background.BLACK, aa_samples=aa_samples),
                                camera=CAM).image
        share = _coverage(scene, garment.positions)
    finally:
        scene.release()
        pems.release()
    ref = render_reference(meshes, materials, cube, CAM, SIZE, SIZE, 64, seed=5, pixel_samples=2).foreground
    near = np.zeros_like(share, bool)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near |= np.roll(share > 0, (dy, dx), axis=(0, 1))
    beside = near & (share == 0) & (ref[..., 3] == 1.0)   # body alone, by the edge
    assert beside.sum() > 30
    ratio = image[..., :3].mean(axis=-1)[beside] / ref[..., :3].mean(axis=-1)[beside]
    # Measured: 0.98-1.03 at either sample count (the reference's noise ~1 %).
    assert np.median(ratio) > 0.97 and ratio.min() > 0.9, (np.median(ratio), ratio.min())
