"""The simulator drives a real service (uvicorn on 127.0.0.1): every simulated frame is posted over
HTTP as it is simulated and comes back rendered (EXR, linear), and the sequence of images has the
properties a viewer of the simulation relies on. Plus the shared newton shirt drape through the
service."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import asset
from service_server import FAST_QUALITY, ServiceProcess

from garment_render_client import RenderClient
from renderer.camera import Camera
from simulation import BodyProxy, ClothSettings, ClothSim, mannequin, sheet, sphere
from simulation.feed import FRONT, DrapeFeed, View, upload_studio_environment

SIZE = 96
# Small and fast, but a 256^2 shadow map: the body's floor is 3 m wide, and at 64^2 a texel (5 cm)
# is too coarse for the shadow of a cloth hanging a few centimetres from a surface.
QUALITY = dict(FAST_QUALITY, shadow_size=256)
OUTPUT = {"width": SIZE, "height": SIZE}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("sim-service"))
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def client(server):
    with RenderClient(server.url) as c:
        yield c


@pytest.fixture(scope="module")
def studio(client):
    return upload_studio_environment(client, 256)


def _run(client, env_id, sim: ClothSim, view: View, n_frames: int):
    """Post the rest state, then each simulated frame; returns images (F, H, W, 4), answers, cloth states."""
    feed = DrapeFeed(client, sim, env_id, views=(view,), quality=QUALITY, output=OUTPUT, format="exr")
    images, answers, states = [], [], []
    for k in range(n_frames):
        if k:
            sim.step_frame()
        states.append(sim.x.copy())
        (answer,) = feed.post(k)
        answers.append(answer)
        images.append(answer.array())
    return np.stack(images), answers, states, feed


def _region(view: View, points: np.ndarray) -> np.ndarray:
    """Pixels (H, W) bool onto which the world points (N, 3) project in `view` (row 0 at the top)."""
    cam = Camera(view.eye, view.target, (0.0, 1.0, 0.0), view.fov_y_deg)
    clip = np.c_[points, np.ones(len(points))] @ (cam.projection(1.0, 0.1, 100.0) @ cam.view()).T
    ndc = clip[:, :2] / clip[:, 3:]
    px = np.c_[(ndc[:, 0] + 1) / 2 * SIZE, (1 - ndc[:, 1]) / 2 * SIZE].astype(int)
    mask = np.zeros((SIZE, SIZE), bool)
    ok = np.all((px >= 0) & (px < SIZE), axis=1)
    mask[px[ok, 1], px[ok, 0]] = True
    return mask


@pytest.fixture(scope="module")
def mannequin_drape(client, studio):
    """The demo's drape (smaller): a 24 x 24 sheet on the mannequin, 16 frames of 1/15 s."""
    sim = ClothSim(sheet(24), mannequin(), ClothSettings(frame_dt_s=1 / 15))
    return _run(client, studio["id"], sim, FRONT, 16)


def test_every_frame_arrives_renders_and_is_finite(mannequin_drape, client):
    images, answers, states, feed = mannequin_drape
    assert [a.frame_index for a in answers] == list(range(16))
    assert [int(a.headers["x-frame-sequence"]) for a in answers] == list(range(1, 17))
    assert images.shape == (16, SIZE, SIZE, 4) and images.dtype == np.float32
    assert np.all(np.isfinite(images)) and images[..., :3].min() >= 0
    for a in answers:
        assert a.media_type == "image/x-exr" and a.timings["render"] > 0 and a.timings["total"] >= a.timings["render"]
    # The cloth moved between frames, and the images with it.
    assert np.linalg.norm(states[-1] - states[0], axis=1).mean() > 0.5
    assert np.abs(images[-1] - images[0]).max() > 0.1
    latest = client._json("GET", f"/scenes/{feed.scene_ids[0]}/latest")
    assert latest["frame"]["frame_index"] == 15 and latest["frame"]["sequence"] == 16


def test_static_background_does_not_flicker(mannequin_drape):
    """Two static regions, two bounds.

    * The environment seen behind the scene (no geometry in any frame) is a function of the view
      direction only. The camera does not move, but its near/far planes are refitted to the scene's
      bounds every frame, and the view ray is reconstructed from them in float32; at sharp edges of
      the map (softboxes, horizon) that moves the bilinear lookup a little. Bound: 5e-3 relative,
      half the smallest step of 8-bit sRGB (0.9 % near white), so never a visible code change
      (measured: 2.5e-3 at those edges, 1e-5 elsewhere).
    * The floor far from the figure on the key light's side (x < -0.8 m, over 1.2 m from its axis):
      the key softbox is upper front-left, so the cloth's and the body's shadows fall to the right,
      where the floor does change as the cloth moves (measured: up to 60 %). On the left only the
      shadow maps change, refitted to the casters' box every frame; a light 1.7 degrees above the
      horizon puts that floor in the figure's long shadow, whose edge shimmered by 2.3 % per frame
      while the texel grid slid with the box. The footprint now steps in size and its centre moves by
      whole texels (fit_light_view_projs), so the grid stays put. Bound: 1 % per pixel per frame,
      below the 1-2 % luminance step a viewer notices on a flat grey (measured: 0).
    """
    images, _, _, _ = mannequin_drape
    radiance = images[..., :3].mean(-1)
    background = np.all(images[..., 3] == 0, axis=0)
    assert background.sum() > 0.1 * SIZE * SIZE
    env = radiance[:, background]
    assert np.max(np.abs(np.diff(env, axis=0)) / np.maximum(env[:-1], 1e-6)) < 5e-3

    gx, gz = np.meshgrid(np.linspace(-1.45, 1.45, 80), np.linspace(-1.45, 1.45, 80))
    floor = np.c_[gx.ravel(), np.zeros(gx.size), gz.ravel()]
    far = _region(FRONT, floor[(np.hypot(floor[:, 0], floor[:, 2]) > 1.2) & (floor[:, 0] < -0.8)])
    far &= np.all(images[..., 3] == 1, axis=0)
    assert far.sum() >= 20
    f = radiance[:, far]
    assert np.max(np.abs(np.diff(f, axis=0)) / f[:-1]) < 0.01


def test_shadow_under_the_cloth_grows_as_it_comes_down(client, studio):
    """A 1 m sheet falls onto a ball on the floor, seen from the side. The occluder's solid angle seen
    from the floor under it grows as it comes closer (a disc of radius R at height h covers
    2 pi (1 - h / sqrt(h^2 + R^2)) sr), so the floor around the ball darkens frame after frame while
    the sheet falls. Once it lies on the ball its footprint shrinks to the ball's: the shadow gets
    smaller again, as a real one does (not tested here)."""
    view = View("side", eye=(0.0, 0.9, 2.4), target=(0.0, 0.35, 0.0), fov_y_deg=40.0)
    body = BodyProxy((sphere((0.0, 0.3, 0.0), 0.3),), floor_y=0.0)
    sim = ClothSim(sheet(24, size_m=1.0, height_m=1.3), body, ClothSettings(frame_dt_s=1 / 15))
    images, answers, states, _ = _run(client, studio["id"], sim, view, 9)
    assert np.all(np.isfinite(images))
    r, t = np.meshgrid(np.linspace(0.32, 0.5, 20), np.linspace(0.0, np.pi, 60))  # floor ring, front half
    ring = _region(view, np.c_[(r * np.cos(t)).ravel(), np.zeros(r.size), (r * np.sin(t)).ravel()])
    # Frames while the sheet is above the ball's top (0.6 m): the ring is floor in all of them.
    falling = [k for k, x in enumerate(states) if x[:, 1].min() > 0.6 + 0.02]
    assert len(falling) >= 6
    ring &= np.all(images[falling, ..., 3] == 1, axis=0)
    assert ring.sum() >= 100
    mean = np.array([images[k, ..., :3].mean(-1)[ring].mean() for k in falling])
    # It only darkens (up to 0.5 % of noise from frame to frame), and by 5 % or more overall
    # (measured: 4.8 %, 14 % once the sheet is 1 cm above the ball).
    assert np.all(np.diff(mean) <= 0.005 * mean[0])
    assert mean[-1] < 0.97 * mean[0]
    dark = (mean[0] - mean) / mean[0]
    assert dark[-1] == dark.max()


def test_newton_shirt_drape_through_the_service(client, studio):
    """The shared newton VBD simulation (a T-shirt falling onto a two-capsule dress form, metres,
    Z-up): frames 0, 20, 40 and 60 through the service as EXR, with the dress form as the body."""
    data = np.load(asset("sim", "newton_shirt_drape_60f.npz"))
    colliders = asset("sim", "newton_shirt_drape_colliders.obj")
    positions, triangles = data["positions"], data["triangles"]
    assert positions.shape == (61, 6436, 3)
    body = client.upload_mesh(colliders, up="z")
    scene = client.create_scene(
        studio["id"], name="newton shirt", up="z", positions=positions[0], faces=triangles,
        material={"albedo": [0.2, 0.3, 0.6], "specular": 0.3, "glossiness": 0.6},
        body=client.mesh_spec(mesh_id=body["id"], material={"albedo": [0.7, 0.7, 0.7]}),
        camera={"eye": [0.0, 3.0, 1.3], "target": [0.0, 0.05, 1.15], "up": [0.0, 0.0, 1.0], "fov_y_deg": 35.0},
        quality=QUALITY, output=OUTPUT)
    frames = [0, 20, 40, 60]
    images = []
    for k in frames:
        answer = client.send_frame(scene["id"], positions[k], format="exr", frame_index=k)
        assert answer.frame_index == k
        images.append(answer.array())
    images = np.stack(images)
    assert np.all(np.isfinite(images)) and images[..., 3].mean() > 0.05
    # The shirt falls about 12 cm over the sequence: consecutive images differ.
    for a, b in zip(images[:-1], images[1:]):
        assert np.abs(a[..., :3] - b[..., :3]).mean() > 1e-3
    client.delete_scene(scene["id"])
