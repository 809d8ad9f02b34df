"""The shadow catcher (issue 62 item 2): a transparent background, the figure opaque with its coverage,
the floor reduced to its shadows (black, alpha = the share of the light the figure takes from it),
against the tracer's shadowed / unshadowed floor; in the command line (a ground plane where no floor
is given) and the service."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from conftest import CAM, balanced, balanced_pems, plane, sphere, sun_sky_cube
from PIL import Image

from renderer.errors import InvalidInputError
from renderer.reference.montecarlo import render_reference
from renderer.renderer import Background
from renderer.shading.material import Material

SIZE = 64
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _luminance(image: np.ndarray) -> np.ndarray:
    return image[..., :3] @ LUMINANCE


@pytest.mark.parametrize("sun", [(1.0, 1.0, 0.5), (-0.6, 0.8, -0.3)])
def test_the_floor_keeps_its_shadow_as_alpha_as_the_tracer_sees_it(renderer, sun):
    """A sphere over a floor under a sun and sky: where the floor shows, 1 - alpha is the tracer's
    floor radiance with the sphere over it without (64 samples, 3 x 3 windows: within 0.08 on the
    median window, the shadow's core and the lit floor told apart alike); the sphere is opaque, the
    sky clear."""
    cube = sun_sky_cube(64, sun, sun_radiance=300.0, sun_radius_deg=4)
    meshes = [sphere(0.5, centre=(0.0, 0.5, 0.0)), plane(4.0, 0.0)]
    materials = [Material((0.7, 0.3, 0.2), 0.2, 0.7), Material((0.6, 0.6, 0.6), 0.0, 0.3)]
    pems = renderer.build_pems(cube, balanced_pems())
    scene = renderer.create_scene(meshes, materials, casters=[True, False], catcher=1)
    try:
        frame = renderer.render(scene, pems, balanced(SIZE, SIZE, background=Background.SHADOW_CATCHER,
                                                      aovs=("id",)), CAM)
    finally:
        scene.release()
        pems.release()
    ids, alpha = frame.aovs["id"], frame.image[..., 3]
    assert (alpha[ids == 0] == 0).all() and (alpha[ids == 1] > 0.99).all()
    assert (frame.image[..., :3][ids == 2] == 0).all()
    shadowed = render_reference(meshes, materials, cube, CAM, SIZE, SIZE, spp=64, seed=1).image
    free = render_reference(meshes[1:], materials[1:], cube, CAM, SIZE, SIZE, spp=64, seed=2).image
    floor = (ids == 2) & (shadowed[..., 3] > 0.99) & (free[..., 3] > 0.99)
    # 3 x 3 windows wholly on the floor, against the tracer's noise.
    from numpy.lib.stride_tricks import sliding_window_view as windows

    whole = windows(floor, (3, 3)).all(axis=(-1, -2))
    ratio_ref = windows(_luminance(shadowed), (3, 3)).sum(axis=(-1, -2)) / np.maximum(
        windows(_luminance(free), (3, 3)).sum(axis=(-1, -2)), 1e-12)
    ours = 1.0 - windows(alpha, (3, 3)).mean(axis=(-1, -2))
    err = np.abs(ours - ratio_ref)[whole]
    assert whole.sum() > 300 and np.median(err) < 0.08, np.median(err)
    dark_ref, dark_ours = (ratio_ref < 0.5) & whole, (ours < 0.5) & whole
    assert dark_ref.sum() > 20   # the sun's shadow is on the floor in view
    assert (dark_ref & dark_ours).sum() / (dark_ref | dark_ours).sum() > 0.6


def test_a_shadow_catcher_frame_needs_its_floor(renderer):
    pems = renderer.build_pems(sun_sky_cube(16, (1, 1, 0.5)), balanced_pems(lights=6, face_size=16))
    scene = renderer.create_scene([sphere(0.5)], [Material()])
    try:
        with pytest.raises(InvalidInputError, match="shadow-catcher frame needs the scene's floor"):
            renderer.render(scene, pems, balanced(16, 16, background=Background.SHADOW_CATCHER), CAM)
        with pytest.raises(InvalidInputError, match="catcher must name one of the 1 meshes"):
            renderer.create_scene([sphere(0.5)], [Material()], catcher=3)
    finally:
        scene.release()
        pems.release()


def test_the_command_line_makes_a_product_image_over_nothing(tmp_path):
    """The bundled scene (its floor catches; anti-aliased, whose edges pass keeps the floor's alpha) and
    a garment alone (a ground plane is made under it): PNGs whose background is clear, whose figure is
    opaque and whose floor holds a shadow."""
    out = tmp_path / "product.png"
    base = [sys.executable, "-m", "renderer.cli", "render", "--size", "64x64", "--preset", "fast",
            "--background", "shadow-catcher", "--out", str(out)]
    for extra in (["--aa-samples", "4"], ["--mesh", str(tmp_path / "garment.obj")]):
        if "--mesh" in extra:
            import trimesh

            from renderer.procedural import procedural_garment
            g = procedural_garment(24)
            trimesh.Trimesh(g.positions, g.faces, process=False).export(tmp_path / "garment.obj")
        done = subprocess.run(base + extra, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        rgba = np.asarray(Image.open(out))
        assert rgba.shape == (64, 64, 4)
        alpha = rgba[..., 3]
        assert (alpha == 0).mean() > 0.2 and (alpha == 255).sum() > 100, extra
        shadow = (alpha > 20) & (alpha < 255) & (rgba[..., :3].max(axis=-1) == 0)
        assert shadow.sum() > 20, extra


def test_the_service_answers_a_shadow_catcher_scene(tmp_path):
    from service_server import one_scene_service

    with one_scene_service(tmp_path, background="shadow-catcher") as (http, scene, mesh):
        assert [m["role"] for m in scene["meshes"]][-1] == "shadow floor"
        frame = http.post(f"/scenes/{scene['id']}/frames", headers={"Content-Type": "application/octet-stream"},
                          content=np.ascontiguousarray(mesh.positions, "<f4").tobytes())
        assert frame.status_code == 200, frame.text
        rgba = np.asarray(Image.open(io.BytesIO(frame.content)))
        alpha = rgba[..., 3]
        assert rgba.shape[2] == 4 and (alpha == 0).any() and (alpha == 255).any()
        assert ((alpha > 0) & (alpha < 255) & (rgba[..., :3].max(axis=-1) == 0)).any()   # a shadow on the floor
