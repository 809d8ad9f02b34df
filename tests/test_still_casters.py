"""Casters that hold still are drawn once (shadows/vsm.py): a body under a moving garment keeps its
shadow-map layers while its positions and the lights' projections stay the same (the projections are
fitted to boxes snapped to a grid: renderer.plan.snap_box)."""

import dataclasses

import numpy as np
import pytest
from conftest import plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.gpu.context import GLContext
from renderer.lighting.pem import PEMSettings
from renderer.plan import SNAP_CELLS, snap_box
from renderer.renderer import Background, FrameSettings, Renderer
from renderer.shading.material import Material
from renderer.shadows.vsm import ShadowMaps

CAM = Camera((0.0, 3.0, 3.5), (0.0, 0.4, 0.0), fov_y_deg=45.0)


def _garment_on_body():
    """A sun and sky, a garment (a ball) over a body (a ball) on a floor, and their materials."""
    cube = sun_sky_cube(32, (0.6, 1.0, 0.3), sun_radiance=800.0, sun_radius_deg=6, sky=(0.2, 0.2, 0.25))
    meshes = [sphere(0.3, centre=(0.0, 0.9, 0.0)), sphere(0.35, centre=(0.2, 0.35, 0.1)), plane(4.0)]
    mats = [Material((0.7, 0.3, 0.3), 0.2, 0.6), Material((0.6, 0.5, 0.45)), Material((0.8, 0.8, 0.8))]
    return cube, meshes, mats


@pytest.fixture
def two_renderers():
    """Two renderers on one context: one that keeps what holds still, one made to draw it anew."""
    gl = GLContext()
    keeps, draws = Renderer(gl), Renderer(gl)
    try:
        yield keeps, draws
    finally:
        keeps.release()
        draws.release()
        gl.release()


@pytest.mark.parametrize("sharp", [False, True])
def test_the_still_group_is_drawn_once_and_the_frames_are_the_same(monkeypatch, two_renderers, sharp):
    """The same frames through a renderer that keeps the body's layers and one that draws every
    caster every frame: identical images; the layers are kept while the garment moves inside its
    box, drawn again when the body moves or the garment leaves the box. `sharp`: the sun's map is in
    the sharp array (small_light_scale 4), which keeps its body's layers the same way."""
    cube, meshes, mats = _garment_on_body()
    garment, body = meshes[:2]
    up = np.array([0.0, 0.01, 0.0], np.float32)
    frames = [None,                                                   # the first: draws everything
              [garment.positions + 0.1 * up, None, None],             # inside the snapped boxes: kept
              [garment.positions, None, None],                        # back where it was: kept
              [garment.positions, body.positions + up, None],         # the body moves: drawn again
              [garment.positions + 40 * up, None, None],              # the garment leaves the box: refit
              [garment.positions, body.positions, None]]              # everything as at first: refit
    expected_hits = [0, 1, 1, 0, 0, 0]
    keeps, draws = two_renderers
    original = ShadowMaps.render
    try:
        monkeypatch.setattr(ShadowMaps, "render", lambda self, *a, **k: original(
            self, *a, **{**k, "still_key": k.get("still_key") if ShadowMaps._keeps else None}))
        ShadowMaps._keeps = False
        scenes = [r.create_scene(meshes, mats) for r in (keeps, draws)]
        pems = keeps.build_pems(cube, PEMSettings(24))
        fs = FrameSettings(64, 64, small_light_scale=4 if sharp else 1, background=Background.BLACK)
        hits, first = [], None
        for positions in frames:
            images = []
            for r, scene in zip((keeps, draws), scenes):
                ShadowMaps._keeps = r is keeps
                images.append(r.render(scene, pems, fs, CAM, positions=positions).image)
            maps = keeps._shadow_maps["sharp" if sharp else "main"]
            assert ("sharp" in keeps._shadow_maps) == sharp
            hits.append(maps.still_hits - sum(hits))
            np.testing.assert_array_equal(images[0], images[1])
            for held in draws._shadow_maps.values():
                assert held.still_key is None and held.still_hits == 0
            first = images[0] if first is None else first
        assert hits == expected_hits
        # The same positions give the same picture, whatever came between.
        np.testing.assert_array_equal(images[0], first)
        assert (images[0][..., 3] > 0.5).mean() > 0.3
    finally:
        del ShadowMaps._keeps
        pems.release()
        for s in scenes:
            s.release()


def test_a_snapped_box_holds_the_box_and_depends_on_it_alone():
    lo, hi = np.array([-0.3, 0.02, -0.25]), np.array([0.31, 1.47, 0.2])
    slo, shi = snap_box(lo, hi)
    assert (slo <= lo).all() and (shi >= hi).all()
    cell = float((shi - slo).max() - (hi - lo).max())   # grown by less than two cells on the longest side
    assert 0 <= cell < 2 * (hi - lo).max() / SNAP_CELLS
    # Cells of a power of two between 1/(2 SNAP_CELLS) and 1/SNAP_CELLS of the longest side.
    size = 2.0 ** np.floor(np.log2((hi - lo).max() / SNAP_CELLS))
    np.testing.assert_allclose(slo / size, np.round(slo / size))
    np.testing.assert_allclose(shi / size, np.round(shi / size))
    # A move inside the cells keeps the box; one across a cell's side does not; the way back restores it.
    moved = snap_box(lo + 1e-3, hi + 1e-3)
    assert all(np.array_equal(a, b) for a, b in zip(moved, (slo, shi)))
    away = snap_box(lo + size, hi + size)
    assert not np.array_equal(away[0], slo)
    assert all(np.array_equal(a, b) for a, b in zip(snap_box(lo.copy(), hi.copy()), (slo, shi)))
    # Far from the origin, and a box of no extent: finite, and still holding it.
    far = snap_box(lo + 1e4, hi + 1e4)
    assert np.isfinite(far).all() and (far[0] <= lo + 1e4).all() and (far[1] >= hi + 1e4).all()
    flat = snap_box(np.ones(3), np.ones(3))
    assert np.isfinite(flat).all() and (flat[0] <= 1).all() and (flat[1] >= 1).all()
    # In the scene's unit: a scene a million times larger snaps to a box a million times larger.
    big = snap_box(lo * 1e6, hi * 1e6, unit=3.7e6)
    small = snap_box(lo, hi, unit=3.7)
    np.testing.assert_allclose(big[0], small[0] * 1e6)
    np.testing.assert_allclose(big[1], small[1] * 1e6)


@pytest.mark.parametrize("aa_samples", [1, 4])
def test_the_still_meshes_geometry_is_drawn_once_per_camera_and_the_frames_are_the_same(two_renderers, aa_samples):
    """The geometry pass draws the body and the floor (every mesh outside shadow group 0) into targets
    of their own, kept while they, their material and the camera stay the same: the frames equal
    those of a renderer that draws them anew every frame, and a body that moves, another camera or a
    colourway draws them again. With anti-aliasing the coverage pass keeps its own (its depths)."""
    cube, meshes, mats = _garment_on_body()
    garment, body = meshes[:2]
    up = np.array([0.0, 0.01, 0.0], np.float32)
    other = Camera((2.0, 2.0, 3.0), (0.0, 0.5, 0.0), fov_y_deg=40.0)
    # (positions, camera, colourway): what each frame changes, and whether its still meshes are copied.
    frames = [(None, CAM, 0, False),                                        # the first draws them
              ([garment.positions + 5 * up, None, None], CAM, 0, True),     # the garment moves: copied
              ([garment.positions, body.positions + up, None], CAM, 0, False),   # the body moves
              ([garment.positions + 5 * up, None, None], CAM, 0, True),
              (None, other, 0, False),                                      # another camera
              (None, other, 1, False),                                      # a colourway
              (None, other, 1, True)]
    keeps, draws = two_renderers
    try:
        scenes = [r.create_scene(meshes, mats) for r in (keeps, draws)]
        for s in scenes:
            assert s.add_variant([None, Material((0.2, 0.3, 0.7)), None]) == 1
        pems = keeps.build_pems(cube, PEMSettings(24))
        fs = FrameSettings(64, 64, background=Background.BLACK, aa_samples=aa_samples)
        for positions, camera, variant, copied in frames:
            hits = keeps.geometry_still_hits
            images = []
            for r, scene in zip((keeps, draws), scenes):
                if r is draws:
                    for kept in r._still_targets.values():
                        kept.key = None   # nothing kept: drawn anew
                images.append(r.render_views(scene, pems, fs, [camera], positions=positions,
                                             variants=[variant])[0].image)
            np.testing.assert_array_equal(images[0], images[1])
            assert keeps.geometry_still_hits - hits == int(copied)
            assert (images[0][..., 3] > 0.5).mean() > 0.3
        assert draws.geometry_still_hits == 0
    finally:
        pems.release()
        for s in scenes:
            s.release()


def test_the_light_plan_is_kept_while_the_snapped_boxes_stay_and_the_frames_are_the_same(two_renderers):
    """The light plan (each light's map and projection, the lights' records) is a function of the PEM
    set, the settings and the snapped boxes: it is kept while they stay (a garment moving within its
    cells), made again when one changes, and the frames (and the contact search's distance, made every
    frame from the casters' own box) equal those of a renderer that plans every frame."""
    cube, meshes, mats = _garment_on_body()
    garment = meshes[0]
    up = np.array([0.0, 1.0, 0.0], np.float32)
    fs = FrameSettings(64, 64, background=Background.BLACK, contact_shadow_texels=12.0)
    # (positions, settings, whether the plan is kept)
    frames = [(None, fs, False),                                           # the first plans
              ([garment.positions + 1e-4 * up, None, None], fs, True),     # within its cells
              ([garment.positions + 0.3 * up, None, None], fs, False),     # across a cell's side
              ([garment.positions + 0.3 * up, None, None], fs, True),
              (None, dataclasses.replace(fs, shadow_size=128), False),     # other settings
              ([garment.positions, None, None], fs, False)]                # back: planned again
    keeps, plans = two_renderers
    pems = keeps.build_pems(cube, PEMSettings(24))
    scenes = [r.create_scene(meshes, mats) for r in (keeps, plans)]
    try:
        for positions, settings, kept in frames:
            hits = keeps.planner.hits
            out = []
            for r, scene in zip((keeps, plans), scenes):
                if r is plans:
                    r.planner.forget()   # nothing kept: planned anew
                out.append(r.render_views(scene, pems, settings, [CAM], positions=positions)[0])
            np.testing.assert_array_equal(out[0].image, out[1].image)
            assert out[0].settings["contact_radius"] == out[1].settings["contact_radius"] > 0.0
            assert keeps.planner.hits - hits == int(kept)
        assert plans.planner.hits == 0
    finally:
        pems.release()
        for s in scenes:
            s.release()
