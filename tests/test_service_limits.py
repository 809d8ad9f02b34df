"""The service under attack, against a real server on 127.0.0.1: every request bounded in memory and
time before its work starts, degenerate input refused with a 422 that names it, honest readiness."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from service_server import ServiceProcess, environment_bytes, garment, scene_body

OCTET = {"Content-Type": "application/octet-stream"}


def assert_error(r: httpx.Response, status: int, *words: str) -> None:
    assert r.status_code == status, f"expected {status}, got {r.status_code}: {r.text}"
    detail = r.json()["detail"]
    for w in words:
        assert w.lower() in detail.lower(), f"{w!r} not in {detail!r}"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("limits")
    srv = ServiceProcess(tmp, queue_size=4)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=120) as c:
        yield c


@pytest.fixture(scope="module")
def env_id(http, tmp_path_factory):
    data, name = environment_bytes(tmp_path_factory.mktemp("env"))
    r = http.post("/environments", content=data, headers=OCTET,
                  params={"name": name, "lights": 12, "face_size": 32, "preset": "fast"})
    assert r.status_code == 201, r.text
    return r.json()["id"]


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
