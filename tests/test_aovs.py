"""Passes beside the image (issue 62 item 3): depth, normal, albedo and id from the geometry pass
(renderer/aovs.py), in the Python API (Frame.aovs), the command line's EXR (--aov) and the service's
EXR and JSON answers (output.aovs)."""

from __future__ import annotations

import base64
import io
import subprocess
import sys

import numpy as np
import pytest
from conftest import CAM, balanced, balanced_pems, plane, sphere, sun_sky_cube

from renderer.aovs import BACKGROUND_DEPTH, parse_aovs
from renderer.errors import InvalidInputError
from renderer.shading.material import Material

SIZE = 64
CENTRE, RADIUS = np.array([0.0, 0.5, 0.0]), 0.5
MATERIALS = [Material((0.7, 0.2, 0.1), 0.3, 0.8), Material((0.3, 0.4, 0.5), 0.0, 0.3)]


@pytest.fixture(scope="module")
def frames(renderer):
    pems = renderer.build_pems(sun_sky_cube(32, (1, 1, 0.5)), balanced_pems(lights=12))
    scene = renderer.create_scene([sphere(RADIUS, centre=tuple(CENTRE)), plane(3.0, 0.0)], MATERIALS)
    try:
        with_aovs = renderer.render(scene, pems, balanced(SIZE, SIZE, aovs=("depth", "normal", "albedo", "id")), CAM)
        plain = renderer.render(scene, pems, balanced(SIZE, SIZE), CAM)
    finally:
        scene.release()
        pems.release()
    return with_aovs, plain


def _rays(size: int) -> np.ndarray:
    """The unit view rays through the pixel centres (rows from the top), from CAM."""
    fwd = np.subtract(CAM.target, CAM.eye)
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = np.tan(np.radians(CAM.fov_y_deg) / 2)
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c * t, -c * t)
    d = fwd + x[..., None] * right + y[..., None] * up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_the_passes_are_the_surfaces_the_camera_sees(frames):
    """Where a pixel's ray meets the sphere (analytically), its depth is the distance along it, its
    normal the sphere's there and its id 1; the floor's pixels are id 2 with an upward normal; the
    background is id 0 at BACKGROUND_DEPTH; the albedo is each mesh's. The image is the same with the
    passes as without."""
    frame, plain = frames
    np.testing.assert_array_equal(frame.image, plain.image)
    assert plain.aovs == {} and set(frame.aovs) == {"depth", "normal", "albedo", "id"}
    ids, depth, normal, albedo = (frame.aovs[k] for k in ("id", "depth", "normal", "albedo"))
    assert depth.shape == ids.shape == (SIZE, SIZE) and normal.shape == albedo.shape == (SIZE, SIZE, 3)
    d = _rays(SIZE)
    oc = np.asarray(CAM.eye) - CENTRE
    b = d @ oc
    disc = b * b - (oc @ oc - RADIUS ** 2)
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    inner = hit & (disc > 0.02)   # away from the silhouette, where a pixel's centre is surely on it
    assert inner.sum() > 200 and (ids[inner] == 1).all()
    np.testing.assert_allclose(depth[inner], t[inner], rtol=0.01)
    n_true = (np.asarray(CAM.eye) + t[..., None] * d - CENTRE) / RADIUS
    assert np.median(np.sum(normal[inner] * n_true[inner], axis=-1)) > 0.999
    np.testing.assert_allclose(albedo[inner], np.broadcast_to(MATERIALS[0].albedo, albedo[inner].shape), atol=1e-5)
    floor = ids == 2
    assert floor.sum() > 200 and np.median(normal[floor][:, 1]) > 0.999
    np.testing.assert_allclose(albedo[floor], np.broadcast_to(MATERIALS[1].albedo, albedo[floor].shape), atol=1e-5)
    background = ids == 0
    assert background.sum() > 50 and (depth[background] == BACKGROUND_DEPTH).all()
    assert (frame.image[..., 3][background] == 0).all() and (frame.image[..., 3][~background] > 0).all()


def test_a_pass_is_named_or_refused_by_name():
    assert parse_aovs("id, depth") == ("depth", "id") and parse_aovs(None) == ()
    with pytest.raises(InvalidInputError, match="unknown pass.*'speed'.*depth, normal, albedo, id"):
        parse_aovs(["depth", "speed"])


def test_the_command_line_writes_the_passes_as_exr_channels(tmp_path):
    import OpenEXR

    exr = tmp_path / "frame.exr"
    cmd = [sys.executable, "-m", "renderer.cli", "render", "--size", "48x48", "--preset", "fast", "--exr", str(exr),
           "--aov", "depth,normal,albedo,id"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    channels = {}
    for name, ch in OpenEXR.File(str(exr)).channels().items():   # the binding groups albedo.R/G/B as a layer
        channels[name] = ch.pixels
    assert {"RGBA", "Z", "N.X", "N.Y", "N.Z", "albedo", "id"} <= set(channels)
    ids = channels["id"]
    # The bundled scene: the dress (1), the mannequin (2), the floor (3), and background (0).
    assert set(np.unique(ids).tolist()) == {0.0, 1.0, 2.0, 3.0}
    assert (channels["Z"][ids == 0] == BACKGROUND_DEPTH).all() and (channels["Z"][ids > 0] < 100).all()
    refused = subprocess.run(cmd[:-4] + ["--timings", str(tmp_path / "t.json"), "--aov", "depth"],
                             capture_output=True, text=True, timeout=300)
    assert refused.returncode != 0 and "--aov writes its passes into the EXR" in refused.stderr


def test_the_service_answers_the_passes_in_exr_and_json(tmp_path):
    import OpenEXR
    from service_server import one_scene_service

    with one_scene_service(tmp_path, aovs=["id", "depth"]) as (http, scene, mesh):
        sid = scene["id"]
        positions = np.ascontiguousarray(mesh.positions, "<f4").tobytes()
        headers = {"Content-Type": "application/octet-stream"}
        exr = http.post(f"/scenes/{sid}/frames", content=positions, headers=headers, params={"format": "exr"})
        assert exr.status_code == 200, exr.text
        ch = OpenEXR.File(io.BytesIO(exr.content)).channels()
        assert {"RGBA", "Z", "id"} <= set(ch) and "N.X" not in ch
        covered = ch["RGBA"].pixels[..., 3] > 0.999
        assert (ch["id"].pixels[covered] == 1).all() and (ch["id"].pixels[~(ch["RGBA"].pixels[..., 3] > 0)] == 0).all()
        js = http.post(f"/scenes/{sid}/frames", content=positions, headers=headers, params={"format": "json"})
        aov = js.json()["aovs"]
        assert set(aov) == {"depth", "id"}
        ids = np.frombuffer(base64.b64decode(aov["id"]["base64"]), "<f4").reshape(aov["id"]["shape"])
        np.testing.assert_array_equal(ids, ch["id"].pixels)
        bad = {"environment_id": "env", "garment": {"positions": mesh.positions.tolist(), "faces": mesh.faces.tolist()},
               "output": {"aovs": ["speed"]}}
        r = http.post("/scenes", json=bad)   # refused by the schema, before any lookup
        assert r.status_code == 422 and "aovs" in r.text
