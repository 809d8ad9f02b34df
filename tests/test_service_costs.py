"""One cost model through the service, against a real server on 127.0.0.1: every preset registers and
renders at the sizes the README names within the default limits, the memory a scene says one frame
takes is what the frame's shadow maps hold, an upload is judged by its PEM set alone, and a face size
gets one answer from either route."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from service_server import PISA, ServiceProcess, assert_error, environment_bytes, garment, scene_body

from renderer.presets import PRESET_NAMES
from renderer.procedural import procedural_body

OCTET = {"Content-Type": "application/octet-stream"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("costs"))   # the default limits
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def mesh():
    return garment(24)


def dressed_body(env_id: str, mesh, quality: dict, size: int) -> dict:
    """A garment over a body (two shadow groups, the body's own targets), `quality` alone."""
    body = procedural_body(12, 16)
    out = scene_body(env_id, mesh, output={"width": size, "height": size},
                     body={"positions": body.positions.tolist(), "faces": body.faces.tolist()})
    out["quality"] = quality
    return out


def upload(http: httpx.Client, tmp_path, **params) -> httpx.Response:
    data, name = environment_bytes(tmp_path)
    return http.post("/environments", content=data, headers=OCTET, params={"name": name, **params})


@pytest.mark.skipif(not PISA.exists(), reason=f"the issue's map {PISA} is not here")
@pytest.mark.parametrize("size", [256, 512])
@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_registers_and_renders_and_says_what_its_frame_holds(http, mesh, tmp_path, preset, size):
    env = upload(http, tmp_path, preset=preset)   # pisa.hdr, the preset's own PEM set
    assert env.status_code in (200, 201), env.text
    r = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, {"preset": preset}, size))
    assert r.status_code == 201, r.text
    scene = r.json()
    memory = scene["frame_memory"]
    assert memory["exact"] and memory["shadow_groups"] == 2
    f = http.post(f"/scenes/{scene['id']}/frames", params={"format": "json"}, headers=OCTET,
                  content=np.ascontiguousarray(mesh.positions, "<f4").tobytes())   # the garment's; the body holds still
    assert f.status_code == 200, f.text
    assert (f.json()["width"], f.json()["height"]) == (size, size)
    # What the registration estimated against what the frame's shadow-map arrays hold (ShadowMaps.nbytes).
    held = f.json()["render"]["shadow_bytes"]
    assert held <= memory["shadow_map_bytes"] <= 1.5 * held, (memory, held)
    assert memory["total_bytes"] < 4 << 30
    http.delete(f"/scenes/{scene['id']}")


def test_an_upload_makes_no_frame_and_a_default_preset_of_accurate_works(tmp_path, mesh):
    """A service whose default preset is accurate takes an upload and a scene without one. One whose
    shadow-map limit (512 MiB) the accurate frame passes (640 MiB: 160 maps of 512^2, two groups) still
    takes the upload (its PEM set alone) and refuses the scene naming the limit and the light plan's
    layout, and a quality no map could fit before its PEM set is built."""
    srv = ServiceProcess(tmp_path, default_preset="accurate")
    try:
        with httpx.Client(base_url=srv.url, timeout=300) as http:
            env = upload(http, tmp_path)
            assert env.status_code == 201, env.text
            assert env.json()["pem_sets"][0]["n_lights"] == 160
            r = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, {}, 256))
            assert r.status_code == 201, r.text
            assert r.json()["quality"]["preset"] == "accurate"
    finally:
        srv.stop()
    srv = ServiceProcess(tmp_path, max_shadow_map_bytes=512 << 20)
    try:
        with httpx.Client(base_url=srv.url, timeout=300) as http:
            env = upload(http, tmp_path, preset="accurate")
            assert env.status_code == 201, env.text
            builds = http.get("/stats").json()["jobs"]["done"]
            r = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, {"preset": "accurate", "shadow_size": 2048},
                                                       256))
            assert_error(r, 422, "at least", "GiB of shadow maps", "up to 66 of them sharp maps of 8192^2",
                         "GARMENT_RENDER_MAX_SHADOW_MAP_BYTES")
            assert http.get("/stats").json()["jobs"]["done"] == builds   # nothing reached the GL thread
            r = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, {"preset": "accurate"}, 256))
            assert_error(r, 422, "640 MiB of shadow maps", "160 main maps of 512^2 for 160 lights", "2 shadow groups",
                         "GARMENT_RENDER_MAX_SHADOW_MAP_BYTES")
    finally:
        srv.stop()


def test_a_face_size_gets_one_answer_from_both_routes(tmp_path, mesh):
    """face_size 2048 with 6 lights, with a disk cache (a set's copy for it counts in its build): the
    upload and the scene refuse it naming the same face size that fits, and both take that one."""
    srv = ServiceProcess(tmp_path, pem_cache_dir=tmp_path / "pems")
    try:
        with httpx.Client(base_url=srv.url, timeout=300) as http:
            quality = {"face_size": 2048, "lights": 6}
            r_env = upload(http, tmp_path, **quality)
            assert_error(r_env, 422, "refused before it is built", "face_size 2048", "What would fit")
            env = upload(http, tmp_path, preset="fast")
            assert env.status_code == 201, env.text
            r_scene = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, quality, 64))
            assert_error(r_scene, 422, "refused before it is built", "face_size 2048", "What would fit")
            fits = [r.json()["detail"].split("What would fit: ")[1].split(" or ")[0].split() for r in (r_env, r_scene)]
            assert fits[0] == fits[1], fits
            face = int(fits[0][1])
            assert upload(http, tmp_path, lights=6, face_size=face).status_code == 200   # the same file again
            r = http.post("/scenes", json=dressed_body(env.json()["id"], mesh, {**quality, "face_size": face}, 64))
            assert r.status_code == 201, r.text
            # One level too many for the upload is one for the scene too.
            assert_error(upload(http, tmp_path, lights=6, face_size=2 * face), 422, "What would fit")
            assert_error(http.post("/scenes", json=dressed_body(env.json()["id"], mesh,
                                                                {**quality, "face_size": 2 * face}, 64)),
                         422, "What would fit")
    finally:
        srv.stop()
