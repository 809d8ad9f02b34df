"""Requests of many images against a real server on 127.0.0.1: bounded by their cost before their
work starts (the limit named in the answer), stopped when their request is over, and never holding
another scene's frames back (service/budgets.py, the worker's steps)."""

from __future__ import annotations

import socket
import threading
import time
from urllib.parse import urlsplit

import httpx
import numpy as np
import pytest
from service_server import ServiceProcess, assert_error, garment, scene_body, upload_environment

OCTET = {"Content-Type": "application/octet-stream"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    # A short timeout: a request past it is answered 504 and its job stops.
    srv = ServiceProcess(tmp_path_factory.mktemp("bounds"), request_timeout_s=3)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def env_id(http, tmp_path_factory):
    return upload_environment(http, tmp_path_factory.mktemp("env"))[0]["id"]


@pytest.fixture(scope="module")
def mesh():
    return garment(24)


def _scene(http, env_id, mesh, size: int) -> str:
    r = http.post("/scenes", json=scene_body(env_id, mesh, output={"width": size, "height": size}))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _frame(http, scene_id, mesh, **kw) -> httpx.Response:
    return http.post(f"/scenes/{scene_id}/frames", content=np.asarray(mesh.positions, "<f4").tobytes(),
                     headers=OCTET, **kw)


def _frames(mesh, n: int) -> bytes:
    base = np.asarray(mesh.positions, np.float32)
    return b"".join((base + np.float32(1e-4 * k)).astype("<f4").tobytes() for k in range(n))


def _stats(http) -> dict:
    return http.get("/stats").json()["jobs"]


def _wait_for_job(http, words: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        job = http.get("/health/ready").json()["current_job"]
        if job is not None and words in job["what"]:
            return
        assert time.monotonic() < deadline, f"no job with {words!r} started"
        time.sleep(0.02)


def test_another_scenes_frames_pass_a_long_batch(server, http, env_id, mesh):
    batched, other = _scene(http, env_id, mesh, 192), _scene(http, env_id, mesh, 96)
    t0 = time.perf_counter()
    assert _frame(http, batched, mesh).status_code == 200
    frame_s = time.perf_counter() - t0
    n = int(min(1000, max(40, 10.0 / frame_s)))   # a batch of about 10 s
    answer = {}

    def batch():
        with httpx.Client(base_url=server.url, timeout=300) as c:
            answer["r"] = c.post(f"/scenes/{batched}/frames/batch", content=_frames(mesh, n), headers=OCTET,
                                 params={"format": "zip"})

    thread = threading.Thread(target=batch)
    thread.start()
    try:
        _wait_for_job(http, f"batch of {n} frames")
        waits = []
        for _ in range(5):
            t0 = time.perf_counter()
            r = _frame(http, other, mesh)
            waits.append(time.perf_counter() - t0)
            assert r.status_code == 200, r.text
        assert thread.is_alive(), (f"the batch of {n} frames ({n * frame_s:.0f} s) ended before five frames of "
                                   f"another scene were answered ({sum(waits):.1f} s): they waited behind it")
        assert max(waits) < 2.0 + 3 * frame_s, waits
    finally:
        thread.join(300)
    assert answer["r"].status_code == 200 and answer["r"].headers["X-Frame-Count"] == str(n)


def _views_request(url: str, scene_id: str, body: bytes, query: str) -> socket.socket:
    u = urlsplit(url)
    s = socket.create_connection((u.hostname, u.port))
    s.sendall(f"POST /scenes/{scene_id}/frames/views?{query} HTTP/1.1\r\nHost: x\r\nContent-Type: "
              f"application/octet-stream\r\nContent-Length: {len(body)}\r\n\r\n".encode() + body)
    return s


@pytest.mark.parametrize("how", ["client leaves", "timeout"])
def test_views_whose_request_is_over_stop_at_their_next_image(server, http, env_id, mesh, how):
    scene_id = _scene(http, env_id, mesh, 384)
    assert _frame(http, scene_id, mesh).status_code == 200   # the first frame builds what the others reuse
    t0 = time.perf_counter()
    assert _frame(http, scene_id, mesh).status_code == 200
    image_s = time.perf_counter() - t0
    views = int(min(64, max(16, 12.0 / image_s)))   # well past the 3 s timeout
    stopped = _stats(http)["stopped"]
    body = np.asarray(mesh.positions, "<f4").tobytes()
    if how == "client leaves":
        with _views_request(server.url, scene_id, body, f"turntable={views}&format=zip"):
            _wait_for_job(http, f"{views} views")
    else:
        with httpx.Client(base_url=server.url, timeout=60) as c:
            r = c.post(f"/scenes/{scene_id}/frames/views", content=body, headers=OCTET,
                       params={"turntable": views, "format": "zip"})
        assert_error(r, 504, "3 s")
    t0 = time.perf_counter()
    r = _frame(http, scene_id, mesh)
    waited = time.perf_counter() - t0
    assert r.status_code == 200, r.text
    assert waited < 1.5 + 3 * image_s, f"the next frame waited {waited:.1f} s behind views nobody receives"
    deadline = time.monotonic() + 10
    while _stats(http)["stopped"] == stopped:
        assert time.monotonic() < deadline, "the views job was not counted as stopped"
        time.sleep(0.05)


# -- bounds: judged on the images' count and size, before the body is decoded or a job queued ----------

@pytest.fixture(scope="module")
def bounded(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("bounded"), max_request_s=2)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def bounded_http(bounded):
    with httpx.Client(base_url=bounded.url, timeout=120) as c:
        yield c


@pytest.mark.parametrize("size, route, params, words", [
    (2048, "views", {"turntable": 64}, ["64 views x 1 colourways of 2048 x 2048", "GARMENT_RENDER_MAX_REQUEST_BYTES"]),
    (4096, "views", {"views": "front,back,left,right,front,back,left,right"},
     ["8 views", "4096 x 4096", "GARMENT_RENDER_MAX_REQUEST_BYTES"]),
    (4096, "batch", {"frames": 20}, ["batch of 20 frames of 4096 x 4096", "GARMENT_RENDER_MAX_REQUEST_BYTES"]),
])
def test_a_request_of_many_large_images_is_refused_by_its_memory_before_any_work(
        bounded_http, tmp_path, mesh, size, route, params, words):
    http = bounded_http
    env_id = upload_environment(http, tmp_path, known=True)[0]["id"]
    scene_id = _scene(http, env_id, mesh, size)
    done = _stats(http)["done"]
    n = params.pop("frames", 1)
    t0 = time.perf_counter()
    r = http.post(f"/scenes/{scene_id}/frames/{route}", content=_frames(mesh, n), headers=OCTET, params=params)
    assert time.perf_counter() - t0 < 1.0
    assert_error(r, 413, "MiB at once", *words)
    assert _stats(http)["done"] == done, "a job ran for a refused request"
    http.delete(f"/scenes/{scene_id}")


def test_a_batch_longer_than_the_time_limit_is_refused_by_its_measured_frames(bounded_http, tmp_path, mesh):
    http = bounded_http
    env_id = upload_environment(http, tmp_path, known=True)[0]["id"]
    scene_id = _scene(http, env_id, mesh, 128)
    # Before any frame of this process, the assumed rate; after one, the scene's own.
    r = http.post(f"/scenes/{scene_id}/frames/batch", content=_frames(mesh, 1000), headers=OCTET)
    assert_error(r, 413, "1000 images", "assumed before any frame was timed", "GARMENT_RENDER_MAX_REQUEST_S")
    for _ in range(3):
        assert _frame(http, scene_id, mesh).status_code == 200
    each_ms = float(_frame(http, scene_id, mesh).headers["Server-Timing"].split("gl_job;dur=")[1].split(",")[0])
    over = int(2.0 / (each_ms / 1e3) * 3) + 1
    r = http.post(f"/scenes/{scene_id}/frames/batch", content=_frames(mesh, min(over, 1000)), headers=OCTET)
    assert_error(r, 413, "this scene's frames so far", "over the limit 2 s (GARMENT_RENDER_MAX_REQUEST_S)")
    under = max(1, int(0.5 / (each_ms / 1e3)))
    r = http.post(f"/scenes/{scene_id}/frames/batch", content=_frames(mesh, under), headers=OCTET)
    assert r.status_code == 200, r.text
    assert r.json()["n_frames"] == under
