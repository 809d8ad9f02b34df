"""Casters that hold still are drawn once (shadows/vsm.py): a body under a moving garment keeps its
shadow-map layers while its positions and the lights' projections stay the same (Scene.stable_fit)."""

import numpy as np
from conftest import paper, paper_pems, plane, sphere, sun_sky_cube

from renderer.camera import Camera
from renderer.gpu.context import GLContext
from renderer.renderer import Background, Renderer
from renderer.scene import KEEP_SHRINK, REFIT_MARGIN
from renderer.shading.material import Material
from renderer.shadows.vsm import ShadowMaps

CAM = Camera((0.0, 3.0, 3.5), (0.0, 0.4, 0.0), fov_y_deg=45.0)


def test_the_still_group_is_drawn_once_and_the_frames_are_the_same(monkeypatch):
    """The same frames through a renderer that keeps the body's layers and one that draws every
    caster every frame: identical images; the layers are kept while the garment moves inside its
    box, drawn again when the body moves or the garment leaves the box."""
    cube = sun_sky_cube(32, (0.6, 1.0, 0.3), sun_radiance=800.0, sun_radius_deg=6, sky=(0.2, 0.2, 0.25))
    garment, body = sphere(0.3, centre=(0.0, 0.9, 0.0)), sphere(0.35, centre=(0.2, 0.35, 0.1))
    meshes = [garment, body, plane(4.0)]
    mats = [Material((0.7, 0.3, 0.3), 0.2, 0.6), Material((0.6, 0.5, 0.45)), Material((0.8, 0.8, 0.8))]
    up = np.array([0.0, 0.01, 0.0], np.float32)
    frames = [None,                                                   # the first: draws everything
              [garment.positions + up, None, None],                   # leaves the first (exact) box: refit
              [garment.positions + 2 * up, None, None],               # inside the grown box: kept
              [garment.positions + up, None, None],                   # again
              [garment.positions + up, body.positions + up, None],    # the body moves: drawn again
              [garment.positions + 40 * up, None, None]]              # the garment leaves the box: refit
    expected_hits = [0, 0, 1, 1, 0, 0]
    gl = GLContext()
    keeps, draws = Renderer(gl), Renderer(gl)
    original = ShadowMaps.render
    try:
        monkeypatch.setattr(ShadowMaps, "render", lambda self, *a, **k: original(
            self, *a, **{**k, "still_key": k.get("still_key") if ShadowMaps._keeps else None}))
        ShadowMaps._keeps = False
        scenes = [r.create_scene(meshes, mats) for r in (keeps, draws)]
        pems = keeps.build_pems(cube, paper_pems(24))
        fs = paper(64, 64, small_light_scale=1, background=Background.BLACK)
        hits = []
        for positions in frames:
            images = []
            for r, scene in zip((keeps, draws), scenes):
                ShadowMaps._keeps = r is keeps
                images.append(r.render(scene, pems, fs, CAM, positions=positions).image)
            maps = keeps._shadow_maps["main"]
            hits.append(maps.still_hits - sum(hits))
            np.testing.assert_array_equal(images[0], images[1])
            assert draws._shadow_maps["main"].still is None
        assert hits == expected_hits
        assert (images[0][..., 3] > 0.5).mean() > 0.3
    finally:
        del ShadowMaps._keeps
        pems.release()
        for s in scenes:
            s.release()
        keeps.release()
        draws.release()
        gl.release()


def test_the_fit_is_kept_inside_its_box_and_refit_with_a_margin_outside(renderer):
    scene = renderer.create_scene([sphere(0.5)], [Material()])
    try:
        lo, hi = np.zeros(3), np.ones(3)
        rec = (np.zeros(3), np.full(3, 0.5))
        first = scene.stable_fit(lo, hi, rec)
        assert np.array_equal(first[0], lo) and np.array_equal(first[1], hi)   # the first fit is exact
        inside = scene.stable_fit(lo + 0.05, hi - 0.05, (rec[0] + 0.01, rec[1]))
        assert np.array_equal(inside[0], lo) and np.array_equal(inside[2][1], rec[1])   # kept
        out = scene.stable_fit(lo, hi + 0.5, rec)
        np.testing.assert_allclose(out[1], hi + 0.5 + REFIT_MARGIN * 1.5)
        np.testing.assert_allclose(out[0], lo - REFIT_MARGIN * 1.5)
        # Shrunk below KEEP_SHRINK of the kept extent: fitted anew.
        small = 0.5 * KEEP_SHRINK
        shrunk = scene.stable_fit(lo + 0.1, lo + 0.1 + small, rec)
        np.testing.assert_allclose(shrunk[1] - shrunk[0], small * (1 + 2 * REFIT_MARGIN))
    finally:
        scene.release()
