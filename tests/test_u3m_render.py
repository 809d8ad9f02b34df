"""A U3M fabric on a garment (renderer/u3m/place.py): its textures at their physical size whatever the
UV layout, rotated and mirrored as the document says, in the renderer and in the reference alike, and
from the command line; what the material does not carry is said."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from u3m_files import (
    color,
    color_texture,
    document,
    encode,
    image,
    normal,
    scalar,
    scalar_texture,
    visualisation,
    write_u3ma,
)

from renderer.camera import Camera
from renderer.errors import MaterialError
from renderer.lighting.pem import PEMSettings
from renderer.mesh import Mesh
from renderer.reference import render_reference
from renderer.renderer import Background, FrameSettings, ShadingMode
from renderer.u3m import Face, load_u3m, material_from_u3m, uv_metres
from renderer.u3m.place import placement

ROOT = Path(__file__).resolve().parents[1]
CAM = Camera((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)
SIZE = 128
UNSHADOWED = FrameSettings(SIZE, SIZE, mode=ShadingMode.NO_OCCLUSION, background=Background.BLACK)


def quad(width: float, height: float, uv_span: tuple[float, float], n: int = 8) -> Mesh:
    """A flat (n x n)-cell sheet `width` x `height` metres facing +z, its UVs spanning `uv_span`."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    p = np.stack([(s - 0.5) * width, (t - 0.5) * height, np.zeros_like(s)], -1).reshape(-1, 3)
    uv = np.stack([s * uv_span[0], t * uv_span[1]], -1).reshape(-1, 2)
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()
    faces = np.concatenate([np.stack([k, k + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + n + 1], 1)])
    return Mesh.from_arrays(p.astype(np.float32), faces, uvs=uv.astype(np.float32), name="sheet")


def checker(pixels: int = 64, squares: int = 2) -> np.ndarray:
    """An sRGB-white and black checker, `squares` x `squares` squares."""
    y, x = np.mgrid[:pixels, :pixels] * squares // pixels
    return np.where(((x + y) % 2 == 0)[..., None], 255, 0).astype(np.uint8).repeat(3, axis=2)


def check_fabric(tmp_path: Path, width_mm: float = 50.0, rotation: float = 0.0, mode: str = "normal",
                 version: str = "1.1", **fields) -> Path:
    """A fabric whose base colour is a 2 x 2 checker one image of `width_mm` square."""
    img = image("check.png", version, width_mm, width_mm, rotation=rotation, mode=mode)
    front = visualisation(version, basecolor=color(texture=color_texture(img)), roughness=scalar(0.8), **fields)
    return write_u3ma(tmp_path / "check.u3ma", document(version, front), {"check.png": encode(checker())})


@pytest.fixture(scope="module")
def white(renderer):
    pems = renderer.build_pems(np.ones((6, 16, 16, 3), np.float32), PEMSettings(6))
    yield np.ones((6, 16, 16, 3), np.float32), pems
    pems.release()


def _render(renderer, pems, mesh, material):
    scene = renderer.create_scene([mesh], [material])
    try:
        return renderer.render(scene, pems, UNSHADOWED, CAM).image
    finally:
        scene.release()


def _period_px(row: np.ndarray) -> float:
    """The dominant period (pixels) of a row's luminance."""
    x = row - row.mean()
    spectrum = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    k = int(np.argmax(spectrum[2:])) + 2
    return len(x) / k


def test_the_uvs_scale_is_measured_on_the_mesh_whatever_their_unit():
    assert uv_metres(quad(0.5, 0.3, (1.0, 1.0))) == pytest.approx((0.5, 0.3))
    assert uv_metres(quad(0.5, 0.3, (4.0, 2.0))) == pytest.approx((0.125, 0.15))
    # A few triangles whose UVs collapse do not move it.
    sheet = quad(1.0, 1.0, (1.0, 1.0), n=16)
    uvs = sheet.uvs.copy()
    uvs[:3] = uvs[0]
    assert uv_metres(Mesh.from_arrays(sheet.positions, sheet.faces, uvs=uvs)) == pytest.approx((1.0, 1.0))
    with pytest.raises(MaterialError, match="no UVs"):
        uv_metres(Mesh.from_arrays(sheet.positions, sheet.faces))
    with pytest.raises(MaterialError, match="cover no area"):
        uv_metres(Mesh.from_arrays(sheet.positions, sheet.faces, uvs=np.zeros_like(uvs)))


def test_a_placement_puts_one_image_on_its_millimetres_turned_by_its_rotation(tmp_path):
    fabric = load_u3m(check_fabric(tmp_path, 50.0, rotation=90.0))
    tex = fabric.front.basecolor
    a = placement(tex, (0.5, 0.25))          # a UV unit: 0.5 m along u, 0.25 m along v
    step_u = a[:, :2] @ (0.1, 0.0)           # 5 cm along u ...
    step_v = a[:, :2] @ (0.0, 0.2)           # ... and along v
    # Turned a quarter: 5 cm along the garment's u is one image along the texture's -v, along v its +u.
    np.testing.assert_allclose(step_u, (0.0, -1.0), atol=1e-12)
    np.testing.assert_allclose(step_v, (1.0, 0.0), atol=1e-12)


def test_a_5_cm_check_is_5_cm_on_the_garment_whatever_the_uv_layout(renderer, white, tmp_path):
    """The same sheet with UVs over one unit and over four: the checker's period in the picture is the
    same, and it is what 5 cm at that distance is in pixels (without placement it is 4x apart)."""
    fabric = load_u3m(check_fabric(tmp_path, 50.0))
    _, pems = white
    periods = []
    for span in ((1.0, 1.0), (4.0, 4.0)):
        sheet = quad(0.4, 0.4, span)
        material, warnings = material_from_u3m(fabric, sheet)
        img = _render(renderer, pems, sheet, material)
        periods.append(_period_px(img[SIZE // 2, SIZE // 4:3 * SIZE // 4, :3].mean(axis=1)))
    pixels_per_metre = SIZE / (2 * 2.0 * np.tan(np.radians(15.0)))
    assert periods[0] == pytest.approx(periods[1], rel=0.05)
    assert periods[0] == pytest.approx(0.05 * pixels_per_metre, rel=0.1)


@pytest.mark.parametrize("rotation, mode", [(0.0, "normal"), (30.0, "normal"), (0.0, "mirror_x")])
def test_a_fabric_renders_as_the_reference_renders_it(renderer, white, tmp_path, rotation, mode):
    """Base colour, roughness and metalness textures and a normal map, placed, rotated, mirrored: the
    renderer's picture against the reference's, which places them the same way (montecarlo.py)."""
    version = "1.1"
    # Features of several pixels (a 12 px square, a 7 px bump): the renderer's mipmaps and the
    # reference's point samples then see the same texture.
    img = image("check.png", version, 200.0, 200.0, rotation=rotation, mode=mode)
    bumps = np.zeros((32, 32, 3), np.uint8)
    y = np.arange(32)[:, None]
    bumps[..., 0] = (128 + 60 * np.sin(2 * np.pi * y / 32)).astype(np.uint8).repeat(32, 1)
    bumps[..., 1] = 128
    bumps[..., 2] = 230
    rough = np.tile(np.linspace(60, 250, 64, dtype=np.uint8)[None, :, None], (64, 1, 3))
    front = visualisation(version, basecolor=color(texture=color_texture(img)),
                          roughness=scalar(0.5, scalar_texture(image("rough.png", version, 80.0, 80.0,
                                                                     rotation=rotation, mode=mode))),
                          normal=normal(version, image("bumps.png", version, 60.0, 60.0, rotation=rotation)))
    path = write_u3ma(tmp_path / "fabric.u3ma", document(version, front),
                      {"check.png": encode(checker(64, 2)), "rough.png": encode(rough), "bumps.png": encode(bumps)})
    sheet = quad(0.4, 0.4, (2.0, 2.0))
    material, _ = material_from_u3m(load_u3m(path), sheet)
    cube, pems = white
    ours = _render(renderer, pems, sheet, material)
    ref = render_reference([sheet], [material], cube, CAM, SIZE, SIZE, spp=16, occlusion=False, pixel_samples=4).image
    inside = (ours[..., 3] > 0.99) & (ref[..., 3] > 0.99)
    diff = np.abs(ours[inside, :3] - ref[inside, :3]).mean() / ref[inside, :3].mean()
    assert diff < 0.05, diff
    # The picture is the fabric's: the same render of a plain grey differs by far more.
    plain = _render(renderer, pems, sheet, type(material)((0.5, 0.5, 0.5), model="pbr", roughness=0.5))
    assert np.abs(plain[inside, :3] - ref[inside, :3]).mean() / ref[inside, :3].mean() > 4 * diff


def test_what_the_material_does_not_carry_is_said(tmp_path):
    version = "1.1"
    front = visualisation(version, basecolor=color((0.5, 0.2, 0.2)), clearcoat_value=scalar(0.6),
                          subsurface_value=scalar(0.3), anisotropy_value=scalar(1.5), anisotropy_rotation=scalar(0.25))
    back = visualisation(version, basecolor=color((0.1, 0.1, 0.1)), anisotropy_value=scalar(0.5))
    path = write_u3ma(tmp_path / "voile.u3ma", document(version, front, back), {})
    material, warnings = material_from_u3m(load_u3m(path), quad(0.4, 0.4, (1.0, 1.0)), Face.FRONT)
    said = "\n".join(warnings)
    for word in ("clearcoat_value", "subsurface_value"):
        assert word in said, said
    assert "back" not in said   # the back is drawn: Material.back
    # Anisotropy is carried, each side's own, beyond the renderer's range clamped and said.
    assert "anisotropy_value: 1.5" in said and "1 is used" in said
    assert (material.anisotropy, material.anisotropy_rotation) == (1.0, 0.25)
    assert (material.back.anisotropy, material.back.anisotropy_rotation) == (0.5, 0.0)
    # The document's colours are sRGB-encoded; the material's are linear.
    assert material.is_pbr and material.albedo == pytest.approx((0.2140, 0.0331, 0.0331), abs=1e-4)
    assert material.back.albedo == pytest.approx((0.0100,) * 3, abs=1e-4)


@pytest.mark.parametrize("has_back", [True, False])
def test_each_side_of_the_cloth_shows_its_own_visualisation(renderer, white, tmp_path, has_back):
    """A sheet seen from its front and from behind: the front's red and the back's checker (the front's
    red on both sides where the back is null, as the spec says), in the renderer as in the reference."""
    version = "1.1"
    front = visualisation(version, basecolor=color((0.8, 0.1, 0.1)))
    back = visualisation(version, basecolor=color(texture=color_texture(image("check.png", version, 200.0, 200.0))))
    path = write_u3ma(tmp_path / "two.u3ma", document(version, front, back if has_back else None),
                      {"check.png": encode(checker(64, 2))})
    sheet = quad(0.4, 0.4, (1.0, 1.0))
    material, _ = material_from_u3m(load_u3m(path), sheet)
    assert (material.back is not None) == has_back
    cube, pems = white
    behind = Camera((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), fov_y_deg=30.0)
    scene = renderer.create_scene([sheet], [material])
    try:
        seen = {name: renderer.render(scene, pems, UNSHADOWED, cam).image for name, cam in (("front", CAM),
                                                                                               ("back", behind))}
    finally:
        scene.release()
    for name, cam in (("front", CAM), ("back", behind)):
        img = seen[name]
        inside = img[..., 3] > 0.99
        rgb = img[inside, :3]
        if name == "front" or not has_back:
            assert rgb[:, 0].mean() > 3 * rgb[:, 1].mean()   # red
        else:
            assert rgb[:, 0].mean() == pytest.approx(rgb[:, 1].mean(), rel=0.05)   # grey checker
            assert rgb[:, 1].std() > 0.2 * rgb[:, 1].mean()
        ref = render_reference([sheet], [material], cube, cam, SIZE, SIZE, spp=16, occlusion=False,
                               pixel_samples=4).image
        both = inside & (ref[..., 3] > 0.99)
        assert np.abs(img[both, :3] - ref[both, :3]).mean() / ref[both, :3].mean() < 0.05


def test_render_takes_a_u3m_fabric_and_says_what_it_leaves_out(tmp_path):
    version = "1.1"
    path = check_fabric(tmp_path, 50.0, version=version, clearcoat_value=scalar(0.5))
    out = tmp_path / "frame.png"
    done = subprocess.run([sys.executable, "-m", "renderer.cli", "render", "--size", "64x64", "--preset", "fast",
                           "--material", str(path), "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "check.u3ma: clearcoat_value: not carried yet" in done.stderr
    from PIL import Image

    assert np.asarray(Image.open(out)).std() > 1.0


def test_the_fabric_benchs_fabrics_load_as_a_users_would_and_say_what_is_not_carried():
    """lab/garment_lab/fabrics.py writes its fabrics with renderer/u3m/write.py: each reads back through
    load_u3m (the schema, the images), on a sheet with UVs, with the fields the renderer leaves out named."""
    from garment_lab.fabrics import FABRIC_NAMES, fabric_archive

    expected = {}
    sheet = quad(0.5, 0.5, (1.0, 1.0))
    for name in FABRIC_NAMES:
        fabric = load_u3m(fabric_archive(name), name=f"{name}.u3ma")
        material, warnings = material_from_u3m(fabric, sheet)
        assert {w.split(":")[0] for w in warnings} == expected.get(name, set()), (name, warnings)
        assert material.is_pbr and material.anisotropy == (0.8 if name == "satin" else 0.0)
    denim = load_u3m(fabric_archive("denim"), name="denim.u3ma").front
    assert denim.basecolor.width_mm == 8.0 and denim.normal.rotation_deg == 20.0


def test_the_writer_writes_linear_colours_as_the_spec_stores_them(tmp_path):
    from renderer.u3m import ColorConstant
    from renderer.u3m.write import document, u3ma_bytes, visualisation

    fabric = load_u3m(u3ma_bytes(document("Red", visualisation(basecolor=(0.2140, 0.0331, 0.0331))), {}),
                      name="red.u3ma")
    assert isinstance(fabric.front.basecolor, ColorConstant)
    assert fabric.front.basecolor.rgb == pytest.approx((0.2140, 0.0331, 0.0331), abs=2e-4)
    with pytest.raises(ValueError, match="no U3M field shine"):
        visualisation(shine=1.0)


@pytest.mark.system
def test_the_fabric_bench_runs_and_reports_textured_against_plain(tmp_path):
    from garment_lab.scenes import shared_assets

    if not (shared_assets() / "hdri").is_dir():
        pytest.skip(f"the fabric bench needs the shared assets ({shared_assets()})")
    done = subprocess.run([sys.executable, "-m", "renderer.cli", "bench", "--fabrics", "--quick", "--out",
                           str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    import json

    data = json.loads((tmp_path / "fabrics.json").read_text())
    rows = data["rows"]
    assert {(r["fabric"], r["textured"], r["preset"]) for r in rows} == {
        (f, t, p) for f in ("print", "denim") for t in (True, False) for p in ("fast", "balanced")}
    assert all(np.isfinite(r["rel_rmse"]) and r["frame_ms"] > 0 for r in rows)
    assert "| balanced | denim |" in (tmp_path / "fabrics.md").read_text()
