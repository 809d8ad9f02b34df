"""Materials per vertex and from textures: woven fabrics mix yarns of different sheen."""

import numpy as np
import pytest

from renderer.camera import Camera
from renderer.errors import InvalidInputError, MeshError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.renderer import Background, FrameSettings, ShadingMode
from renderer.shading.material import Material

CAM = Camera((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), fov_y_deg=40.0)
QUAD_P = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
UNSHADOWED = FrameSettings(64, 64, mode=ShadingMode.NO_OCCLUSION, background=Background.BLACK)


@pytest.fixture(scope="module")
def white_pems(renderer):
    pems = renderer.build_pems(np.ones((6, 16, 16, 3), np.float32), PEMSettings(6))
    yield pems
    pems.release()


def _render(renderer, pems, mesh, material):
    scene = renderer.create_scene([mesh], [material])
    try:
        return renderer.render(scene, pems, UNSHADOWED, CAM).image
    finally:
        scene.release()


def test_albedo_map_colours_the_surface_by_uv(renderer, white_pems):
    tex = np.zeros((8, 8, 3), np.float32)
    tex[:, :4] = (1, 0, 0)   # left half of the image red
    tex[:, 4:] = (0, 1, 0)   # right half green
    mesh = Mesh.from_arrays(QUAD_P, QUAD_F, uvs=QUAD_UV)
    img = _render(renderer, white_pems, mesh, Material((1, 1, 1), 0.0, 0.0, albedo_map=tex))
    left, right = img[32, 20, :3], img[32, 44, :3]
    np.testing.assert_allclose(left, (1, 0, 0), atol=0.02)
    np.testing.assert_allclose(right, (0, 1, 0), atol=0.02)


def test_per_vertex_albedo_is_interpolated(renderer, white_pems):
    mesh = Mesh.from_arrays(QUAD_P, QUAD_F)
    albedo = np.array([[1, 0, 0], [0, 0, 1], [0, 0, 1], [1, 0, 0]], np.float32)  # red left, blue right
    img = _render(renderer, white_pems, mesh, Material(albedo, 0.0, 0.0))
    assert img[32, 12, 0] > 0.8 and img[32, 12, 2] < 0.2
    assert img[32, 52, 2] > 0.8 and img[32, 52, 0] < 0.2


def test_gloss_map_changes_sheen_per_texel(renderer):
    # A sun-like spot reflected by a mirror half and a diffuse half of the same quad.
    from conftest import sun_sky_cube

    cube = sun_sky_cube(64, (0, 0, 1), sun_radiance=100.0, sun_radius_deg=10, sky=(0, 0, 0), ground=(0, 0, 0))
    pems = renderer.build_pems(cube, PEMSettings(6))
    gm = np.zeros((4, 4, 2), np.float32)
    gm[..., 0] = 1.0
    gm[:, :2, 1] = 1.0   # left: mirror
    gm[:, 2:, 1] = 0.0   # right: diffuse lobe
    p = QUAD_P.copy()
    p[:, 0] *= 0.2       # a narrow quad near the optical axis: the mirror sees the spot
    mesh = Mesh.from_arrays(p, QUAD_F, uvs=QUAD_UV)
    try:
        img = _render(renderer, pems, mesh, Material((0, 0, 0), 0.0, 0.0, gloss_map=gm))
    finally:
        pems.release()
    cov = img[..., 3] > 0.5
    cols = np.nonzero(cov.any(axis=0))[0]
    mid = (cols.min() + cols.max()) // 2
    mirror = img[20:44, cols.min() + 1:mid - 1, 0]
    diffuse = img[20:44, mid + 2:cols.max(), 0]
    assert mirror.mean() > 5 * diffuse.mean() > 0


def test_bad_materials_are_rejected_with_a_reason():
    with pytest.raises(InvalidInputError, match="glossiness"):
        Material(glossiness=1.5).vertex_arrays(3)
    with pytest.raises(InvalidInputError, match="NaN"):
        Material(albedo=(np.nan, 0, 0)).vertex_arrays(3)
    with pytest.raises(InvalidInputError, match=r"shape \(3,\) or \(4, 3\)"):
        Material(albedo=np.ones((5, 3))).vertex_arrays(4)


def test_material_maps_need_uvs(renderer):
    with pytest.raises(MeshError, match="UVs"):
        renderer.create_scene([Mesh.from_arrays(QUAD_P, QUAD_F)], [Material(albedo_map=np.ones((2, 2, 3)))])


def test_the_material_fields_are_declared_once_and_every_interface_takes_them():
    """The registry (renderer/shading/fields.py) makes the command line's flags, the material files'
    fields, the service's MaterialSpec and docs/materials.md's table; Material takes each field and
    refuses a scalar field's value outside its range with the registry's words."""
    from pathlib import Path

    from renderer.cli import MATERIAL_FIELDS, build_parser
    from renderer.shading import fields
    from service.schemas import MaterialSpec

    names = [f.name for f in fields.FIELDS]
    assert list(MATERIAL_FIELDS) == ["model", *names]
    render = build_parser()._subparsers._group_actions[0].choices["render"]
    flags = {opt for action in render._actions for opt in action.option_strings}
    assert {f.flag for f in fields.FIELDS} <= flags
    assert set(names) | {"model"} <= set(MaterialSpec.model_fields)
    for f in fields.FIELDS:
        assert MaterialSpec.model_fields[f.name].default == (list(f.default) if f.kind == "colour" else f.default)
        assert f.name in Material.__dataclass_fields__
    doc = (Path(__file__).resolve().parents[1] / "docs" / "materials.md").read_text()
    assert fields.reference_table() in doc, "docs/materials.md's table is stale: renderer.shading.fields.reference_table()"
    with pytest.raises(InvalidInputError, match=r"anisotropy_rotation must lie in \[-1, 1\]"):
        Material(model="pbr", anisotropy_rotation=2.0)


def test_a_print_seen_obliquely_keeps_its_stripes(renderer, white_pems):
    """Material maps are read at the MIP level of the pixel footprint's area (gbuffer.frag, area_lod):
    stripes along a floor that recedes from the camera stay stripes near the horizon, where GL's own
    level, set by the footprint's long side, greys them out (measured at that row: a contrast of 0.0
    at GL's level, 0.29 at the area's, 0.63 with 16x anisotropic filtering; the stripes' own is 1)."""
    p = np.array([[-1, 0, 0], [1, 0, 0], [1, 0, -20], [-1, 0, -20]], np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 5], [0, 5]], np.float32)
    tex = np.zeros((256, 256, 3), np.float32)
    tex[:, (np.arange(256) // 16) % 2 == 0] = 1.0      # 8 stripes across u, none along v
    floor = Mesh.from_arrays(p, np.array([[0, 1, 2], [0, 2, 3]]), uvs=uv)
    scene = renderer.create_scene([floor], [Material((1, 1, 1), 0.0, 0.0, albedo_map=tex)])
    try:
        img = renderer.render(scene, white_pems, FrameSettings(96, 96, mode=ShadingMode.NO_OCCLUSION,
                                                               background=Background.BLACK),
                              Camera((0.0, 0.3, 1.0), (0.0, 0.0, -5.0), fov_y_deg=40.0)).image
    finally:
        scene.release()
    lum, covered = img[..., :3].mean(axis=-1), img[..., 3] > 0.99
    far = next(row for row in range(96) if covered[row].sum() >= 40)   # the farthest row of 40 pixels or more
    values = lum[far][covered[far]]
    assert values.std() / values.mean() > 0.2, (far, values.std() / values.mean())
