"""The service as Ray Serve replicas (service/ray_serve.py), for real: `garment-render serve --ray
--replicas 2` starts a local Ray instance on 127.0.0.1; scenes registered through the HTTP API stay on
the replica that registered them (each answer names it), a replica killed between two frames of a
sequence or in the middle of a batch costs no frame (each is answered once, 200), and the images are
the same as a single process's."""

from __future__ import annotations

import ipaddress
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_server import ServiceProcess, garment, scene_body, upload_environment

ray = pytest.importorskip("ray", reason="Ray is an optional extra (pip install .[ray]; scripts/setup.sh installs it)")

from garment_render_client import RenderClient  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cluster():
    from service.load import serve_ray

    # Under a short root: Ray's sockets are AF_UNIX paths (at most 107 bytes), and pytest's own folder
    # under a parallel run's worker is too deep for them.
    tmp = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))
    # Without GARMENT_RENDER_STATE_DIR: a local instance's replicas share the user's default directory.
    proc, url, env = serve_ray(2, tmp, timeout_s=240, state_dir=False)
    try:
        yield {"url": url, "tmp": tmp, "env": env, "pid": proc.pid}
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(tmp, ignore_errors=True)


def _replicas(env) -> list[str]:
    """The names of the render deployment's replica actors (not the ingress's), asked of the running Ray
    instance."""
    code = ("import ray; ray.init(address='auto', logging_level='ERROR'); "
            "print('\\n'.join(a['name'] for a in ray.util.list_named_actors(all_namespaces=True) "
            "if a['name'].startswith('SERVE_REPLICA::garment-render#garment-render#')))")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return [n for n in r.stdout.split() if n]


def _kill(env, name: str) -> None:
    code = (f"import ray; ray.init(address='auto', logging_level='ERROR'); "
            f"ray.kill(ray.get_actor({name!r}, namespace='serve'), no_restart=False)")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def _listening(pid: int) -> list[tuple[str, int, int]]:
    """(address, port, pid) of every TCP socket listening in process `pid` and its descendants, from
    /proc (Linux)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:   # the process went
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    tree, todo = [], [pid]
    while todo:
        p = todo.pop()
        tree.append(p)
        todo.extend(children.get(p, ()))
    owner = {}
    for p in tree:
        for fd in Path(f"/proc/{p}/fd").glob("*"):
            try:
                link = str(fd.readlink())
            except OSError:
                continue
            if link.startswith("socket:["):
                owner[int(link[8:-1])] = p
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            local, state, inode = cols[1], cols[3], int(cols[9])
            if state != "0A" or inode not in owner:   # 0A: LISTEN
                continue
            hexaddr, hexport = local.split(":")
            raw = bytes.fromhex(hexaddr)
            # /proc writes the address as 32-bit words in host order (little-endian here)
            words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
            found.append((ipaddress.ip_address(words).compressed, int(hexport, 16), owner[inode]))
    return found


def _loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address)
    return ip.is_loopback or (ip.version == 6 and ip.ipv4_mapped is not None and ip.ipv4_mapped.is_loopback)


@pytest.mark.system
@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads listening sockets from Linux's /proc")
def test_a_local_instance_listens_on_the_loopback_alone(cluster):
    # Ray's GCS, raylet, workers and agents, the replicas and Serve's proxy: every process under serve --ray.
    listening = _listening(cluster["pid"])
    port = int(cluster["url"].rsplit(":", 1)[1])
    assert any(p == port for _, p, _ in listening), listening   # the proxy's port is seen: the check reads
    assert len({pid for _, _, pid in listening}) >= 4, listening   # GCS, raylet, workers, not the driver alone
    # Each Serve replica's inter-deployment gRPC server too, which Ray Serve binds to [::] with no
    # setting for it (service/ray_serve.py binds it to the node's address: here the loopback).
    replicas = [(a, p) for a, p, pid in listening if Path(f"/proc/{pid}/comm").read_text().startswith("ray::ServeRepl")]
    assert len(replicas) >= 4, listening   # two ingress and two render replicas
    wide = [(a, p, Path(f"/proc/{pid}/comm").read_text().strip()) for a, p, pid in listening if not _loopback(a)]
    assert wide == [], wide


def _readme_block(path: Path, marker: str) -> str:
    text = path.read_text()
    start = text.index("```sh\n", text.index(marker)) + len("```sh\n")
    return text[start:text.index("```", start)]


@pytest.mark.system
def test_the_service_readmes_recipe_reaches_this_ray_instance(cluster):
    """service/README.md's lines for reaching the instance `serve --ray` started, run as written (its
    address put in), from an environment that names no Ray variable of its own."""
    block = _readme_block(ROOT / "service" / "README.md", "another process on the")
    command = block.replace("HOST:PORT", cluster["env"]["RAY_ADDRESS"]).replace(".venv/bin/python", sys.executable)
    env = {k: v for k, v in cluster["env"].items() if not k.startswith("RAY_") or k == "RAY_TMPDIR"}
    r = subprocess.run(["bash", "-c", command], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    names = r.stdout.split()
    assert sum(n.startswith("SERVE_REPLICA::garment-render#garment-render#") for n in names) == 2, names
    assert sum(n.startswith("SERVE_REPLICA::garment-render#garment-render-ingress#") for n in names) == 2, names


@pytest.mark.system
def test_a_local_instance_without_a_state_dir_shares_the_default_one(cluster):
    state = cluster["tmp"] / "xdg" / "garment-render" / "state"
    log = next(cluster["tmp"].glob("serve-*.log")).read_text()
    assert f"GARMENT_RENDER_STATE_DIR is not set: the replicas on this machine share {state}" in log
    assert state.is_dir()


@pytest.mark.system
def test_another_ray_instance_on_the_machine_is_not_the_one_reached(cluster, tmp_path):
    """A process told the cluster's environment reaches its Ray instance, not another running beside it
    (a second cluster of a parallel test run): `ray.init(address="auto")` alone attaches to any instance
    it finds when none was started by `ray start`, and its kills then missed (named actor not found)."""
    env = {k: v for k, v in cluster["env"].items() if k != "RAY_ADDRESS"}
    env["RAY_TMPDIR"] = tempfile.mkdtemp(prefix="ray-other-", dir="/tmp")
    code = ("import sys, ray\n"
            "ray.init(include_dashboard=False, logging_level='ERROR')\n"
            "print(ray.get_runtime_context().gcs_address, flush=True)\n"
            "sys.stdin.readline()\n")
    other = subprocess.Popen([sys.executable, "-c", code], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        address = other.stdout.readline().strip()
        assert address and address != cluster["env"]["RAY_ADDRESS"], address
        names = _replicas(cluster["env"])
        # The two render replicas of this cluster: their names end with the ids its answers carry.
        with httpx.Client(base_url=cluster["url"], timeout=120) as http:
            ids = {http.get("/health/ready").headers["x-replica"] for _ in range(8)}
        assert len(names) == 2 and all(any(n.endswith(i) for n in names) for i in ids), (names, ids)
    finally:
        other.stdin.close()
        other.wait(timeout=120)
        shutil.rmtree(env["RAY_TMPDIR"], ignore_errors=True)


@pytest.mark.system
def test_scenes_stay_on_their_replica_and_survive_one_dying(cluster, tmp_path):
    mesh = garment(16)
    frames = [np.asarray(mesh.positions) + np.float32(0.01 * k) for k in range(8)]
    with httpx.Client(base_url=cluster["url"], timeout=120) as http:
        env, _, _ = upload_environment(http, tmp_path)
    with RenderClient(cluster["url"], max_retries=200, max_retry_wait_s=1.0) as c:
        # Every frame of a scene, from the first, goes to the replica that registered it.
        scenes, owners = [], {}
        for _ in range(2):
            r = c.http.post("/scenes", json=c.scene_spec(env["id"], positions=mesh.positions, faces=mesh.faces,
                                                         **{k: v for k, v in scene_body(env["id"], mesh).items()
                                                            if k in ("quality", "output")}))
            assert r.status_code == 201, r.text
            scenes.append(r.json())
            owners[r.json()["id"]] = r.headers["x-replica"]
        for s in scenes:
            seen = {c.send_frame(s["id"], frames[0], frame_index=0).headers["x-replica"] for _ in range(3)}
            assert seen == {owners[s["id"]]}, (seen, owners)
        # Kill the replica holding the first scene half way through its sequence. Ray's list of named
        # actors can lag a replica that came back after an earlier test's kill: it is asked again for
        # a while before the owner counts as missing.
        sid = scenes[0]["id"]
        deadline, live = time.monotonic() + 30.0, _replicas(cluster["env"])
        while not any(n.endswith(owners[sid]) for n in live) and time.monotonic() < deadline:
            time.sleep(1.0)
            live = _replicas(cluster["env"])
        assert len(live) == 2, live
        victim = next((n for n in live if n.endswith(owners[sid])), None)
        assert victim is not None, (owners[sid], live)
        got, sequence = {}, []
        for k, positions in enumerate(frames):
            if k == 4:
                _kill(cluster["env"], victim)
            f = c.send_frame(sid, positions, frame_index=k)
            assert f.frame_index == k and k not in got
            got[k] = (f.array(), f.headers["x-replica"])
            sequence.append(int(f.headers["x-frame-sequence"]))
            assert "," not in f.headers["x-request-id"]   # one id, not the proxy's and the service's
        assert sorted(got) == list(range(len(frames)))
        # One count for the scene on every replica (the shared state directory's), rising across the
        # kill: each frame answered once, a frame the killed replica had counted only skipped.
        assert all(a < b for a, b in zip(sequence, sequence[1:])) and sequence[0] > 3, sequence
        # Before the kill, its owner answered; after it, another replica did (from the stored registration).
        assert {got[k][1] for k in range(4)} == {owners[sid]}
        assert all(got[k][1] != owners[sid] for k in range(4, len(frames))), [g[1] for g in got.values()]
        # The other scene is answered too: by its replica, or by the killed one's successor where the
        # ring gave the new replica its id (a consistent hash moves only the keys of a changed replica).
        other = scenes[1]["id"]
        now = c.send_frame(other, frames[1]).headers["x-replica"]
        assert now != owners[sid] and (now == owners[other] or now not in owners.values()), (now, owners)
    # The same frames from one process without Ray: the same images.
    single = ServiceProcess(tmp_path)
    try:
        with httpx.Client(base_url=single.url, timeout=120) as http:
            e, _, _ = upload_environment(http, tmp_path)
        with RenderClient(single.url) as c:
            s = c.create_scene(e["id"], positions=mesh.positions, faces=mesh.faces,
                               **{k: v for k, v in scene_body(e["id"], mesh).items() if k in ("quality", "output")})
            for k, positions in enumerate(frames):
                np.testing.assert_array_equal(c.send_frame(s["id"], positions).array(), got[k][0])
    finally:
        single.stop()


class _Killer:
    """A process attached to the Ray instance, ready to kill one replica the moment it is told to (its
    start, some seconds of Ray's, is paid before)."""

    def __init__(self, env, name: str):
        code = (f"import sys, ray\n"
                f"ray.init(address='auto', logging_level='ERROR')\n"
                f"a = ray.get_actor({name!r}, namespace='serve')\n"
                f"print('ready', flush=True)\n"
                f"if sys.stdin.readline().strip() == 'now':\n"
                f"    ray.kill(a, no_restart=False)\n"
                f"    print('killed', flush=True)\n")
        self.proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().strip() == "ready"

    def kill(self) -> None:
        self.proc.stdin.write("now\n")
        self.proc.stdin.flush()
        assert self.proc.stdout.readline().strip() == "killed"
        assert self.proc.wait(timeout=60) == 0

    def close(self) -> None:
        """Let a killer that was not told to kill go: told nothing but its input's end, it kills nothing."""
        if self.proc.poll() is None:
            self.proc.stdin.close()
            self.proc.wait(timeout=60)


@pytest.mark.system
def test_a_replica_killed_in_the_middle_of_a_batch_costs_no_frame(cluster, tmp_path):
    """The batch's replica is killed while it renders: the same request, with no retry of the client's
    (plain httpx), is answered 200 with every frame once, by the other replica (the ingress sent it
    again); a scene's frame after it is answered too.

    The victim is the replica that says it runs the batch, not the one that answered an earlier frame: a
    replica killed by an earlier test may have come back since, and the ring that sent the earlier frame
    need not be the ring that sends the batch."""
    mesh = garment(16)
    with httpx.Client(base_url=cluster["url"], timeout=300) as http:
        env, _, _ = upload_environment(http, tmp_path, known=True)
        with RenderClient(cluster["url"], max_retries=200, max_retry_wait_s=1.0) as c:
            s = c.create_scene(env["id"], positions=mesh.positions, faces=mesh.faces,
                               **{k: v for k, v in scene_body(env["id"], mesh).items() if k in ("quality", "output")})
            c.send_frame(s["id"], mesh.positions)
        route = {"serve_multiplexed_model_id": s["id"]}   # requests of the scene's: to its replica
        # A batch the watcher sees running only after it has ended (a quiet machine renders 150 frames
        # in a few seconds) tests no kill: it is sent again, twice as long.
        for n in (150, 300, 600):
            body = np.stack([np.asarray(mesh.positions, np.float32) + np.float32(0.002 * k)
                             for k in range(n)]).astype("<f4")
            deadline = time.monotonic() + 120
            while len(names := _replicas(cluster["env"])) != 2:   # an earlier test's victim is back
                assert time.monotonic() < deadline, names
                time.sleep(1.0)
            killers = {name: _Killer(cluster["env"], name) for name in names}   # each ready before the batch
            answer: dict = {}

            def batch(body=body, answer=answer):
                answer["r"] = http.post(f"/scenes/{s['id']}/frames/batch", content=body.tobytes(),
                                        headers={"Content-Type": "application/octet-stream", **route})

            thread = threading.Thread(target=batch)
            thread.start()
            victim = None
            try:
                while thread.is_alive():   # a replica's render thread says it runs the batch
                    ready = http.get("/health/ready", headers=route)
                    job = ready.json().get("current_job")
                    if job and f"batch of {n} frames" in job["what"]:
                        victim = ready.headers["x-replica"]
                        break
                    assert time.monotonic() < deadline, answer
                    time.sleep(0.05)
                if victim is not None:
                    next(k for name, k in killers.items() if name.endswith(victim)).kill()
            finally:
                for k in killers.values():
                    k.close()
            thread.join(timeout=240)
            if victim is not None:
                break
        assert victim is not None, "no batch was seen running"
        r = answer["r"]
        assert r.status_code == 200, r.text[:2000]
        assert r.headers["x-replica"] != victim and int(r.headers["x-replicas-lost"]) >= 1, (victim, r.headers)
        assert [f["frame_index"] for f in r.json()["frames"]] == list(range(n))
        after = http.post(f"/scenes/{s['id']}/frames", content=body[0].tobytes(),
                          headers={"Content-Type": "application/octet-stream", **route})
        assert after.status_code == 200 and after.headers["content-type"] == "image/png"


def _series(text: str, name: str) -> dict[str, float]:
    """{replica: value} of a metric's unlabelled-but-for-replica samples, summed over other labels."""
    from prometheus_client.parser import text_string_to_metric_families

    out: dict[str, float] = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == name:
                out[s.labels.get("replica", "")] = out.get(s.labels.get("replica", ""), 0.0) + s.value
    return out


@pytest.mark.system
def test_one_scrape_holds_every_replicas_metrics(cluster, tmp_path):
    """/metrics on any replica: each live replica's series, labelled by it; the frames counted there are
    the frames each replica answered."""
    mesh = garment(16)
    with httpx.Client(base_url=cluster["url"], timeout=120) as http:
        env, _, _ = upload_environment(http, tmp_path, known=True)

        def scrape(reporting: int) -> str:
            deadline = time.monotonic() + 60   # a replica reports every second; a gone one drops in five
            while True:
                text = http.get("/metrics").text
                if _series(text, "garment_render_replicas_reporting").get("") == reporting:
                    return text
                assert time.monotonic() < deadline, text[-2000:]
                time.sleep(0.5)

        # Every replica has reported since its last frame (an earlier test's frame counted in its next report).
        time.sleep(2.5)
        before = _series(scrape(2), "garment_render_frames_total")
        answered: dict[str, int] = {}
        with RenderClient(cluster["url"], max_retries=200, max_retry_wait_s=1.0) as c:
            for _ in range(4):
                s = c.create_scene(env["id"], positions=mesh.positions, faces=mesh.faces,
                                   **{k: v for k, v in scene_body(env["id"], mesh).items()
                                      if k in ("quality", "output")})
                for k in range(2):
                    name = c.send_frame(s["id"], mesh.positions, frame_index=k).headers["x-replica"]
                    answered[name] = answered.get(name, 0) + 1
        time.sleep(2.5)   # every replica has reported since
        text = scrape(2)
    after = _series(text, "garment_render_frames_total")
    ready = _series(text, "garment_render_gl_ready")   # every replica's own gauges, side by side
    assert len(ready) == 2 and set(ready.values()) == {1.0} and set(answered) <= set(ready), (ready, answered)
    # A replica that has answered no frame yet has no such series.
    for name in set(after) | set(answered):
        assert after.get(name, 0.0) - before.get(name, 0.0) == answered.get(name, 0), (name, before, after, answered)
    assert sum(answered.values()) == 8


def test_merged_metrics_label_each_replicas_samples_and_write_each_family_once():
    from prometheus_client import CollectorRegistry, Counter, generate_latest

    from service.ray_serve import merge_metrics

    texts = {}
    for name, n in (("a", 2), ("b", 3)):
        r = CollectorRegistry()
        Counter("garment_render_frames", "Frames", ["endpoint"], registry=r).labels("frames").inc(n)
        texts[name] = generate_latest(r)
    text = merge_metrics(texts).decode()
    assert text.count("# TYPE garment_render_frames_total counter") == 1
    assert _series(text, "garment_render_frames_total") == {"a": 2.0, "b": 3.0}
    assert _series(text, "garment_render_replicas_reporting") == {"": 2.0}


def test_the_start_up_lines_ray_address_is_read_back_as_written():
    """serve --ray writes its Ray instance's address into its start-up line and service.load reads it
    back from the log (service/logs.py holds both sides): an IPv4 and an IPv6 address, followed by more text."""
    from service.logs import RAY_ADDRESS_IN_LOG, ray_address_note

    for address in ("127.0.0.1:61234", "[::1]:6379"):
        line = f"garment-render: 2 Ray Serve replicas on http://127.0.0.1:8000 {ray_address_note(address)}\nmore"
        assert RAY_ADDRESS_IN_LOG.search(line).group(1) == address
    assert RAY_ADDRESS_IN_LOG.search("garment-render: 2 Ray Serve replicas on http://127.0.0.1:8000") is None


def test_the_cli_refuses_workers_with_ray():
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "serve", "--ray", "--workers", "2"], capture_output=True,
                       text=True, timeout=60, cwd=ROOT)
    assert r.returncode != 0 and "--replicas" in r.stderr


@pytest.mark.system
def test_the_load_script_reports_throughput_and_latency_per_replica(cluster):
    from service.load import markdown, run_load

    row = run_load(cluster["url"], scenes=2, frames=3, clients=2, size=32, resolution=8)
    assert row["frames"] == 6 and row["throughput_fps"] > 0 and row["p99_ms"] >= row["p50_ms"] > 0
    assert sum(row["replicas"].values()) == 6 and all(name != "-" for name in row["replicas"])
    text = markdown([{**row, "replica_count": 2}], "test machine", "python -m service.load --ray 2", "2026-01-02")
    assert "`python -m service.load --ray 2`" in text and "| 2 | 6 |" in text and "(2026-01-02)" in text


def test_the_load_table_says_when_the_ring_left_a_replica_without_scenes():
    from service.load import markdown

    row = {"frames": 8, "wall_s": 1.0, "throughput_fps": 8.0, "p50_ms": 100.0, "p99_ms": 150.0, "retries": 0,
           "scenes": 4, "clients": 4, "size": 32}
    rows = [{**row, "replicas": {"a": 8}, "replica_count": 1}, {**row, "replicas": {"b": 8}, "replica_count": 2}]
    text = markdown(rows, "test machine", "python -m service.load --ray 1,2", "2026-01-02")
    assert "With 2 replicas the ring placed all 4 scenes' ids on 1 of them" in text
    rows[1]["replicas"] = {"b": 5, "c": 3}
    assert "the ring placed all" not in markdown(rows, "test machine", "python -m service.load --ray 1,2", "2026-01-02")


def test_the_cluster_config_builds_the_deployment_it_names():
    import importlib

    import yaml
    from ray import serve

    config = yaml.safe_load((ROOT / "deploy" / "serve.yaml").read_text())
    (app,) = config["applications"]
    module, name = app["import_path"].split(":")
    built = getattr(importlib.import_module(module), name)(app["args"])
    assert isinstance(built, serve.Application)
    assert built._bound_deployment.name == "garment-render-ingress"   # Serve's proxy calls the ingress,
    (replicas,) = built._bound_deployment._replica_config.init_args   # which holds the render replicas' handle
    deployment = replicas._bound_deployment
    assert deployment.name == "garment-render"
    assert deployment.num_replicas == app["args"]["replicas"]
    assert deployment.ray_actor_options["num_gpus"] == app["args"]["gpus_per_replica"] == 1
    assert set(app["args"]["settings"]) == {"state_dir", "pem_cache_dir"}


def test_a_cluster_without_a_shared_state_dir_is_refused_before_ray_starts(monkeypatch):
    from service import ray_serve

    monkeypatch.delenv("GARMENT_RENDER_STATE_DIR", raising=False)
    monkeypatch.setattr(ray_serve.ray, "init", lambda *a, **k: pytest.fail("Ray was started"))
    with pytest.raises(ValueError, match="on a cluster needs GARMENT_RENDER_STATE_DIR"):
        ray_serve.run("127.0.0.1", 0, 2, address="ray://head.example:10001")
    monkeypatch.setenv("RAY_ADDRESS", "ray://head.example:10001")
    with pytest.raises(ValueError, match="on a cluster needs GARMENT_RENDER_STATE_DIR"):
        ray_serve.run("127.0.0.1", 0, 2)


# The most a request that Serve's proxy routed to a killed ingress replica waits before the proxy notices
# the death and sends it to the other: Ray's own detection, far below an ingress's restart (~7 s).
RAY_DETECTION_S = 5.0


@pytest.mark.system
def test_an_ingress_replica_killed_costs_no_outage(cluster, tmp_path):
    """One of the two ingress replicas killed while a simulator sends frames: every frame is answered
    200 (the client sends again the one Serve's proxy answered with its own 500, if any), and none sent
    after the kill waits for Serve to bring the ingress back (~7 s with one ingress replica); plain
    requests right after the kill are answered within RAY_DETECTION_S, the most a request the proxy
    routed to the dead replica waits for it to notice the death (seen: up to 2.9 s on a loaded 2-core
    machine). The frame in flight on the killed replica waits for the same, so it is held to a looser
    bound. Last in the module: it uploads the map that the tests before it upload first."""
    mesh = garment(16)
    names = []
    deadline = time.monotonic() + 120
    while len(names) != 2:   # both ingress replicas up (an earlier test's kill may be coming back)
        code = ("import ray; ray.init(address='auto', logging_level='ERROR'); "
                "print(*[a['name'] for a in ray.util.list_named_actors(True) "
                "if a['name'].startswith('SERVE_REPLICA::garment-render#garment-render-ingress#')])")
        r = subprocess.run([sys.executable, "-c", code], env=cluster["env"], capture_output=True, text=True,
                           timeout=120)
        names = r.stdout.split()
        assert time.monotonic() < deadline, (names, r.stderr[-1000:])
    with httpx.Client(base_url=cluster["url"], timeout=120) as http:
        env, _, _ = upload_environment(http, tmp_path, known=True)
    killer = _Killer(cluster["env"], names[0])
    spans, failures, statuses, stop = [], [], [], threading.Event()
    with RenderClient(cluster["url"], max_retries=50, max_retry_wait_s=0.5) as c:
        s = c.create_scene(env["id"], positions=mesh.positions, faces=mesh.faces,
                           **{k: v for k, v in scene_body(env["id"], mesh).items() if k in ("quality", "output")})
        c.send_frame(s["id"], mesh.positions)

        def simulator():
            k = 0
            while not stop.is_set():
                t0 = time.perf_counter()
                try:
                    c.send_frame(s["id"], np.asarray(mesh.positions) + np.float32(0.001 * (k % 50)))
                except Exception as exc:   # noqa: BLE001 - the test reports it
                    failures.append(repr(exc))
                    return
                spans.append((t0, time.perf_counter()))
                k += 1

        thread = threading.Thread(target=simulator)
        thread.start()
        try:
            time.sleep(1.0)
            killed_at = time.perf_counter()
            killer.kill()
            t0 = time.perf_counter()
            with httpx.Client(base_url=cluster["url"], timeout=60) as http:
                statuses = [http.get("/health/live").status_code for _ in range(5)]
            first_s = time.perf_counter() - t0
            time.sleep(3.0)
        finally:
            stop.set()
            killer.close()
            thread.join(timeout=120)
    assert failures == [] and statuses == [200] * 5 and first_s < RAY_DETECTION_S, (failures, statuses, first_s)
    in_flight = [b - a for a, b in spans if a <= killed_at < b]
    after = [b - a for a, b in spans if a > killed_at]
    report = [(round(a - killed_at, 2), round(b - a, 2)) for a, b in spans]
    assert len(after) > 5 and max(after) < RAY_DETECTION_S, f"a frame sent after the kill waited: {report}"
    assert all(w < 15.0 for w in in_flight), f"the frame in flight at the kill waited: {report}"
