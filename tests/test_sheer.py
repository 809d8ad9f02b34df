"""Sheer and transmitting cloth (issue 61 item 4; Material.alpha, Material.transmission): the garment
seen through in the right order, a sheer sheet's partial shadow, light through a thin fabric from
behind; the reference's exact model and the renderer's against it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import CAM, balanced, balanced_pems, plane, sphere, sun_sky_cube

from renderer.errors import InvalidInputError, MeshError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.reference.montecarlo import render_reference
from renderer.renderer import Background, FrameSettings, ShadingMode
from renderer.shading.material import Material

SIZE = 48
FRONT_CAM = CAM.__class__((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)
RED, BLUE = (0.8, 0.1, 0.1), (0.1, 0.2, 0.8)


def _quad(half: float, z: float, name: str) -> Mesh:
    p = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return Mesh.from_arrays(p, np.array([[0, 1, 2], [0, 2, 3]]), name=name)


def test_the_fields_are_checked():
    for bad in ({"alpha": 1.5}, {"alpha": float("nan")}, {"transmission": -0.1}):
        with pytest.raises(InvalidInputError):
            Material(RED, **bad)
    m = Material(RED, alpha=0.3, transmission=0.5)
    assert m.is_sheer and m.transmits and not Material(RED).is_sheer


def test_the_reference_sees_through_and_keeps_energy():
    """Under a uniform white sky a lone sheet of albedo a and transmission t shows (1 - t) of its own
    reflection plus t a (its fibres pass on the sky behind it: a Phong sheet shows a whatever t), and a sheet of alpha 0.5 shows half its
    own light and half the sky's, with alpha 0.5."""
    cube = np.ones((6, 8, 8, 3), np.float32)
    floor = plane(4.0, 0.0)
    cam = CAM.__class__((0.0, 3.0, 0.5), (0.0, 0.0, 0.0), fov_y_deg=30.0)
    albedo = np.array([0.5, 0.4, 0.3])
    for model in ("phong", "pbr"):
        glowing = render_reference([floor], [Material(tuple(albedo), model=model, transmission=0.6)], cube, cam, 8, 8,
                                   64, seed=1).image
        opaque = render_reference([floor], [Material(tuple(albedo), model=model)], cube, cam, 8, 8, 64, seed=1).image
        np.testing.assert_allclose(glowing[..., :3].mean(axis=(0, 1)),
                                   0.4 * opaque[..., :3].mean(axis=(0, 1)) + 0.6 * albedo, rtol=0.03)
        sheer = render_reference([floor], [Material(tuple(albedo), model=model, alpha=0.5)], cube, cam, 8, 8, 64,
                                 seed=1).image
        np.testing.assert_allclose(sheer[..., 3], 0.5, atol=1e-6)
        np.testing.assert_allclose(sheer[..., :3].mean(axis=(0, 1)),
                                   0.5 * opaque[..., :3].mean(axis=(0, 1)) + 0.5, rtol=0.03)


def test_a_sheet_of_alpha_zero_is_not_there_for_the_reference():
    cube = sun_sky_cube(16, (0.5, 1.0, 0.3), sun_radiance=200.0, sun_radius_deg=8)
    ball, floor = sphere(0.5, centre=(0.0, 0.5, 0.0)), plane(4.0, 0.0)
    grey = Material((0.5, 0.5, 0.5))
    without = render_reference([floor], [grey], cube, CAM, 24, 24, 64, seed=1)
    ghost = render_reference([ball, floor], [Material(RED, alpha=0.0), grey], cube, CAM, 24, 24, 64, seed=1)
    diff = np.abs(ghost.image[..., :3] - without.image[..., :3])
    assert float(diff.mean()) < 3.0 * float(np.nanmean(without.noise_std)) + 1e-3


@pytest.fixture(scope="module")
def uniform_pems(renderer):
    pems = renderer.build_pems(np.ones((6, 16, 16, 3), np.float32), PEMSettings(6))
    yield pems
    pems.release()


@pytest.mark.parametrize("aa_samples", [1, 4])
def test_the_renderer_shows_what_is_behind_a_sheer_sheet_in_order(renderer, uniform_pems, aa_samples):
    """A red sheet of alpha 0.4 before a blue one before a white sky: 0.4 red + 0.6 blue where both
    are, 0.4 red + 0.6 sky where the blue one is moved aside; alpha the share the meshes stop (1 over
    the blue, 0.4 over the sky, 0 on the sky alone), as the reference's. Without its layers (the sheet
    opaque) the test fails."""
    meshes = [_quad(0.3, 0.0, "front"), _quad(0.6, -0.5, "back")]
    right = [_quad(0.3, 0.0, "front"), _quad(0.6, -0.5, "back")]
    right[1] = Mesh.from_arrays(right[1].positions + [0.9, 0.0, 0.0], right[1].faces, name="back")
    for geometry, behind in ((meshes, np.array(BLUE)), (right, None)):
        scene = renderer.create_scene(geometry, [Material(RED, alpha=0.4), Material(BLUE)])
        try:
            fs = FrameSettings(SIZE, SIZE, mode=ShadingMode.NO_OCCLUSION, aa_samples=aa_samples,
                               background=Background.ENVIRONMENT)
            image = renderer.render(scene, uniform_pems, fs, camera=FRONT_CAM).image
        finally:
            scene.release()
        centre = image[SIZE // 2 - 2:SIZE // 2 + 2, SIZE // 2 - 6:SIZE // 2 - 2]
        seen = np.array(BLUE) if behind is not None else np.ones(3)
        np.testing.assert_allclose(centre[..., :3].mean(axis=(0, 1)), 0.4 * np.array(RED) + 0.6 * seen, atol=0.03)
        np.testing.assert_allclose(centre[..., 3], 1.0 if behind is not None else 0.4, atol=1e-4)
        assert image[0, 0, 3] == 0.0 and abs(image[0, 0, :3] - 1.0).max() < 0.01


def test_a_sheer_sheet_casts_its_share_of_shadow_as_the_reference_does(renderer):
    """A sheet of alpha 0.4 over a floor under a sun: the floor under it keeps 0.6 of its light, in the
    reference (exact) and the renderer (within 0.06)."""
    cube = sun_sky_cube(32, (0.0, 1.0, 0.2), sun_radiance=400.0, sun_radius_deg=5)
    sheet = Mesh.from_arrays(np.array([[-0.5, 0.6, -0.5], [0.5, 0.6, -0.5], [0.5, 0.6, 0.5], [-0.5, 0.6, 0.5]]),
                             np.array([[0, 2, 1], [0, 3, 2]]), name="sheet")
    floor = plane(4.0, 0.0)
    cam = CAM.__class__((0.0, 3.5, 2.0), (0.0, 0.0, 0.0), fov_y_deg=35.0)
    grey = Material((0.6, 0.6, 0.6))
    ratios = {}
    for alpha in (1.0, 0.4):
        mats = [Material(RED, alpha=alpha), grey]
        pems = renderer.build_pems(cube, balanced_pems())
        scene = renderer.create_scene([sheet, floor], mats)
        try:
            frame = renderer.render(scene, pems, balanced(SIZE, SIZE, background=Background.BLACK, aovs=("id",)), cam)
        finally:
            scene.release()
            pems.release()
        ids = frame.aovs["id"]
        lit = frame.image[..., :3].mean(-1)
        ref = render_reference([sheet, floor], mats, cube, cam, SIZE, SIZE, 64, seed=1).image[..., :3].mean(-1)
        free = render_reference([floor], [grey], cube, cam, SIZE, SIZE, 64, seed=2).image[..., :3].mean(-1)
        free_ours = np.median(lit[(ids == 2)][lit[ids == 2] > np.percentile(lit[ids == 2], 80)])
        # The floor seen beside the sheet, under its shadow's core: the pixels the reference says are
        # shadowed with the sheet opaque.
        if alpha == 1.0:
            core = (ids == 2) & (ref < 0.3 * free)
            assert core.sum() > 20
        ratios[alpha] = (float(np.median(lit[core]) / free_ours), float(np.median(ref[core] / free[core])))
    ours, exact = ratios[0.4]
    assert abs(exact - (0.6 + 0.4 * ratios[1.0][1])) < 0.05, ratios
    assert abs(ours - exact) < 0.06, ratios


@pytest.mark.parametrize("mode", [ShadingMode.FULL, ShadingMode.NO_OCCLUSION])
def test_light_through_a_thin_fabric_from_behind(renderer, mode):
    """A sheet lit from behind alone (the sun behind it, the camera in front): what shows is what its
    fibres pass on, transmission x albedo x the light behind; the renderer within 10 % of the
    reference (its occlusion off in the no-occlusion mode), little without transmission (the dim
    ground's light)."""
    cube = sun_sky_cube(32, (0.0, 0.3, -1.0), sun_radiance=300.0, sun_radius_deg=6, sky=0.0)
    sheet = _quad(0.6, 0.0, "sheet")
    out = {}
    for t in (0.0, 0.5):
        mats = [Material((0.8, 0.7, 0.5), alpha=1.0, transmission=t)]
        pems = renderer.build_pems(cube, balanced_pems())
        scene = renderer.create_scene([sheet], mats)
        try:
            image = renderer.render(scene, pems, balanced(SIZE, SIZE, background=Background.BLACK, mode=mode),
                                    FRONT_CAM).image
        finally:
            scene.release()
            pems.release()
        ref = render_reference([sheet], mats, cube, FRONT_CAM, SIZE, SIZE, 64, seed=1,
                               occlusion=mode is ShadingMode.FULL).image
        inner = slice(SIZE // 2 - 6, SIZE // 2 + 6)
        out[t] = (float(image[inner, inner, :3].mean()), float(ref[inner, inner, :3].mean()))
    assert out[0.0][1] < 0.05 and out[0.0][0] < 0.05, out   # the ground's light alone
    ours, exact = out[0.5]
    assert exact > 0.2 and abs(ours / exact - 1.0) < 0.1, out


def test_a_colourway_keeps_its_fabrics_open_weave(renderer):
    scene = renderer.create_scene([_quad(0.3, 0.0, "front")], [Material(RED, alpha=0.4)])
    try:
        with pytest.raises(MeshError, match="alpha"):
            scene.add_variant([Material(BLUE)])
        assert scene.add_variant([Material(BLUE, alpha=0.4, transmission=0.3)]) == 1
    finally:
        scene.release()


def test_the_voile_fabric_carries_its_alpha_and_transmission():
    from garment_lab.fabrics import fabric_archive
    from renderer.procedural import procedural_garment
    from renderer.u3m import load_u3m, material_from_u3m

    material, warnings = material_from_u3m(load_u3m(fabric_archive("voile"), name="voile.u3ma"),
                                           procedural_garment(16))
    assert (material.alpha, material.transmission) == pytest.approx((0.35, 0.5))
    assert not any("alpha" in w or "transmission" in w for w in warnings), warnings
    assert dataclasses.replace(material, alpha=1.0).is_sheer is False


def test_a_lace_shows_through_its_holes_where_the_reference_does(renderer, uniform_pems):
    """A red sheet whose alpha map is a checker of holes (TextureSet.alpha_map) before a blue one: the
    holes show blue, the rest red, pixel for pixel as the reference draws them (no occlusion, pixel
    centres); alpha 1 throughout (the blue sheet behind)."""
    from renderer.shading.material import TextureSet

    y, x = np.mgrid[:8, :8]
    holes = (((x // 2) + (y // 2)) % 2).astype(np.float32)[..., None]
    corners = np.array([[-0.4, -0.4, 0.0], [0.4, -0.4, 0.0], [0.4, 0.4, 0.0], [-0.4, 0.4, 0.0]])
    lace = Mesh.from_arrays(corners, np.array([[0, 1, 2], [0, 2, 3]]), uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]]),
                            name="lace")
    materials = [Material(RED, texture_sets=(TextureSet(alpha_map=holes),), texture_set=np.zeros(4, np.int32)),
                 Material(BLUE)]
    assert materials[0].is_sheer and materials[0].mean_alpha() == pytest.approx(0.5)
    meshes = [lace, _quad(0.6, -0.5, "back")]
    scene = renderer.create_scene(meshes, materials)
    try:
        fs = FrameSettings(SIZE, SIZE, mode=ShadingMode.NO_OCCLUSION, background=Background.BLACK)
        image = renderer.render(scene, uniform_pems, fs, camera=FRONT_CAM).image
    finally:
        scene.release()
    ref = render_reference(meshes, materials, np.ones((6, 16, 16, 3), np.float32), FRONT_CAM, SIZE, SIZE, 16,
                           occlusion=False).image
    inner = (slice(SIZE // 2 - 10, SIZE // 2 + 10),) * 2
    ours, exact = image[inner][..., :3], ref[inner][..., :3]
    red = exact[..., 0] > exact[..., 2]
    assert 0.3 < red.mean() < 0.7   # both show holes and fibre
    # The texels' edges fall between pixel centres alike; bilinear filtering blurs them a little.
    assert (np.abs(ours - exact).max(axis=-1) < 0.1).mean() > 0.85
    np.testing.assert_allclose(image[inner][..., 3], 1.0, atol=1e-4)


def test_a_u3m_alpha_texture_is_carried_at_its_size(tmp_path):
    """A U3M lace (its alpha a texture 20 mm wide) becomes the material's alpha map, placed at its
    physical size, no warning."""
    from u3m_files import document, encode, image, scalar, scalar_texture, visualisation, write_u3ma

    from renderer.procedural import procedural_garment
    from renderer.u3m import load_u3m, material_from_u3m

    y, x = np.mgrid[:16, :16]
    holes = np.where(((x // 4) + (y // 4)) % 2 == 0, 255, 0).astype(np.uint8)
    front = visualisation("1.1", alpha=scalar(1.0, scalar_texture(image("lace.png", "1.1", 20.0, 20.0))),
                          transmission=scalar(0.2))
    path = write_u3ma(tmp_path / "lace.u3ma", document("1.1", front), {"lace.png": encode(holes)})
    material, warnings = material_from_u3m(load_u3m(path), procedural_garment(16), uv_scale=(1.0, 1.0))
    ts = material.texture_sets[0]
    assert ts.alpha_map is not None and ts.alpha_map.shape == (16, 16, 1) and material.alpha == 1.0
    assert material.mean_alpha() == pytest.approx(0.5, abs=0.01) and material.transmission == pytest.approx(0.2)
    # 20 mm a repeat: 50 repeats a metre of the garment's UVs.
    np.testing.assert_allclose(np.abs(ts.placement("alpha")[:, :2]).max(), 50.0, rtol=1e-6)
    assert not any("alpha" in w for w in warnings), warnings
