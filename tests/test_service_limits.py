"""The service under attack, against a real server on 127.0.0.1: every request bounded in memory and
time before its work starts, degenerate input refused with a 422 that names it, honest readiness."""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np
import pytest
from service_server import ServiceProcess, assert_error, environment_bytes, garment, scene_body, upload_environment

OCTET = {"Content-Type": "application/octet-stream"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("limits")
    srv = ServiceProcess(tmp, queue_size=4, ready_max_busy_s=0.5)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def env_id(http, tmp_path_factory):
    return upload_environment(http, tmp_path_factory.mktemp("env"))[0]["id"]


@pytest.fixture(scope="module")
def mesh():
    return garment(24)


@pytest.fixture(scope="module")
def scene_id(http, env_id, mesh):
    r = http.post("/scenes", json=scene_body(env_id, mesh))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def post_frame(http, scene_id, positions, **kw):
    return http.post(f"/scenes/{scene_id}/frames", content=np.ascontiguousarray(positions, "<f4").tobytes(),
                     headers=OCTET, **kw)


@pytest.mark.parametrize("value", [0.0, 1e-45, 1.0, 1e38, 3.4e38, -3.4e38])
def test_a_frame_whose_vertices_all_coincide_is_a_422_naming_it(http, scene_id, mesh, value):
    r = post_frame(http, scene_id, np.full(mesh.positions.shape, value, np.float32))
    if abs(value) > 1e18:
        assert_error(r, 422, "coordinates beyond", "metres")
    else:
        assert_error(r, 422, "coincide", f"all {mesh.n_vertices} vertices")
    # ... and the scene renders its next good frame.
    assert post_frame(http, scene_id, mesh.positions).status_code == 200


def test_inputs_that_could_never_render_are_refused_when_given_naming_the_problem(http, env_id, mesh, scene_id):
    """Issue 60, item 4: one vertex 30 km off (the camera would frame it and shrink the garment to a
    dot), a camera eye a thousand kilometres off (every frame a 422) and an exposure beyond any display
    are refused where they are given, with what and the limit; the scene renders its next good frame."""
    stray = mesh.positions.copy()
    stray[7] = (30_000.0, 0.0, 0.0)
    assert_error(post_frame(http, scene_id, stray), 422, "vertex 7", "more than 1000 times farther")
    assert post_frame(http, scene_id, mesh.positions).status_code == 200
    body = scene_body(env_id, mesh)
    body["garment"]["positions"] = stray.tolist()
    assert_error(http.post("/scenes", json=body), 422, "vertex 7")
    far = scene_body(env_id, mesh, camera={"eye": [1e6, 0.0, 0.0], "target": [0.0, 0.0, 0.0]})
    assert_error(http.post("/scenes", json=far), 422, "pixels across", "bring the eye closer")
    beyond = scene_body(env_id, mesh, camera={"eye": [1e30, 0.0, 0.0], "target": [0.0, 0.0, 0.0]})
    assert_error(http.post("/scenes", json=beyond), 422, "pixels across")
    bright = scene_body(env_id, mesh, output={"width": 64, "height": 64, "exposure_ev": 1e308})
    assert_error(http.post("/scenes", json=bright), 422, "exposure_ev")


@pytest.mark.parametrize("scale", [1e-30, 1e-40, 1e17])
def test_a_scene_at_the_edge_of_float32_renders_or_is_a_422_never_a_500(http, env_id, mesh, scale):
    # Attometres, below float32's normal range, and 10^17 m across: answered either way, never a 5xx.
    p = ((mesh.positions - mesh.positions.mean(0)) * scale).astype(np.float32)
    body = scene_body(env_id, mesh)
    body["garment"]["positions"] = p.tolist()
    r = http.post("/scenes", json=body)
    assert r.status_code in (201, 422), r.text
    if r.status_code == 201:
        f = post_frame(http, r.json()["id"], p)
        assert f.status_code in (200, 422), f.text
        if f.status_code == 422:
            assert "float32" in f.json()["detail"] or "coincide" in f.json()["detail"]
        http.delete(f"/scenes/{r.json()['id']}")


@pytest.mark.parametrize("fmt", ["obj", "stl"])
def test_a_mesh_file_that_is_not_utf8_is_read(http, fmt):
    # A valid OBJ with a latin-1 copyright sign in a comment, an ASCII STL with one in its name.
    if fmt == "obj":
        text = "# \xa9 Atelier\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n"
    else:
        text = ("solid \xa9atelier\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                "endloop\nendfacet\nendsolid \xa9atelier\n")
    r = http.post("/meshes", content=text.encode("latin-1"), headers=OCTET, params={"format": fmt})
    assert r.status_code == 201, r.text
    assert r.json()["n_faces"] == (2 if fmt == "obj" else 1)


# -- the gate: the headers are judged before the body is read ---------------------------------------

@pytest.fixture(scope="module")
def token_server(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("token"), token="s3cret", max_upload_bytes=256 << 20)
    yield srv
    srv.stop()


def _headers_only(url: str, request: bytes, timeout_s: float = 10.0) -> bytes:
    """Send a request's headers and none of its body; what the server answers within the timeout."""
    import socket
    from urllib.parse import urlsplit

    u = urlsplit(url)
    with socket.create_connection((u.hostname, u.port), timeout=timeout_s) as s:
        s.sendall(request)
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
        head, _, rest = data.partition(b"\r\n\r\n")
        return head + b"\r\n\r\n" + rest


@pytest.mark.parametrize("auth, want", [(b"", b"401"), (b"Authorization: Bearer wrong\r\n", b"401"),
                                        (b"Authorization: Bearer s3cret\r\nContent-Type: text/html\r\n", b"415")])
def test_a_refusal_on_the_headers_comes_before_the_body(token_server, auth, want):
    # 200 MB announced and never sent: a server that read the body first would wait for it.
    body_type = b"" if b"Content-Type" in auth else b"Content-Type: application/octet-stream\r\n"
    answer = _headers_only(token_server.url, b"POST /environments HTTP/1.1\r\nHost: x\r\nContent-Length: 200000000\r\n"
                           + body_type + auth + b"\r\n")
    status_line = answer.split(b"\r\n", 1)[0]
    assert want in status_line, answer[:300]
    assert b"connection: close" in answer.lower()


def test_unauthenticated_large_bodies_do_not_grow_the_service(token_server):
    import concurrent.futures as cf

    def rss_mb() -> float:
        text = (Path("/proc") / str(token_server.proc.pid) / "status").read_text()
        return int(next(line for line in text.splitlines() if line.startswith("VmRSS")).split()[1]) / 1024

    chunk = b"\0" * (1 << 20)

    def upload():
        def body():
            for _ in range(100):   # 100 MB each, streamed
                yield chunk
        try:
            return httpx.post(token_server.url + "/environments", content=body(), headers=OCTET, timeout=60).status_code
        except httpx.TransportError:   # the server answered 401 and closed while we were still sending
            return 401

    before = rss_mb()
    with cf.ThreadPoolExecutor(4) as pool:
        codes = list(pool.map(lambda _: upload(), range(4)))
    assert codes == [401] * 4
    assert rss_mb() - before < 50, f"RSS {before:.0f} -> {rss_mb():.0f} MB"
    assert token_server.alive()


# -- a 5xx answers properly; the client sends again what got no answer -------------------------------

def test_an_unexpected_error_is_a_500_that_keeps_the_connection_usable():
    import threading

    import uvicorn
    from fastapi import FastAPI

    from service.errors import install_error_handlers
    from service.limits import RequestGate

    app = FastAPI()
    install_error_handlers(app)
    app.add_middleware(RequestGate, max_bytes=1 << 20, token=None, media_types=("application/json",))

    @app.get("/boom")
    async def boom():
        raise RuntimeError("an unforeseen failure")

    @app.get("/ok")
    async def ok():
        return {"ok": True}

    from service_server import free_port

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="critical"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as c:
            for _ in range(100):
                try:
                    c.get("/ok")
                    break
                except httpx.TransportError:
                    import time
                    time.sleep(0.05)
            for _ in range(5):   # the same keep-alive connection, answer after answer
                r = c.get("/boom")
                assert_error(r, 500, "RuntimeError", "an unforeseen failure", "still up")
                assert r.headers.get("connection", "").lower() != "close"
                assert c.get("/ok").json() == {"ok": True}
    finally:
        server.should_exit = True
        thread.join(10)


def test_the_client_sends_again_a_request_whose_connection_failed_before_an_answer():
    import socket
    import threading

    from garment_render_client import RenderClient

    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    seen = []

    def serve():
        for k in range(2):
            conn, _ = listener.accept()
            with conn:
                seen.append(conn.recv(65536).split(b"\r\n", 1)[0])
                if k == 0:   # reset, no answer
                    conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                    continue
                body = b'{"status": "ok"}'
                conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: "
                             + str(len(body)).encode() + b"\r\nConnection: close\r\n\r\n" + body)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    with RenderClient(f"http://127.0.0.1:{port}") as client:
        assert client.live() == {"status": "ok"}
        assert client.transport_retries == 1
    thread.join(5)
    listener.close()
    assert seen == [b"GET /health/live HTTP/1.1"] * 2


def _answering(answers: list[tuple[str, str, bytes]]):
    """A server on 127.0.0.1 giving `answers` (status line, content type, body) in turn, one connection
    each; returns (port, the request lines it saw, its thread)."""
    import socket
    import threading

    listener = socket.create_server(("127.0.0.1", 0))
    seen: list[bytes] = []

    def serve():
        with listener:
            for status, media_type, body in answers:
                conn, _ = listener.accept()
                with conn:
                    seen.append(conn.recv(65536).split(b"\r\n", 1)[0])
                    conn.sendall(f"HTTP/1.1 {status}\r\nContent-Type: {media_type}\r\nContent-Length: {len(body)}"
                                 f"\r\nRetry-After: 0\r\nConnection: close\r\n\r\n".encode() + body)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return listener.getsockname()[1], seen, thread


def test_the_client_sends_again_a_proxys_own_error_but_not_a_lost_registration():
    """A 5xx whose body is not the service's JSON (a proxy in front of it, e.g. Ray Serve's when its
    ingress went) is as if no answer came: sent again. A scale-out replica lost while it held a scene's
    registration (503 replica_lost) is not sent again: it may have been stored."""
    from garment_render_client import RenderClient, ServiceError

    port, seen, thread = _answering([("500 Internal Server Error", "text/plain", b"Internal Server Error"),
                                     ("200 OK", "application/json", b'{"status": "ok"}')])
    with RenderClient(f"http://127.0.0.1:{port}") as client:
        assert client.live() == {"status": "ok"} and client.transport_retries == 1
    thread.join(5)
    assert seen == [b"GET /health/live HTTP/1.1"] * 2

    lost = b'{"code": "replica_lost", "detail": "the replica holding POST /scenes went before it answered"}'
    port, seen, thread = _answering([("503 Service Unavailable", "application/json", lost)])
    with RenderClient(f"http://127.0.0.1:{port}") as client, pytest.raises(ServiceError, match="replica_lost"):
        client.create_scene("env_0", positions=[[0, 0, 0]], faces=[[0, 0, 0]])
    thread.join(5)
    assert seen == [b"POST /scenes HTTP/1.1"]


# -- a PEM set's cost is known from its settings, and refused before it is built ----------------------

@pytest.fixture(scope="module")
def tight_server(tmp_path_factory):
    """PEM limits small enough that sets a test builds in a second are on either side of them."""
    srv = ServiceProcess(tmp_path_factory.mktemp("tight"), pem_cache_bytes=128 << 20, max_pem_build_bytes=256 << 20,
                         max_pem_build_s=1.5)
    yield srv
    srv.stop()


@pytest.mark.parametrize("params, words", [
    ({"face_size": 512, "lights": 12}, ["face_size 512", "MiB exceed the PEM cache's 128 MiB",
                                        "GARMENT_RENDER_PEM_CACHE_BYTES", "would fit: face_size 256"]),
    ({"face_size": 128, "lights": 192}, ["192 lights", "GARMENT_RENDER_PEM_CACHE_BYTES", "GARMENT_RENDER_MAX_PEM_BUILD_S",
                                         "would fit: face_size 64 or lights 48"]),
    ({"face_size": 256, "lights": 24}, ["would take about 2 s", "GARMENT_RENDER_MAX_PEM_BUILD_S"]),
])
def test_a_pem_set_beyond_the_limits_is_refused_before_it_is_built(tight_server, tmp_path, params, words):
    import time

    data, name = environment_bytes(tmp_path)
    with httpx.Client(base_url=tight_server.url, timeout=120) as http:
        before = http.get("/stats").json()["jobs"]
        t0 = time.perf_counter()
        r = http.post("/environments", content=data, headers=OCTET, params={"name": name, "preset": "fast", **params})
        assert_error(r, 422, "refused before it is built", *words)
        assert time.perf_counter() - t0 < 5.0
        assert http.get("/stats").json()["jobs"]["done"] == before["done"]   # nothing reached the GL thread
        # What the answer says fits, fits.
        fit = r.json()["detail"].split("What would fit: ")[1].split(" or ")[0].split()
        ok = http.post("/environments", content=data, headers=OCTET,
                       params={"name": name, "preset": "fast", **params, fit[0]: int(fit[1])})
        assert ok.status_code in (200, 201), ok.text
        assert http.get("/stats").json()["pem_builds"]["ns_per_texel_light_measured"] is not None


def test_a_scene_whose_pem_set_is_too_costly_is_refused(http, env_id, mesh):
    body = scene_body(env_id, mesh)
    body["quality"] = {"preset": "fast", "lights": 384, "face_size": 512, "shadow_size": 64, "small_light_scale": 1}
    assert_error(http.post("/scenes", json=body), 422, "refused before it is built", "384 lights")


def test_a_huge_face_is_refused_before_any_table_of_it_is_made(tmp_path, mesh):
    """face_size 2048 with 6 lights and no preset: refused from the settings alone, before the
    glossiness calibration of a 2048^2 face is made (it once took 86-100 s and 8.6 GiB here), and the
    service's memory stays where it was."""
    import time

    cache = tmp_path / "cache"
    srv = ServiceProcess(tmp_path, cache_dir=cache)
    try:
        with httpx.Client(base_url=srv.url, timeout=120) as http:
            data, name = environment_bytes(tmp_path)
            env = http.post("/environments", content=data, headers=OCTET, params={"name": name, "preset": "fast"})
            assert env.status_code in (200, 201), env.text
            rss = _rss_mib(srv.proc.pid)
            body = scene_body(env.json()["id"], mesh)
            body["quality"] = {"face_size": 2048, "lights": 6}
            t0 = time.perf_counter()
            assert_error(http.post("/scenes", json=body), 422, "refused before it is built", "face_size 2048",
                         "GARMENT_RENDER_MAX_PEM_BUILD_BYTES")
            assert time.perf_counter() - t0 < 3.0
            assert _rss_mib(srv.proc.pid) < rss + 64
        assert not list((cache / "lobe-tables").glob("2048-*"))
    finally:
        srv.stop()


def _extremes(st) -> list:
    """Each end of a registry setting's range (every value of a choice or a switch)."""
    if st.choices is not None:
        return list(st.choices)
    if st.type is bool:
        return [False, True]
    lo = st.minimum + (1 if st.type is int else 1e-6) * st.above_minimum
    return [st.type(lo), st.type(st.maximum)]


@pytest.mark.system
def test_every_registry_extreme_alone_and_together_is_answered_in_bounded_time_and_memory(tmp_path, mesh):
    """Every end of every quality setting over balanced, then every setting at its least and at its
    greatest at once: a scene (and one frame of it) or a 422 that names a limit, each in seconds,
    never a 5xx; the service's peak memory bounded and its memory back after."""
    import time

    from renderer import config

    srv = ServiceProcess(tmp_path, cache_dir=tmp_path / "cache")
    cases = [{st.name: v} for st in config.SETTINGS for v in _extremes(st)]
    cases += [{st.name: _extremes(st)[i] for st in config.SETTINGS if st.choices is None} for i in (0, -1)]
    slowest = (0.0, None)
    try:
        with httpx.Client(base_url=srv.url, timeout=300) as http:
            data, name = environment_bytes(tmp_path)
            env = http.post("/environments", content=data, headers=OCTET, params={"name": name, "preset": "fast"})
            assert env.status_code in (200, 201), env.text
            rss = _rss_mib(srv.proc.pid)
            answered = {201: 0, 422: 0}
            for quality in cases:
                body = scene_body(env.json()["id"], mesh, output={"width": 32, "height": 32})
                body["quality"] = {"preset": "balanced", **quality}
                t0 = time.perf_counter()
                r = http.post("/scenes", json=body)
                assert r.status_code in answered, (quality, r.status_code, r.text)
                if r.status_code == 201:
                    f = post_frame(http, r.json()["id"], mesh.positions)
                    assert f.status_code == 200, (quality, f.text)
                    http.delete(f"/scenes/{r.json()['id']}")
                else:
                    # The answer names what is over which limit.
                    detail = r.json()["detail"]
                    assert any(w in str(detail) for w in ("limit", "at most", "exceed", "must be", "refused")), detail
                answered[r.status_code] += 1
                slowest = max(slowest, (time.perf_counter() - t0, quality), key=lambda x: x[0])
            # Measured: 41 cases, 35 scenes and 6 refusals, the slowest 2.7 s (a new PEM set); memory 204 MiB
            # before, 546 MiB at the peak, 295 MiB after.
            assert slowest[0] < 20.0, slowest
            assert answered[201] > len(cases) // 2 and answered[422] >= 2, answered
            # Peak memory of the whole run, and what stays after it (the scenes deleted).
            peak = _hwm_mib(srv.proc.pid)
            assert peak < rss + 1536, (peak, rss)
            assert _rss_mib(srv.proc.pid) < rss + 512
            assert http.get("/health/ready").status_code == 200
    finally:
        srv.stop()


def _hwm_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_the_pem_cost_is_the_set_s_memory(renderer):
    from renderer.envmap import environment_from_array, studio_environment
    from renderer.lighting.pem_plan import PEMSettings, pem_cost

    env = environment_from_array(studio_environment(128), "latlong", 32, name="studio")
    for settings in (PEMSettings(12), PEMSettings(24, base_level=2), PEMSettings(6, levels=3)):
        pems = renderer.build_pems(env.cube, settings)
        try:
            cost = pem_cost(32, settings, export=True)
            assert cost.stored_bytes == pems.nbytes
            assert cost.peak_bytes > cost.stored_bytes + sum(a.nbytes for a in pems.export().values())
        finally:
            pems.release()


# -- abandoned work is dropped; readiness says what the render thread does ----------------------------

def _batch_bytes(mesh, n: int) -> bytes:
    # Every frame a little different, so that none is a copy of the one before.
    base = np.asarray(mesh.positions, np.float32)
    return b"".join((base + np.float32(1e-4 * k)).astype("<f4").tobytes() for k in range(n))


def test_a_batch_whose_client_left_is_stopped_between_frames(server, http, env_id, mesh):
    import socket
    import time
    from urllib.parse import urlsplit

    # Frames of 256 x 256: a 1000-frame batch takes many seconds here (and on a GPU, more than the 0.5 s).
    r = http.post("/scenes", json=scene_body(env_id, mesh, output={"width": 256, "height": 256}))
    assert r.status_code == 201, r.text
    scene_id = r.json()["id"]
    first = post_frame(http, scene_id, mesh.positions)
    assert first.status_code == 200
    before = int(first.headers["X-Frame-Sequence"])
    abandoned = http.get("/stats").json()["jobs"]["abandoned"]
    body = _batch_bytes(mesh, 1000)
    u = urlsplit(server.url)
    with socket.create_connection((u.hostname, u.port)) as s:
        s.sendall(f"POST /scenes/{scene_id}/frames/batch HTTP/1.1\r\nHost: x\r\nContent-Type: "
                  f"application/octet-stream\r\nContent-Length: {len(body)}\r\n\r\n".encode() + body)
        deadline = time.monotonic() + 60.0   # the batch is rendering (the render thread says so); its client leaves
        while http.get("/health/ready").json()["current_job"] is None:
            assert time.monotonic() < deadline, "the batch never started"
            time.sleep(0.05)
    t0 = time.perf_counter()
    r = post_frame(http, scene_id, mesh.positions)
    waited = time.perf_counter() - t0
    assert r.status_code == 200, r.text
    assert waited < 3.0, f"the next frame waited {waited:.1f} s behind the abandoned batch"
    sequence = int(r.headers["X-Frame-Sequence"])
    assert sequence - before < 500, f"{sequence - before} sequence numbers spent, most on frames nobody received"
    assert http.get("/stats").json()["jobs"]["abandoned"] == abandoned + 1
    http.delete(f"/scenes/{scene_id}")


def test_readiness_turns_503_while_the_render_thread_is_held_and_says_by_what(server, http, scene_id, mesh):
    import threading
    import time

    assert http.get("/health/ready").json()["current_job"] is None
    body = _batch_bytes(mesh, 200)
    answer = {}

    def batch():
        with httpx.Client(base_url=server.url, timeout=120) as c:
            answer["r"] = c.post(f"/scenes/{scene_id}/frames/batch", content=body, headers=OCTET)

    thread = threading.Thread(target=batch)
    thread.start()
    seen = None
    deadline = time.monotonic() + 60
    while thread.is_alive() and time.monotonic() < deadline:
        r = http.get("/health/ready")
        if r.status_code == 503:
            seen = r
            break
        time.sleep(0.05)
    thread.join(120)
    assert answer["r"].status_code == 200
    assert seen is not None, "readiness never said the thread was held"
    info = seen.json()
    assert info["status"] == "busy" and "batch of 200 frames" in info["current_job"]["what"]
    assert info["current_job"]["age_s"] >= 0.5 and "GARMENT_RENDER_READY_MAX_BUSY_S" in info["detail"]
    assert int(seen.headers["retry-after"]) >= 1
    assert http.get("/health/ready").status_code == 200   # free again


# -- environment maps: the decoded size is judged on the header, their memory in one budget ------------

@pytest.fixture(scope="module")
def env_budget_server(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("envs"), max_env_pixels=1 << 20, max_environment_bytes=10 << 20)
    yield srv
    srv.stop()


def _exr(path: Path, img: np.ndarray, compression=None) -> bytes:
    import OpenEXR

    header = {"compression": compression} if compression is not None else {}
    OpenEXR.File(header, {"RGB": np.ascontiguousarray(img)}).write(str(path))
    return path.read_bytes()


def test_a_decompression_bomb_is_refused_on_its_header(env_budget_server, tmp_path):
    import time

    import OpenEXR

    # 4 Mpx of one value in ZIP blocks: a few kB of file, 48 MB decoded.
    bomb = _exr(tmp_path / "bomb.exr", np.full((2048, 2048, 3), 0.5, np.float16), OpenEXR.ZIP_COMPRESSION)
    assert len(bomb) < 200_000
    t0 = time.perf_counter()
    r = httpx.post(env_budget_server.url + "/environments", content=bomb, headers=OCTET, timeout=60)
    assert_error(r, 413, "2048x2048", "GARMENT_RENDER_MAX_ENV_PIXELS")
    assert time.perf_counter() - t0 < 2.0


def test_the_environments_memory_is_one_budget(env_budget_server, tmp_path):
    from renderer.envmap import sky_environment, studio_environment

    url = env_budget_server.url
    # 512 x 1024 lat-long maps: 6 MiB decoded each, so the second passes the 10 MiB budget.
    a = _exr(tmp_path / "a.exr", studio_environment(1024))
    b = _exr(tmp_path / "b.exr", sky_environment(1024))
    params = {"preset": "fast", "lights": 6, "face_size": 16}
    first = httpx.post(url + "/environments", content=a, headers=OCTET, params=params, timeout=60)
    assert first.status_code == 201, first.text
    r = httpx.post(url + "/environments", content=b, headers=OCTET, params=params, timeout=60)
    assert_error(r, 409, "GARMENT_RENDER_MAX_ENVIRONMENT_BYTES", "MiB", "delete one")
    stats = httpx.get(url + "/stats").json()["environments"]
    assert 6 << 20 < stats["bytes"] <= stats["max_bytes"] == 10 << 20
    assert httpx.delete(url + f"/environments/{first.json()['id']}").status_code == 204
    r = httpx.post(url + "/environments", content=b, headers=OCTET, params=params, timeout=60)
    assert r.status_code == 201, r.text


# -- the disk cache: orphans of killed writers go, entries are checked against their key ----------------

def test_a_restarted_service_cleans_orphans_and_rebuilds_an_entry_under_the_wrong_key(tmp_path):
    from renderer.envmap import sky_environment, studio_environment

    cache = tmp_path / "pem-cache"
    a = _exr(tmp_path / "a.exr", studio_environment(256))
    b = _exr(tmp_path / "b.exr", sky_environment(256))
    params = {"preset": "fast", "lights": 6, "face_size": 16}
    srv = ServiceProcess(tmp_path, pem_cache_dir=cache)
    try:
        ids = [httpx.post(srv.url + "/environments", content=m, headers=OCTET, params=params, timeout=60).json()
               for m in (a, b)]
        keys = [env["pem_sets"][0]["key"] for env in ids]
    finally:
        srv.stop()
    (cache / f"{keys[1]}.npz").write_bytes((cache / f"{keys[0]}.npz").read_bytes())   # a's set under b's key
    (cache / ".tmp-killed-writer").write_bytes(b"\0" * 4096)                           # what kill -9 leaves
    srv = ServiceProcess(tmp_path, pem_cache_dir=cache)
    try:
        stats = httpx.get(srv.url + "/stats").json()["pem_cache"]
        assert (stats["temporaries_removed"], stats["temporary_bytes_removed"]) == (1, 4096)
        assert not (cache / ".tmp-killed-writer").exists()
        r = httpx.post(srv.url + "/environments", content=b, headers=OCTET, params=params, timeout=60)
        assert r.status_code == 201, r.text
        assert r.json()["pem_sets"][0]["source"] == "built"      # not a's set from the copied file
        stats = httpx.get(srv.url + "/stats").json()["pem_cache"]
        assert stats["disk_key_mismatches"] == 1 and stats["disk_hits"] == 0
    finally:
        srv.stop()


def test_idle_scenes_give_their_slots_to_new_ones(tmp_path):
    import time

    # The timeout leaves room for a machine slowed by other work between a's creation and the refusal
    # (at 1 s, a loaded run saw a idle already and the third scene took its slot).
    idle_s = 3.0
    srv = ServiceProcess(tmp_path, max_scenes=2, scene_idle_timeout_s=idle_s)
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as http:
            env = upload_environment(http, tmp_path)[0]["id"]
            mesh = garment(8)
            made = time.monotonic()
            a, b = (http.post("/scenes", json=scene_body(env, mesh)).json()["id"] for _ in range(2))
            both = time.monotonic()
            assert_error(http.post("/scenes", json=scene_body(env, mesh)), 409, "GARMENT_RENDER_MAX_SCENES")
            assert time.monotonic() - made < idle_s    # the refusal was judged with both scenes in use
            time.sleep(max(0.0, both + idle_s + 0.3 - time.monotonic()))   # both idle now
            assert post_frame(http, a, mesh.positions).status_code == 200    # a is in use again; b is idle
            c = http.post("/scenes", json=scene_body(env, mesh))
            assert c.status_code == 201, c.text
            assert_error(post_frame(http, b, mesh.positions), 404, "released after", "SCENE_IDLE_TIMEOUT_S")
            assert post_frame(http, a, mesh.positions).status_code == 200
            assert sorted(s["id"] for s in http.get("/scenes").json()) == sorted([a, c.json()["id"]])
    finally:
        srv.stop()


# -- what an operator reads: request ids on answers and log lines, JSON logs -----------------------------

def test_every_answer_and_log_line_carries_the_request_id(tmp_path):
    import json

    srv = ServiceProcess(tmp_path, log_level="info", log_format="json")
    try:
        mine = httpx.get(srv.url + "/scenes/scn_nope", headers={"X-Request-Id": "sim-42.frame-7"})
        assert mine.status_code == 404 and mine.headers["x-request-id"] == "sim-42.frame-7"
        made = httpx.get(srv.url + "/health/live", headers={"X-Request-Id": "bad id\twith spaces"})
        rid = made.headers["x-request-id"]
        assert len(rid) == 16 and int(rid, 16) >= 0          # an unusable id is replaced by one of ours
        refused = httpx.post(srv.url + "/environments", content=b"x", headers={"Content-Type": "text/html"})
        assert refused.status_code == 415 and refused.headers["x-request-id"]
    finally:
        srv.stop()
    lines = [json.loads(line) for line in srv.log_path.read_text().splitlines() if line.startswith("{")]
    assert lines and all({"time", "level", "logger", "request_id", "message"} <= set(x) for x in lines)
    ids = {x["request_id"] for x in lines if x["logger"] == "uvicorn.access"}
    assert {"sim-42.frame-7", rid} <= ids


def test_a_terminated_service_finishes_the_requests_in_flight_and_takes_no_new_ones(tmp_path, mesh):
    import signal
    import threading
    import time

    srv = ServiceProcess(tmp_path, shutdown_timeout_s=60)
    try:
        with httpx.Client(base_url=srv.url, timeout=120) as http:
            env = upload_environment(http, tmp_path)[0]["id"]
            sid = http.post("/scenes", json=scene_body(env, mesh, output={"width": 128, "height": 128})).json()["id"]
        answer = {}

        def batch():
            with httpx.Client(base_url=srv.url, timeout=120) as c:
                answer["r"] = c.post(f"/scenes/{sid}/frames/batch", content=_batch_bytes(mesh, 300), headers=OCTET)

        thread = threading.Thread(target=batch)
        thread.start()
        time.sleep(0.5)
        srv.proc.send_signal(signal.SIGTERM)
        time.sleep(0.3)
        with pytest.raises(httpx.TransportError):   # the listener is closed: no new work
            httpx.get(srv.url + "/health/live", timeout=2)
        thread.join(120)
        r = answer["r"]
        assert r.status_code == 200 and r.json()["n_frames"] == 300   # the batch in flight was answered whole
        # A clean exit; uvicorn re-raises the signal it handled once it has shut down.
        assert srv.proc.wait(60) in (0, -signal.SIGTERM)
    finally:
        srv.stop()


def test_a_connection_that_sends_no_headers_in_time_is_closed(tmp_path):
    import socket
    import time
    from urllib.parse import urlsplit

    srv = ServiceProcess(tmp_path, header_timeout_s=0.5)
    try:
        u = urlsplit(srv.url)
        idle, trickle = (socket.create_connection((u.hostname, u.port), timeout=5) for _ in range(2))
        trickle.sendall(b"GET /health/live HTTP/1.1\r\nHo")     # one byte at a time, never done
        t0 = time.perf_counter()
        for s in (idle, trickle):
            assert s.recv(1024) == b""                            # closed by the server
            s.close()
        assert time.perf_counter() - t0 < 3.0
        # A client that completes its headers in time is served, on the same kind of connection.
        with socket.create_connection((u.hostname, u.port), timeout=5) as s:
            s.sendall(b"GET /health/live HTTP/1.1\r\nHost: x\r\n\r\n")
            answer = b""
            while not answer.endswith(b'{"status":"ok"}'):   # the whole answer, however it is split
                chunk = s.recv(1024)
                assert chunk, answer
                answer += chunk
            assert answer.startswith(b"HTTP/1.1 200")
            time.sleep(1.0)                                       # then idles past the deadline: closed
            assert s.recv(1024) == b""
    finally:
        srv.stop()


def test_every_service_setting_is_documented_with_its_default():
    from service.settings import ServiceSettings, reference_table

    stored = (Path(__file__).resolve().parents[1] / "docs" / "service-settings.md").read_text()
    assert stored == reference_table(), "docs/service-settings.md is stale: regenerate it with " \
                                        "service.settings.reference_table()"
    assert all(f.description for f in ServiceSettings.model_fields.values())


def test_a_client_that_leaves_mid_upload_is_one_info_line_with_its_request_id(tmp_path, mesh):
    import socket
    import time

    srv = ServiceProcess(tmp_path, log_level="info")
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as http:
            env, _, _ = upload_environment(http, tmp_path)
            sid = http.post("/scenes", json=scene_body(env["id"], mesh)).json()["id"]
            body = np.asarray(mesh.positions, np.float32).tobytes()
            with socket.create_connection(("127.0.0.1", srv.port)) as s:
                s.sendall(f"POST /scenes/{sid}/frames HTTP/1.1\r\nHost: x\r\nContent-Type: application/octet-stream\r\n"
                          f"Content-Length: {len(body)}\r\nX-Request-ID: leaves-early\r\n\r\n".encode()
                          + body[: len(body) // 2])
                time.sleep(0.3)
            deadline = time.monotonic() + 10
            while "leaves-early" not in srv.log() and time.monotonic() < deadline:
                time.sleep(0.1)
            lines = [line for line in srv.log().splitlines() if "leaves-early" in line]
            assert len(lines) == 1 and " INFO " in lines[0] and "client disconnected" in lines[0], lines
            assert "Traceback" not in srv.log() and " ERROR " not in srv.log()
            assert http.post(f"/scenes/{sid}/frames", content=body, headers=OCTET).status_code == 200   # still serving
    finally:
        srv.stop()
