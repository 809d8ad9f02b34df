"""Scenes and environments in a state directory: a restarted service, and every process of a
multi-process one, restore them by id on first use."""

from __future__ import annotations

import httpx
import numpy as np
from service_server import ServiceProcess, environment_bytes, garment, scene_body, upload_environment

OCTET = {"Content-Type": "application/octet-stream"}


def test_restarted_service_restores_scene_by_id(tmp_path):
    data, name = environment_bytes(tmp_path)
    mesh = garment(32)
    settings = {"state_dir": tmp_path / "state", "pem_cache_dir": tmp_path / "cache"}
    first = ServiceProcess(tmp_path, **settings)
    try:
        env = httpx.post(first.url + "/environments", content=data, headers=OCTET,
                         params={"name": name, "lights": 12, "face_size": 32}, timeout=60).json()
        scene = httpx.post(first.url + "/scenes", json=scene_body(env["id"], mesh), timeout=60).json()
        before = httpx.post(f"{first.url}/scenes/{scene['id']}/frames", content=np.asarray(mesh.positions).tobytes(),
                            headers=OCTET, params={"format": "exr"}, timeout=60)
        assert before.status_code == 200
    finally:
        first.stop()
    second = ServiceProcess(tmp_path, **settings)
    try:
        after = httpx.post(f"{second.url}/scenes/{scene['id']}/frames", content=np.asarray(mesh.positions).tobytes(),
                           headers=OCTET, params={"format": "exr"}, timeout=60)
        assert after.status_code == 200, after.text
        assert after.content == before.content  # the same scene, camera and PEM set: the same linear image
        assert after.headers["x-pem-source"] == "memory"  # loaded from disk while the scene was restored
        assert httpx.get(f"{second.url}/environments/{env['id']}").status_code == 200
        assert httpx.delete(f"{second.url}/scenes/{scene['id']}").status_code == 204
        r = httpx.post(f"{second.url}/scenes/{scene['id']}/frames", content=np.asarray(mesh.positions).tobytes(),
                       headers=OCTET)
        assert r.status_code == 404
    finally:
        second.stop()


def test_two_processes_share_scenes_through_the_state_dir(tmp_path):
    """What `uvicorn --workers N` relies on, made deterministic: two processes on two ports, one state dir."""
    data, name = environment_bytes(tmp_path)
    mesh = garment(16)
    settings = {"state_dir": tmp_path / "state", "pem_cache_dir": tmp_path / "cache"}
    a = ServiceProcess(tmp_path, **settings)
    b = ServiceProcess(tmp_path, **settings)
    try:
        env = httpx.post(a.url + "/environments", content=data, headers=OCTET,
                         params={"name": name, "lights": 12, "face_size": 32}, timeout=60).json()
        sid = httpx.post(a.url + "/scenes", json=scene_body(env["id"], mesh), timeout=60).json()["id"]
        frames = [np.asarray(mesh.positions) + np.float32(0.01 * k) for k in range(4)]
        labels = {s.url: httpx.get(s.url + "/stats").json()["process"]["label"] for s in (a, b)}
        assert len(set(labels.values())) == 2
        for k, p in enumerate(frames):  # alternate between the processes, as a load balancer would
            srv = (a, b)[k % 2]
            r = httpx.post(f"{srv.url}/scenes/{sid}/frames", content=p.astype("<f4").tobytes(), headers=OCTET,
                           timeout=60)
            assert r.status_code == 200, r.text
            # Each process names itself by a label of its own, not by its id on the host.
            assert r.headers["x-render-process"] == labels[srv.url] != str(srv.proc.pid)
            # One sequence for the scene, whichever process renders it (the state dir's counter).
            assert r.headers["x-frame-sequence"] == str(k + 1)
        assert [httpx.get(f"{s.url}/scenes/{sid}").json()["frames_rendered"] for s in (a, b)] == [4, 4]
    finally:
        a.stop()
        b.stop()


def test_an_empty_token_setting_means_no_token(monkeypatch):
    from service.settings import ServiceSettings

    monkeypatch.setenv("GARMENT_RENDER_TOKEN", "")
    assert ServiceSettings().token is None
    monkeypatch.setenv("GARMENT_RENDER_TOKEN", "s3cret")
    assert ServiceSettings().token.get_secret_value() == "s3cret"


def test_a_restored_scene_keeps_an_uploaded_floor_that_casts_nothing(tmp_path):
    import trimesh

    data, name = environment_bytes(tmp_path)
    mesh = garment(16)
    lo, hi = np.asarray(mesh.positions).min(axis=0), np.asarray(mesh.positions).max(axis=0)
    span, c, y = 3.0 * float((hi - lo).max()), 0.5 * (lo + hi), float(lo[1]) - 0.05
    floor = np.array([[c[0] - span, y, c[2] - span], [c[0] + span, y, c[2] - span],
                      [c[0] + span, y, c[2] + span], [c[0] - span, y, c[2] + span]])
    path = tmp_path / "floor.ply"
    trimesh.Trimesh(floor, [[0, 2, 1], [0, 3, 2]], process=False).export(path)
    settings = {"state_dir": tmp_path / "state", "pem_cache_dir": tmp_path / "cache"}
    frame = np.asarray(mesh.positions).astype("<f4").tobytes()
    first = ServiceProcess(tmp_path, **settings)
    try:
        env = httpx.post(first.url + "/environments", content=data, headers=OCTET,
                         params={"name": name, "lights": 12, "face_size": 32}, timeout=60).json()
        floor_id = httpx.post(first.url + "/meshes", content=path.read_bytes(), headers=OCTET,
                              params={"format": "ply"}, timeout=60).json()["id"]
        body = scene_body(env["id"], mesh, body={"mesh_id": floor_id, "cast_shadows": False})
        scene = httpx.post(first.url + "/scenes", json=body, timeout=60)
        assert scene.status_code == 201, scene.text
        sid = scene.json()["id"]
        before = httpx.post(f"{first.url}/scenes/{sid}/frames", content=frame, headers=OCTET,
                            params={"format": "exr"}, timeout=60)
        assert before.status_code == 200, before.text
    finally:
        first.stop()
    second = ServiceProcess(tmp_path, **settings)   # the uploaded floor is not in this process's memory
    try:
        after = httpx.post(f"{second.url}/scenes/{sid}/frames", content=frame, headers=OCTET,
                           params={"format": "exr"}, timeout=60)
        assert after.status_code == 200, after.text
        # A floor that cast shadows would change the shadow maps' fit, and the picture.
        assert after.content == before.content
    finally:
        second.stop()


def test_a_restarted_service_lists_its_stored_scenes_and_unknown_ids_leave_nothing_behind(tmp_path):
    mesh = garment(16)
    settings = {"state_dir": tmp_path / "state", "pem_cache_dir": tmp_path / "cache"}
    first = ServiceProcess(tmp_path, **settings)
    try:
        with httpx.Client(base_url=first.url, timeout=60) as http:
            env = upload_environment(http, tmp_path)[0]
            made = sorted(http.post("/scenes", json=scene_body(env["id"], mesh)).json()["id"] for _ in range(2))
    finally:
        first.stop()
    (tmp_path / "state" / "scenes" / ".tmp-killed").write_bytes(b"{")   # a scene write cut short
    second = ServiceProcess(tmp_path, **settings)
    try:
        listed = httpx.get(second.url + "/scenes", timeout=60).json()
        assert sorted(s["id"] for s in listed) == made
        with httpx.Client(base_url=second.url, timeout=30) as c:
            for k in range(300):
                assert c.post(f"/scenes/scene_nope{k}/frames", content=b"\0" * 12, headers=OCTET).status_code == 404
        state = httpx.get(second.url + "/stats").json()["state"]
        assert state["restorations_pending"] == 0 and state["stored_scenes"] == 2
        assert state["temporaries_removed"] == 1
    finally:
        second.stop()


def _count(root, scene_id, times, out):
    from service.state import StateDir

    state = StateDir(root)
    out.put([state.count_frames(scene_id) for _ in range(times)])


def test_the_frame_count_is_one_sequence_over_processes(tmp_path):
    """StateDir.count_frames under its file lock: two processes counting the same scene at once get
    every number once; another scene counts apart; deleting the scene ends its count."""
    import multiprocessing as mp

    from service.state import StateDir

    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    procs = [ctx.Process(target=_count, args=(tmp_path, "scn_0a", 200, out)) for _ in range(2)]
    for p in procs:
        p.start()
    got = [out.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    assert sorted(got[0] + got[1]) == list(range(1, 401))
    assert all(a < b for g in got for a, b in zip(g, g[1:]))   # each process's own answers rise
    state = StateDir(tmp_path)
    assert (state.count_frames("scn_0a", 0), state.count_frames("scn_0b", 2)) == (400, 2)
    state.delete_scene("scn_0a")
    assert state.count_frames("scn_0a", 0) == 0


def test_the_hosts_paths_and_process_id_are_shown_only_behind_a_token(tmp_path):
    settings = {"state_dir": tmp_path / "state", "pem_cache_dir": tmp_path / "cache"}
    open_srv = ServiceProcess(tmp_path, **settings)
    try:
        r = httpx.get(open_srv.url + "/stats")
    finally:
        open_srv.stop()
    assert str(tmp_path) not in r.text and "pid" not in r.json()["process"], r.text
    token = "s3cret-token"
    closed = ServiceProcess(tmp_path, token=token, **settings)
    try:
        stats = httpx.get(closed.url + "/stats", headers={"Authorization": f"Bearer {token}"}).json()
    finally:
        closed.stop()
    assert stats["state"]["dir"] == str(tmp_path / "state") and stats["pem_cache"]["disk_dir"] == str(tmp_path / "cache")
    assert stats["process"]["pid"] == closed.proc.pid and len(stats["process"]["label"]) == 8
