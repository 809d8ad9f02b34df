"""One frame from several cameras and in several colourways (Renderer.render_views, Scene.add_variant,
renderer/views.py): the shared shadow pass gives each view the image a frame of its own gives, a
colourway the image of a scene registered with it, and the command line writes the views and their
contact sheet."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import plane, sphere, sun_sky_cube
from PIL import Image

from renderer.camera import frame_meshes
from renderer.errors import InvalidInputError, MeshError
from renderer.lighting.pem import PEMSettings
from renderer.renderer import FrameSettings
from renderer.shading.material import Material
from renderer.views import contact_sheet, named_views, turntable

GARMENT = Material((0.7, 0.3, 0.2), 0.3, 0.7)
RED = Material((0.9, 0.05, 0.05), 0.5, 0.9)


@pytest.fixture
def setup(renderer):
    cube = sun_sky_cube(32, (0.4, 0.8, 0.3), sun_radiance=300.0, sun_radius_deg=4.0)
    pems = renderer.build_pems(cube, PEMSettings(lights=12))
    meshes = [sphere(0.4, centre=(0.0, 0.5, 0.0)), plane(3.0, 0.0)]
    scene = renderer.create_scene(meshes, [GARMENT, Material((0.5, 0.5, 0.5))])
    yield renderer, pems, scene, meshes
    scene.release()
    pems.release()


def test_views_that_see_the_whole_scene_are_the_frames_each_camera_renders_alone(setup):
    r, pems, scene, meshes = setup
    settings = FrameSettings(48, 48)
    together = r.render_views(scene, pems, settings, turntable(frame_meshes(meshes[:1]), 4))
    # Each alone fits its maps to what it sees; together they are fitted to what any of them sees.
    # Cameras framing the whole floor see everything: then the two are one frame.
    wide = named_views(frame_meshes(meshes), ["front", "left", "three-quarter"])
    alone = [r.render(scene, pems, settings, c).image for c in wide]
    shared = r.render_views(scene, pems, settings, wide)
    for a, b in zip(alone, shared):
        np.testing.assert_array_equal(a, b.image)
    assert len(together) == 4 and [f.timings["views"] for f in together] == [4] * 4
    # The shared stages are the first frame's; the others have their own passes only.
    assert "shadow_maps" in together[0].timings["wall_ms"]
    assert all("shadow_maps" not in f.timings["wall_ms"] and "shading" in f.timings["wall_ms"] for f in together[1:])
    # Four different views of the lit sphere: no two images alike.
    means = [f.image[..., :3].mean() for f in together]
    assert len({round(float(m), 5) for m in means}) == 4


def test_a_colourway_is_the_frame_of_a_scene_registered_with_it(setup):
    r, pems, scene, meshes = setup
    settings = FrameSettings(48, 48)
    k = scene.add_variant([RED, None])
    assert k == 1 and scene.n_variants == 2
    base, red = r.render_views(scene, pems, settings, [None], variants=[0, 1])
    other = r.create_scene(meshes, [RED, Material((0.5, 0.5, 0.5))])
    try:
        np.testing.assert_array_equal(red.image, r.render(other, pems, settings).image)
    finally:
        other.release()
    np.testing.assert_array_equal(base.image, r.render(scene, pems, settings).image)
    assert red.image[..., 0].sum() > base.image[..., 0].sum() and red.image[..., 1].sum() < base.image[..., 1].sum()
    scene.drop_variants()
    assert scene.n_variants == 1
    with pytest.raises(InvalidInputError, match="variant 1 is not in the scene"):
        r.render_views(scene, pems, settings, variants=[1])


def test_bad_colourways_and_views_are_refused_with_what_is_wrong(setup):
    _, _, scene, _ = setup
    with pytest.raises(MeshError, match="physically based"):
        scene.add_variant([Material(model="pbr"), None])
    with pytest.raises(MeshError, match="one material \\(or None\\) per mesh: 2, got 1"):
        scene.add_variant([RED])
    with pytest.raises(InvalidInputError, match="unknown view"):
        named_views(frame_meshes([sphere()]), ["front", "sideways"])
    with pytest.raises(InvalidInputError, match="1 to 64 views"):
        turntable(frame_meshes([sphere()]), 0)


def test_a_turntable_turns_the_camera_about_its_target():
    base = frame_meshes([sphere()])
    cams = turntable(base, 4)
    assert cams[0].eye == pytest.approx(base.eye)
    d0 = np.subtract(cams[0].eye, base.target)
    d1 = np.subtract(cams[1].eye, base.target)
    assert np.linalg.norm(d1) == pytest.approx(np.linalg.norm(d0)) and d1[1] == pytest.approx(d0[1])
    assert np.dot(d0[[0, 2]], d1[[0, 2]]) == pytest.approx(0.0, abs=1e-9)   # a quarter turn


def test_a_contact_sheet_places_the_images_row_by_row():
    ims = [np.full((2, 3, 1), k, np.float32) for k in range(1, 6)]
    sheet = contact_sheet(ims, 3, gap=1)
    assert sheet.shape == (5, 11, 1)
    assert sheet[0, 0, 0] == 1 and sheet[0, 4, 0] == 2 and sheet[3, 4, 0] == 5 and sheet[3, 8, 0] == 0
    with pytest.raises(InvalidInputError, match="one size"):
        contact_sheet([ims[0], np.zeros((3, 3, 1))], 2)


def test_the_command_line_writes_a_turntable_in_two_colourways(tmp_path):
    (tmp_path / "red.toml").write_text('albedo = [0.9, 0.05, 0.05]\nspecular = 0.4\nglossiness = 0.8\n')
    out = tmp_path / "sheet.png"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", "--turntable", "3", "--colourway",
                        str(tmp_path / "red.toml"), "--size", "40x40", "--preset", "fast", "--out", str(out),
                        "--timings", str(tmp_path / "t.json")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    views = sorted(p.name for p in tmp_path.glob("sheet_v*_c*.png"))
    assert views == [f"sheet_v{v:02d}_c{c}.png" for v in range(3) for c in range(2)]
    sheet = Image.open(out)
    assert sheet.size == (2 * 40 + 2, 3 * 40 + 2 * 2)   # a row per view, a column per colourway
    # Each tile is its view's image but for its label in the top-left corner ("120 deg / red").
    tile = np.asarray(sheet.convert("RGBA"))[42:82, 42:82].astype(int)
    alone = np.asarray(Image.open(tmp_path / "sheet_v01_c1.png").convert("RGBA")).astype(int)
    assert np.abs(tile[20:] - alone[20:]).max() <= 1
    assert np.abs(tile[:10] - alone[:10]).max() > 100
    report = json.loads((tmp_path / "t.json").read_text())
    assert report["timings"]["views"] == 6 and len(report["views"]) == 5


def test_the_views_bench_reports_the_saving_it_measured():
    from garment_lab.views import _compare, markdown

    calls = []

    class F:
        def __init__(self, v):
            self.image = np.full((2, 2, 4), v, np.float32)

    def together():
        calls.append("one call")
        return [F(1.0), F(2.0)]

    def one_by_one():
        calls.append("one by one")
        return [F(1.0), F(2.5)]

    row = _compare("fast", "2 views", together, one_by_one, rounds=3)
    # A warm-up each, then the two ways take turns.
    assert calls == ["one call", "one by one"] + ["one call", "one by one"] * 3
    assert row["images"] == 2 and row["max_image_difference"] == pytest.approx(0.5 / 2.5)
    data = {"machine": {"gl_renderer": "llvmpipe", "cores": 2, "date": "2026-12-02"}, "size": 8, "rounds": 3,
            "quick": True, "wall_s": 1.0, "rows": [dict(row, shared_ms=60.0, alone_ms=100.0, saving=0.4)]}
    text = markdown(data)
    assert "`garment-render bench --views --quick`" in text and "| fast | 2 views | 60 | 100 | 40 % | 0.2 |" in text
