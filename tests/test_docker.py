"""The container images without a Docker engine (none runs on the test machines).

What a build would use is checked statically: every COPY source exists and is inside the build context
(.dockerignore), the entrypoint is copied, executable and run by a non-root user, the health check asks a
real route, the PEM cache volume is mounted where the service's PEM_CACHE_DIR points, the NVIDIA image asks
for the `graphics` driver capability and ships a valid EGL vendor file naming libEGL_nvidia.so.0.

What a container would run is run directly: docker/install.sh in --check mode against this machine and in
--dry-run mode for both flavors; docker/entrypoint.sh with the repository's venv on PATH, serving on a free
port on 127.0.0.1 with the images' settings (temporary cache and state directories in place of the
volumes), rendering a frame, stopping cleanly on SIGTERM and coming back on the same "volumes"; the
one-shot `render` command; the health check script against a live and a dead port.
"""

from __future__ import annotations

import fnmatch
import io
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from service_server import environment_bytes, free_port, garment, scene_body

yaml = pytest.importorskip("yaml", reason="PyYAML parses docker/compose.yaml (pip install -e '.[test]')")

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
DOCKERFILES = {"cpu": DOCKER / "Dockerfile.cpu", "nvidia": DOCKER / "Dockerfile.nvidia"}
VENV_BIN = Path(sys.executable).parent
OCTET = {"Content-Type": "application/octet-stream"}


# -- reading Dockerfiles, .dockerignore and the compose file ------------------------------------------

def dockerfile_instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) in order; comments dropped, backslash continuations joined."""
    out, pending = [], ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line = pending + line
        pending = ""
        word, _, rest = line.partition(" ")
        out.append((word.upper(), rest.strip()))
    assert not pending, f"{path.name} ends inside a continued line"
    return out


def exec_form(args: str) -> list[str]:
    """ENTRYPOINT/CMD/COPY arguments in JSON (exec) form or shell words."""
    return json.loads(args) if args.startswith("[") else shlex.split(args)


def dockerfile_env(path: Path) -> dict[str, str]:
    env = {}
    for inst, args in dockerfile_instructions(path):
        if inst == "ENV":
            for word in shlex.split(args):
                key, _, value = word.partition("=")
                env[key] = value
    return env


def copies(path: Path) -> list[tuple[list[str], str]]:
    """(sources relative to the build context, destination) of every COPY/ADD without --from."""
    out = []
    for inst, args in dockerfile_instructions(path):
        if inst in ("COPY", "ADD"):
            words = exec_form(args)
            flags = [w for w in words if w.startswith("--")]
            if any(f.startswith("--from") for f in flags):
                continue
            words = [w for w in words if not w.startswith("--")]
            out.append((words[:-1], words[-1]))
    return out


def image_path_to_source(path: Path, image_path: str) -> Path:
    """The repository file a path inside the image comes from, following WORKDIR and COPY."""
    workdir = "/"
    mapping = {}
    for inst, args in dockerfile_instructions(path):
        if inst == "WORKDIR":
            workdir = os.path.join(workdir, args)
        elif inst == "COPY":
            *sources, dest = [w for w in exec_form(args) if not w.startswith("--")]
            dest = os.path.normpath(os.path.join(workdir, dest))
            for src in sources:
                # "COPY a/b.sh dir/" puts the file into the directory; "COPY a/b.sh a/b.sh" names it.
                is_dir_dest = dest.endswith("/") or len(sources) > 1 or (ROOT / src).is_dir()
                target = os.path.join(dest, Path(src).name) if is_dir_dest and not (ROOT / src).is_dir() else dest
                mapping[os.path.normpath(target)] = ROOT / src
    image_path = os.path.normpath(image_path)
    if image_path in mapping:
        return mapping[image_path]
    for target, src in mapping.items():  # inside a copied directory
        if src.is_dir() and image_path.startswith(target + "/"):
            return src / os.path.relpath(image_path, target)
    raise AssertionError(f"{image_path} is not copied into the image by {path.name}")


def dockerignore_patterns() -> list[str]:
    lines = (ROOT / ".dockerignore").read_text().splitlines()
    return [ln.strip().lstrip("/") for ln in lines if ln.strip() and not ln.strip().startswith("#")]


def ignored(rel_path: str, patterns: list[str]) -> bool:
    """Docker's rule: a path is excluded when the last pattern matching it or one of its parents is not
    a `!` exception. Patterns use filepath.Match syntax plus `**` for any number of directories."""
    parts = Path(rel_path).parts
    candidates = ["/".join(parts[:i]) for i in range(1, len(parts) + 1)]
    excluded = False
    for pattern in patterns:
        negate = pattern.startswith("!")
        pat = pattern[1:] if negate else pattern
        variants = {pat, pat.replace("**/", "")} if pat.startswith("**/") else {pat}
        for cand in candidates:
            names = [cand] + (["/".join(cand.split("/")[i:]) for i in range(1, cand.count("/") + 1)]
                              if pat.startswith("**/") else [])
            if any(fnmatch.fnmatchcase(n, v) for n in names for v in variants):
                excluded = not negate
                break
    return excluded


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((DOCKER / "compose.yaml").read_text())


def compose_service(compose: dict, profile: str) -> tuple[str, dict]:
    found = [(name, svc) for name, svc in compose["services"].items() if profile in svc.get("profiles", [])]
    assert len(found) == 1, f"expected one service in profile {profile!r}, got {[n for n, _ in found]}"
    return found[0]


def healthcheck_path() -> str:
    sys.path.insert(0, str(DOCKER))
    try:
        import healthcheck
    finally:
        sys.path.remove(str(DOCKER))
    return healthcheck.READY_PATH


# -- the Dockerfiles --------------------------------------------------------------------------------

@pytest.mark.parametrize("flavor", sorted(DOCKERFILES))
def test_every_copy_source_exists_and_is_in_the_build_context(flavor):
    patterns = dockerignore_patterns()
    found = copies(DOCKERFILES[flavor])
    assert found, "the image copies nothing"
    for sources, _dest in found:
        for src in sources:
            assert (ROOT / src).exists(), f"{DOCKERFILES[flavor].name}: COPY source {src} does not exist"
            assert not ignored(src, patterns), f"{src} is copied but excluded by .dockerignore"
            if (ROOT / src).is_dir():  # nothing the package needs is filtered out from inside it
                for f in (ROOT / src).rglob("*"):
                    rel = f.relative_to(ROOT).as_posix()
                    if f.is_file() and not ignored(rel, patterns):
                        break
                else:
                    pytest.fail(f"every file of {src} is excluded by .dockerignore")
    # The editable install reads pyproject.toml, its readme and every package's folder (package-dir maps
    # renderer.shaders to shaders/ and the client to client/).
    copied = {s for sources, _ in found for s in sources}
    assert {"pyproject.toml", "README.md", "docker/install.sh", *_package_folders()} <= copied


def _package_folders() -> set[str]:
    """The top-level folder each of pyproject.toml's packages comes from."""
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapped = setup["package-dir"]
    return {mapped[p].split("/")[0] if p in mapped else p.split(".")[0] for p in setup["packages"]}


@pytest.mark.parametrize("flavor", sorted(DOCKERFILES))
def test_entrypoint_is_copied_executable_and_run_by_a_non_root_user(flavor):
    path = DOCKERFILES[flavor]
    inst = dockerfile_instructions(path)
    names = [i for i, _ in inst]
    assert names[0] == "FROM" and "slim" in inst[0][1], "both images start from the same slim Python base"
    entry = exec_form(dict(inst)["ENTRYPOINT"])
    assert len(entry) == 1, "the entrypoint script takes the command from CMD / docker run arguments"
    script = image_path_to_source(path, entry[0])
    assert script == DOCKER / "entrypoint.sh"
    assert script.is_file() and os.access(script, os.X_OK), f"{script} must be executable"
    mode = subprocess.run(["git", "ls-files", "-s", str(script.relative_to(ROOT))], cwd=ROOT,
                          capture_output=True, text=True).stdout.split()
    if mode:  # tracked: a fresh clone must keep the executable bit too
        assert mode[0] == "100755", f"git records {script.name} as {mode[0]}; run git update-index --chmod=+x"
    assert exec_form(dict(inst)["CMD"]) == ["serve"]
    # The user switch comes after the last RUN (installs need root) and names no root account.
    user_at = max(i for i, n in enumerate(names) if n == "USER")
    assert user_at > max(i for i, n in enumerate(names) if n == "RUN")
    assert inst[user_at][1] not in ("root", "0", "0:0")
    runs = " ".join(a for i, a in inst if i == "RUN")
    assert f"--flavor {flavor}" in runs and "install.sh" in runs
    assert all("install.sh" in a for i, a in inst if i == "RUN"), "every install step goes through install.sh"
    assert inst[user_at][1] == "render", "the USER is the account install.sh creates (its --user default)"


@pytest.mark.parametrize("flavor", sorted(DOCKERFILES))
def test_image_healthcheck_asks_a_real_route(flavor):
    path = DOCKERFILES[flavor]
    args = dict(dockerfile_instructions(path))["HEALTHCHECK"]
    cmd = exec_form(args[args.index("CMD") + 3:].strip())
    assert cmd[0] == "python" and image_path_to_source(path, cmd[1]) == DOCKER / "healthcheck.py"

    from service.app import create_app
    from service.settings import ServiceSettings

    app = create_app(ServiceSettings(_env_file=None))
    paths = app.openapi()["paths"]
    assert "get" in paths.get(healthcheck_path(), {}), f"no GET {healthcheck_path()} among {sorted(paths)}"


def test_nvidia_image_asks_for_graphics_and_ships_the_egl_vendor_file():
    env = dockerfile_env(DOCKERFILES["nvidia"])
    assert "graphics" in env["NVIDIA_DRIVER_CAPABILITIES"].split(",")
    vendor = DOCKER / "nvidia" / "10_nvidia.json"
    doc = json.loads(vendor.read_text())
    assert doc["ICD"]["library_path"] == "libEGL_nvidia.so.0"
    assert doc["file_format_version"] == "1.0.0"
    mesa = Path("/usr/share/glvnd/egl_vendor.d/50_mesa.json")
    if mesa.exists():  # the same schema as the vendor file glvnd already reads on this machine
        assert json.loads(mesa.read_text()).keys() == doc.keys()
    assert any("docker/nvidia/10_nvidia.json" in s for s, _ in copies(DOCKERFILES["nvidia"]))
    # The CPU image has no vendor file: Mesa's own 50_mesa.json comes with libegl-mesa0.
    assert not any("nvidia" in " ".join(s) for s, _ in copies(DOCKERFILES["cpu"]))


def test_both_images_serve_the_same_settings_on_the_same_paths():
    from service.settings import ServiceSettings

    cpu, nvidia = (dockerfile_env(p) for p in (DOCKERFILES["cpu"], DOCKERFILES["nvidia"]))
    service_keys = {f"GARMENT_RENDER_{name.upper()}" for name in ServiceSettings.model_fields}
    assert {k: v for k, v in cpu.items() if k in service_keys} == {k: v for k, v in nvidia.items() if k in service_keys}
    assert cpu["GARMENT_RENDER_HOST"] == "0.0.0.0", "inside a container the service listens on all interfaces"
    # Debian's libegl1 pulls in Mesa, so the NVIDIA image could fall back to llvmpipe: it forbids that.
    assert nvidia["GARMENT_RENDER_REQUIRE_GPU"] == "1" and "GARMENT_RENDER_REQUIRE_GPU" not in cpu


# -- .dockerignore ----------------------------------------------------------------------------------

def test_dockerignore_keeps_the_context_small():
    patterns = dockerignore_patterns()
    for heavy in (".venv", "out", ".git", "renderer/__pycache__", "tests", "garment_render.egg-info",
                  ".pytest_cache", ".hypothesis"):
        assert ignored(heavy, patterns), f"{heavy} should not be sent to the Docker daemon"
    assert ignored("renderer/gpu/__pycache__/context.cpython-311.pyc", patterns)
    total = 0
    for dirpath, dirnames, filenames in os.walk(ROOT):
        rel_dir = Path(dirpath).relative_to(ROOT)
        dirnames[:] = [d for d in dirnames if not ignored((rel_dir / d).as_posix(), patterns)]
        total += sum((Path(dirpath) / f).stat().st_size for f in filenames
                     if not ignored((rel_dir / f).as_posix(), patterns) and (Path(dirpath) / f).is_file())
    assert total < 20 << 20, f"the build context is {total / 2**20:.1f} MiB"


# -- the compose file -------------------------------------------------------------------------------

def test_compose_builds_the_two_images_from_existing_files(compose):
    for profile, flavor in (("cpu", "cpu"), ("gpu", "nvidia")):
        _, svc = compose_service(compose, profile)
        context = (DOCKER / svc["build"]["context"]).resolve()
        assert context == ROOT
        assert (context / svc["build"]["dockerfile"]).resolve() == DOCKERFILES[flavor]


def test_compose_health_checks_ask_the_readiness_route(compose):
    for profile in ("cpu", "gpu"):
        _, svc = compose_service(compose, profile)
        test = svc["healthcheck"]["test"]
        assert test[0] == "CMD" and test[1] == "python"
        assert image_path_to_source(DOCKERFILES["cpu"], test[2]) == DOCKER / "healthcheck.py"
        assert svc["environment"]["GARMENT_RENDER_PORT"] == svc["ports"][0].rsplit(":", 1)[1]
    assert healthcheck_path() == "/health/ready"


def test_compose_mounts_the_pem_cache_volume_where_the_service_writes_it(compose):
    from service.settings import ServiceSettings

    for profile, flavor in (("cpu", "cpu"), ("gpu", "nvidia")):
        _, svc = compose_service(compose, profile)
        mounts = dict(v.split(":")[:2][::-1] for v in svc["volumes"])  # container path -> volume
        env = {**dockerfile_env(DOCKERFILES[flavor]), **{k: v for k, v in svc["environment"].items() if v}}
        settings = ServiceSettings(_env_file=None, **{
            k.removeprefix("GARMENT_RENDER_").lower(): v for k, v in env.items()
            if k in ("GARMENT_RENDER_PEM_CACHE_DIR", "GARMENT_RENDER_STATE_DIR")})
        for setting in (settings.pem_cache_dir, settings.state_dir):
            volume = mounts.get(str(setting))
            assert volume is not None, f"{profile}: nothing is mounted at {setting}"
            assert volume in compose["volumes"], f"{volume} is not a named volume"
        assert mounts[str(settings.pem_cache_dir)] == "pem-cache"
        # A token left empty would demand an empty token: compose passes it only when the shell has one.
        assert svc["environment"].get("GARMENT_RENDER_TOKEN") is None


def test_compose_gpu_service_reserves_an_nvidia_gpu_with_graphics(compose):
    _, gpu = compose_service(compose, "gpu")
    devices = gpu["deploy"]["resources"]["reservations"]["devices"]
    assert [d["driver"] for d in devices] == ["nvidia"]
    assert {"gpu", "graphics"} <= set(devices[0]["capabilities"])
    assert "graphics" in gpu["environment"]["NVIDIA_DRIVER_CAPABILITIES"].split(",")
    _, cpu = compose_service(compose, "cpu")
    assert "deploy" not in cpu


# -- docker/install.sh ------------------------------------------------------------------------------

@pytest.mark.skipif(shutil.which("shellcheck") is None, reason="shellcheck is not installed (apt install shellcheck)")
def test_shell_scripts_pass_shellcheck():
    r = subprocess.run(["shellcheck", *(str(DOCKER / s) for s in ("install.sh", "entrypoint.sh", "build-local.sh",
                                                                  "run-local.sh"))],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stdout



def install(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(DOCKER / "install.sh"), "--python", sys.executable, *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, env={**os.environ, **(env or {})})


@pytest.mark.skipif(shutil.which("dpkg-query") is None, reason="install.sh checks Debian packages")
def test_install_check_passes_on_this_machine():
    r = install("--check", "--flavor", "cpu")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Debian packages present" in r.stdout and "Python dependencies satisfied" in r.stdout
    assert f"project imports from {ROOT / 'renderer'}" in r.stdout


@pytest.mark.skipif(Path("/usr/share/glvnd/egl_vendor.d/10_nvidia.json").exists(),
                    reason="this machine has the NVIDIA vendor file")
def test_install_check_names_what_is_missing():
    r = install("--check", "--flavor", "nvidia", "system")
    assert r.returncode == 1
    assert "/usr/share/glvnd/egl_vendor.d/10_nvidia.json" in r.stderr


@pytest.mark.parametrize("flavor", sorted(DOCKERFILES))
def test_install_dry_run_prints_the_image_steps(flavor):
    env = dockerfile_env(DOCKERFILES[flavor])
    r = install("--dry-run", "--flavor", flavor, env=env)
    assert r.returncode == 0, r.stderr
    lines = [shlex.split(ln[2:]) for ln in r.stdout.splitlines() if ln.startswith("+ ")]
    apt = next(ln for ln in lines if "apt-get" in ln and "install" in ln)
    packages = set(apt[apt.index("--no-install-recommends") + 1:])
    assert {"libegl1", "libgl1"} <= packages  # glvnd's libEGL.so.1 and libGL.so.1: moderngl loads both
    assert ({"libegl-mesa0", "libgl1-mesa-dri"} <= packages) == (flavor == "cpu")
    vendor_copy = [ln for ln in lines if ln[:1] == ["install"] and "/usr/share/glvnd/egl_vendor.d/10_nvidia.json" in ln]
    assert bool(vendor_copy) == (flavor == "nvidia")
    # The directories the volumes mount on are created for the non-root user.
    assert next(ln for ln in lines if ln[:1] == ["useradd"])[-1] == "render"
    mkdirs = next(ln for ln in lines if ln[:2] == ["install", "-d"])
    assert env["GARMENT_RENDER_PEM_CACHE_DIR"] in mkdirs and env["GARMENT_RENDER_STATE_DIR"] in mkdirs
    assert mkdirs[mkdirs.index("-o") + 1] == "render"
    # Every runtime dependency of pyproject.toml, then the project itself, editable.
    import tomllib

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    pip = [ln for ln in lines if ln[1:4] == ["-m", "pip", "install"]]
    assert len(pip) == 2
    assert set(deps) <= set(pip[0])
    assert pip[1][-2:] == ["-e", str(ROOT)]


# -- docker/entrypoint.sh, run directly -------------------------------------------------------------

def entrypoint_env(tmp: Path, port: int) -> dict[str, str]:
    """The CPU image's environment with this machine's venv on PATH and temporary 'volumes'."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("GARMENT_RENDER_")}
    env.update(dockerfile_env(DOCKERFILES["cpu"]))
    env.update(PATH=f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}", GARMENT_RENDER_HOST="127.0.0.1",
               GARMENT_RENDER_PORT=str(port), GARMENT_RENDER_PEM_CACHE_DIR=str(tmp / "pem"),
               GARMENT_RENDER_STATE_DIR=str(tmp / "state"))
    return env


class Container:
    """docker/entrypoint.sh with no arguments (the image's default command), as a process."""

    def __init__(self, tmp: Path, port: int, *args: str):
        self.url = f"http://127.0.0.1:{port}"
        self.port = port
        self.log_path = tmp / f"entrypoint-{port}-{time.monotonic_ns()}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen([str(DOCKER / "entrypoint.sh"), *args], cwd=ROOT, env=entrypoint_env(tmp, port),
                                     stdout=self._log, stderr=subprocess.STDOUT)

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def wait_ready(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, f"the entrypoint exited with {self.proc.returncode}:\n{self.log()}"
            try:
                if httpx.get(f"{self.url}/health/ready", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        raise AssertionError(f"not ready within {timeout} s:\n{self.log()}")

    def terminate(self, timeout: float = 30.0) -> int:
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        finally:
            self._log.close()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._log.close()


@pytest.fixture(scope="module")
def volumes(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("docker-volumes")


@pytest.fixture(scope="module")
def container(volumes):
    c = Container(volumes, free_port())
    try:
        c.wait_ready()
        yield c
    finally:
        c.kill()


@pytest.fixture(scope="module")
def rendered(container, volumes):
    """An environment, a scene and one frame through the served entrypoint."""
    with httpx.Client(base_url=container.url, timeout=120) as http:
        data, name = environment_bytes(volumes)
        env = http.post("/environments", content=data, headers=OCTET,
                        params={"name": name, "lights": 12, "face_size": 32, "preset": "fast"})
        assert env.status_code == 201, env.text
        mesh = garment(24)
        scene = http.post("/scenes", json=scene_body(env.json()["id"], mesh))
        assert scene.status_code == 201, scene.text
        frame = http.post(f"/scenes/{scene.json()['id']}/frames", headers=OCTET,
                          content=np.ascontiguousarray(mesh.positions, "<f4").tobytes())
        assert frame.status_code == 200, frame.text
        return {"scene_id": scene.json()["id"], "mesh": mesh, "png": frame.content}


def test_entrypoint_checks_gl_then_serves(container):
    ready = httpx.get(f"{container.url}/health/ready", timeout=5).json()
    log = container.log()
    assert "entrypoint: OpenGL 4.5" in log, log
    assert f"on {ready['gl']['renderer']}" in log, "the entrypoint prints the renderer the service then uses"
    assert f"serving on 127.0.0.1:{container.port}" in log


def test_healthcheck_script_follows_readiness(container):
    script = [sys.executable, str(DOCKER / "healthcheck.py")]
    live = subprocess.run(script, env={**os.environ, "GARMENT_RENDER_PORT": str(container.port)}, timeout=10)
    assert live.returncode == 0
    dead = subprocess.run(script, env={**os.environ, "GARMENT_RENDER_PORT": str(free_port())}, timeout=10,
                          capture_output=True, text=True)
    assert dead.returncode == 1 and "/health/ready" in dead.stderr


def test_entrypoint_serves_frames_into_the_volumes(rendered, volumes):
    image = np.asarray(Image.open(io.BytesIO(rendered["png"])), np.float32)
    assert image.shape[:2] == (64, 64) and np.isfinite(image).all() and image.std() > 1.0
    assert any(p.is_file() for p in (volumes / "pem").rglob("*")), "the PEM set was not written to the cache"
    assert any(p.is_file() for p in (volumes / "state").rglob("*")), "the scene was not written to the state"


def test_sigterm_stops_cleanly_and_a_restart_reuses_the_volumes(container, rendered, volumes):
    t0 = time.monotonic()
    code = container.terminate()
    log = container.log()
    # `docker stop` sends SIGTERM to the exec'ed service. uvicorn finishes the lifespan (the GL thread
    # stops), then exits 0 or, since 0.29, re-raises the signal: both are a clean stop.
    assert code in (0, -signal.SIGTERM), f"exit code {code} on SIGTERM:\n{log}"
    assert "Application shutdown complete" in log and "Finished server process" in log, log
    assert "Traceback" not in log and "ERROR" not in log, log
    assert time.monotonic() - t0 < 20

    again = Container(volumes, free_port(), "serve")
    try:
        again.wait_ready()
        with httpx.Client(base_url=again.url, timeout=120) as http:
            frame = http.post(f"/scenes/{rendered['scene_id']}/frames", headers=OCTET,
                              content=np.ascontiguousarray(rendered["mesh"].positions, "<f4").tobytes())
            assert frame.status_code == 200, frame.text
            cache = http.get("/stats").json()["pem_cache"]
        assert cache["disk_hits"] >= 1 and cache["builds"] == 0, cache
        assert again.terminate() in (0, -signal.SIGTERM)
    finally:
        again.kill()


def test_entrypoint_one_shot_render(tmp_path):
    out = tmp_path / "frame.png"
    r = subprocess.run([str(DOCKER / "entrypoint.sh"), "render", "--size", "48x32", "--preset", "fast",
                        "--lights", "6", "--face-size", "16", "--shadow-size", "64", "--out", str(out)],
                       cwd=ROOT, env=entrypoint_env(tmp_path, free_port()), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert Image.open(out).size == (48, 32)


def test_entrypoint_refuses_an_unwritable_cache_dir(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    env = {**entrypoint_env(tmp_path, free_port()), "GARMENT_RENDER_PEM_CACHE_DIR": str(blocker / "pem")}
    t0 = time.monotonic()
    r = subprocess.run([str(DOCKER / "entrypoint.sh")], cwd=ROOT, env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 1
    assert "GARMENT_RENDER_PEM_CACHE_DIR" in r.stderr and "writable" in r.stderr
    assert time.monotonic() - t0 < 5, "it fails before starting anything"


def test_entrypoint_runs_other_commands(tmp_path):
    r = subprocess.run([str(DOCKER / "entrypoint.sh"), "python", "-c", "import renderer; print('ok')"], cwd=ROOT,
                       env=entrypoint_env(tmp_path, free_port()), capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
    check = subprocess.run([str(DOCKER / "entrypoint.sh"), "check"], cwd=ROOT,
                           env=entrypoint_env(tmp_path, free_port()), capture_output=True, text=True, timeout=60)
    assert check.returncode == 0 and "entrypoint: OpenGL 4.5" in check.stderr, check.stderr


def test_entrypoint_requiring_a_gpu_refuses_a_software_renderer(tmp_path):
    env = {**entrypoint_env(tmp_path, free_port()), "GARMENT_RENDER_REQUIRE_GPU": "1"}
    r = subprocess.run([str(DOCKER / "entrypoint.sh")], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=60)
    software = any(s in r.stderr for s in ("llvmpipe", "softpipe", "swrast"))
    if not software:
        pytest.skip(f"this machine renders on a GPU: {r.stderr.strip()}")
    assert r.returncode == 1, "the NVIDIA image must not serve from llvmpipe"
    assert "--gpus all" in r.stderr and "GARMENT_RENDER_REQUIRE_GPU=0" in r.stderr
    assert "serving on" not in r.stderr
