"""The packages as a user installs them: the server's wheel built from the checkout, installed into a
fresh virtual environment, renders a frame from outside the checkout (its shaders and data are in the
wheel); the client's own wheel (client/), installed with numpy, httpx and Pillow alone (no GL, no
server), sends frames to a real service."""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
import venv
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
CLIENT = ROOT / "client"
SHADER_SUFFIXES = {".glsl", ".vert", ".frag", ".comp"}
# What a simulator's machine must not get with the client: GL, the server's libraries, our other packages.
NOT_THE_CLIENT_S = ("moderngl", "fastapi", "uvicorn", "trimesh", "OpenEXR", "scipy", "pxr", "renderer", "service",
                    "simulation")


def _packages() -> list[str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]


def _client_project() -> dict:
    return tomllib.loads((CLIENT / "pyproject.toml").read_text())


def _folders(root: Path, top: str) -> set[str]:
    """The dotted names of the folders under root/top that hold Python modules."""
    return {p.parent.relative_to(root).as_posix().replace("/", ".") for p in (root / top).rglob("*.py")}


def test_the_package_list_names_every_folder_of_code_and_shaders():
    on_disk = {name for top in ("renderer", "service", "simulation") for name in _folders(ROOT, top)}
    on_disk |= {p.parent.relative_to(ROOT).as_posix().replace("/", ".") for p in (ROOT / "renderer").rglob("*.npz")}
    on_disk |= {"renderer." + p.relative_to(ROOT).as_posix().replace("/", ".")
                for p in [ROOT / "shaders", *(d for d in (ROOT / "shaders").rglob("*") if d.is_dir())]}
    client = _folders(CLIENT, "garment_render_client")   # the client's own distribution, carried by the server's
    assert client == {"garment_render_client"}
    assert sorted(_packages()) == sorted(on_disk | client)
    assert sorted(_client_project()["tool"]["setuptools"]["packages"]) == sorted(client)


def test_the_lab_is_its_own_distribution_that_the_product_never_imports():
    """The benchmarks and figures (lab/garment_lab) ship in garment-render-lab, not in the product's
    wheel; they reach the command line through the core's entry-point group, and no module of the
    product, the service or the simulation imports them."""
    lab = tomllib.loads((ROOT / "lab" / "pyproject.toml").read_text())
    assert lab["tool"]["setuptools"]["packages"] == sorted(_folders(ROOT / "lab", "garment_lab")) == ["garment_lab"]
    assert lab["project"]["entry-points"]["garment_render.commands"] == {"lab": "garment_lab.cli:add_commands"}
    assert "garment-render" in _requirement_names(lab["project"]["dependencies"])
    assert not any(name.startswith("garment_lab") or ".bench" in name for name in _packages())
    product = [p for top in ("renderer", "service", "simulation") for p in (ROOT / top).rglob("*.py")]
    assert len(product) > 50
    imports_lab = re.compile(r"^\s*(from|import)\s+garment_lab\b|import_module\([^)]*garment_lab", re.M)
    assert [p for p in product if imports_lab.search(p.read_text())] == []


def test_the_client_is_released_with_the_server_and_needs_numpy_and_httpx_alone():
    client, server = _client_project()["project"], _project()
    assert (client["version"], client["requires-python"]) == (server["version"], server["requires-python"])
    assert sorted(_requirement_names(client["dependencies"])) == ["httpx", "numpy"]
    # The same lower bounds as the server's, which carries the same code.
    assert set(client["dependencies"]) <= set(server["dependencies"])


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    # Built from a copy of the sources: setuptools' build/ folder would otherwise stay in the checkout,
    # and files it kept from an earlier build could reach the wheel.
    src = tmp_path_factory.mktemp("src") / "garment-render"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "dist", "out", "docs", "tests",
                                                             "__pycache__", "*.egg-info", ".pytest_cache", ".hypothesis"))
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(src)], check=True, cwd=out, timeout=300)
    (whl,) = out.glob("garment_render-*.whl")
    return whl


def test_the_wheel_carries_every_shader_and_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    shaders = {"renderer/shaders/" + p.relative_to(ROOT / "shaders").as_posix()
               for p in (ROOT / "shaders").rglob("*") if p.suffix in SHADER_SUFFIXES}
    assert shaders and shaders <= names, sorted(shaders - names)
    assert {"renderer/presets/measured.json", "service/viewer.html"} <= names
    presets = {p.relative_to(ROOT).as_posix() for p in (ROOT / "renderer" / "presets").glob("*.toml")}
    assert len(presets) == 4 and presets <= names
    assert "renderer/data/default_scene.npz" in names   # the bundled default scene
    u3m = {f"renderer/u3m/schema/{n}" for n in ("u3m_schema.json", "u3m_schema_version1.json", "LICENSE")}
    assert u3m <= names, sorted(u3m - names)   # the U3M spec's schemas, with their licence (BSD-3)
    modules = {p.relative_to(ROOT).as_posix() for top in ("renderer", "service", "simulation")
               for p in (ROOT / top).rglob("*.py")}
    modules |= {p.relative_to(CLIENT).as_posix() for p in (CLIENT / "garment_render_client").rglob("*.py")}
    assert "garment_render_client/__init__.py" in modules   # the server's install includes the client
    assert modules <= names, sorted(modules - names)


def _distributions(names: list[str]) -> list[importlib.metadata.Distribution]:
    """The installed distributions `names` need, with what they require (markers of extras skipped; a
    requirement that its marker leaves out of this Python is not installed here, and skipped)."""
    seen: dict[str, importlib.metadata.Distribution] = {}
    todo = list(names)
    while todo:
        name = todo.pop()
        key = re.sub(r"[-_.]+", "-", name).lower()
        if key in seen:
            continue
        try:
            seen[key] = dist = importlib.metadata.distribution(name)
        except importlib.metadata.PackageNotFoundError:
            continue
        todo += [re.match(r"[A-Za-z0-9_.-]+", r).group(0) for r in dist.requires or [] if "extra ==" not in r]
    return list(seen.values())


def _requirement_names(requirements: list[str]) -> list[str]:
    return [re.match(r"[A-Za-z0-9_.-]+", r).group(0) for r in requirements]


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _fresh_env(folder: Path, requirements: list[str]) -> tuple[Path, dict]:
    """A new virtual environment in `folder` that holds the installed distributions `requirements`
    need (linked from this environment: no network), nothing else; returns its python and an
    environment for its processes."""
    env_dir = folder / "env"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                  check=True, capture_output=True, text=True).stdout.strip())
    deps = folder / "deps"
    deps.mkdir()
    for dist in _distributions(_requirement_names(requirements)):
        for top in {f.parts[0] for f in dist.files or [] if f.parts[0] not in ("..", "__pycache__")}:
            source = Path(dist.locate_file(top))
            if source.exists() and not (deps / top).exists():
                (deps / top).symlink_to(source)
    # Searched after the fresh site-packages; the checkout's own .pth files (its editable install) are
    # not among them.
    (purelib / "deps.pth").write_text(str(deps) + "\n")
    return python, {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}


def _install(python: Path, wheel: Path | str, resolve: bool = False) -> float:
    """pip installs `wheel` (a path, or a path with extras: "x.whl[pil]") into the environment of
    `python`, without an index; returns the seconds it took. With `resolve`, pip checks the wheel's
    requirements against what the environment holds, so one that _fresh_env did not link fails."""
    t0 = time.monotonic()
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-index", "--disable-pip-version-check",
                    *([] if resolve else ["--no-deps"]), str(wheel)], check=True, timeout=300)
    return time.monotonic() - t0


def _absent(python: Path, env: dict, cwd: Path, modules: tuple[str, ...]) -> list[str]:
    """Which of `modules` the environment of `python` can import."""
    out = subprocess.run([str(python), "-c", f"import importlib.util as u; print([m for m in {modules!r} "
                          "if u.find_spec(m)])"], check=True, capture_output=True, text=True, cwd=cwd, env=env)
    return json.loads(out.stdout.replace("'", '"'))


@pytest.mark.gpu
@pytest.mark.system
def test_the_wheel_without_extras_renders_and_serves_outside_the_checkout(wheel, tmp_path):
    """A fresh environment with the wheel and its dependencies alone (no extra: no plotting, no FLIP,
    no Ray): a frame renders from outside the checkout, and the service starts and answers."""
    python, env = _fresh_env(tmp_path, _project()["dependencies"])
    _install(python, wheel)
    work = tmp_path / "elsewhere"
    work.mkdir()
    assert _absent(python, env, work, ("matplotlib", "flip_evaluator", "ray", "pytest")) == []
    assert _absent(python, env, work, ("garment_render_client",)) == ["garment_render_client"]   # the client too
    where = subprocess.run([str(python), "-c", "import renderer, renderer.gpu.shaders as s; print(renderer.__file__); "
                            "print(s.SHADER_DIR)"], check=True, capture_output=True, text=True, cwd=work,
                           env=env).stdout.split()
    assert all(Path(p).is_relative_to(tmp_path / "env") for p in where), where
    cli = tmp_path / "env" / "bin" / "garment-render"
    done = subprocess.run([str(cli), "render", "--size", "48x48", "--out", "frame.png", "--timings", "timings.json"],
                          capture_output=True, text=True, cwd=work, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    image = np.asarray(Image.open(work / "frame.png"))
    assert image.shape[:2] == (48, 48) and image.std() > 1.0   # a shaded frame, not a blank one
    assert json.loads((work / "timings.json").read_text())["timings"]["frame_wall_ms"] > 0
    # The lab is not in it: its commands say how to install it.
    assert _absent(python, env, work, ("garment_lab",)) == []
    lab = subprocess.run([str(cli), "bench", "--broad"], capture_output=True, text=True, cwd=work, env=env, timeout=120)
    assert lab.returncode == 2 and "pip install ./lab" in lab.stderr, lab.stderr[-2000:]

    import httpx
    from service_server import free_port

    port = free_port()
    server = subprocess.Popen([str(cli), "serve", "--port", str(port), "--log-level", "warning"], cwd=work,
                              env={**env, "GARMENT_RENDER_CACHE_DIR": str(tmp_path / "cache")},
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/health/ready", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert server.poll() is None and time.monotonic() < deadline, server.stderr.read()[-2000:]
            time.sleep(0.3)
    finally:
        server.terminate()
        server.wait(timeout=30)


@pytest.fixture(scope="module")
def client_wheel(tmp_path_factory) -> Path:
    """The client's own wheel, built from a copy of client/ (as `wheel` is)."""
    src = tmp_path_factory.mktemp("client-src") / "client"
    shutil.copytree(CLIENT, src, ignore=shutil.ignore_patterns("build", "dist", "__pycache__", "*.egg-info"))
    out = tmp_path_factory.mktemp("client-wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(src)], check=True, cwd=out, timeout=300)
    (whl,) = out.glob("garment_render_client-*.whl")
    return whl


@pytest.mark.system
def test_the_client_installs_alone_in_seconds_and_sends_frames_to_a_real_service(client_wheel, tmp_path):
    """A simulator's machine: a fresh environment that gets the client's wheel with its `pil` extra, pip
    resolving its requirements against numpy, httpx and Pillow alone (no index), so that a requirement
    of anything else fails the install; GL, the server's libraries and our other packages cannot be
    imported there, the wheel puts one top-level package into site-packages, and the README's client
    example runs in it, as written, against a real service."""
    tops = {name.split("/")[0] for name in zipfile.ZipFile(client_wheel).namelist()}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"garment_render_client"}, tops

    python, env = _fresh_env(tmp_path / "client", ["numpy", "httpx", "pillow"])
    install_s = _install(python, f"{client_wheel}[pil]", resolve=True)
    assert install_s < 30, f"pip took {install_s:.0f} s to install the client"
    assert _absent(python, env, tmp_path, NOT_THE_CLIENT_S) == []
    installed = subprocess.run([str(python), "-c", "import importlib.metadata as m; print(sorted({f.parts[0] for f in "
                                "m.distribution('garment-render-client').files}))"], check=True, capture_output=True,
                               text=True, cwd=tmp_path, env=env).stdout
    assert [t for t in json.loads(installed.replace("'", '"')) if not t.endswith(".dist-info")] == \
        ["garment_render_client"]

    from service_server import ServiceProcess
    from test_readme import _block, write_example_files

    code = _block("RenderClient")
    assert code == re.findall(r"```python\n(.*?)```", (CLIENT / "README.md").read_text(), re.S)[0]   # one example
    work = tmp_path / "simulator"
    work.mkdir()
    write_example_files(work)
    server = ServiceProcess(tmp_path)
    try:
        done = subprocess.run([str(python), "-c", code.replace("http://127.0.0.1:8000", server.url)],
                              capture_output=True, text=True, cwd=work, env=env, timeout=300)
    finally:
        server.stop()
    assert done.returncode == 0, done.stderr[-2000:]
    frames = sorted(work.glob("frame_*.png"))
    assert [f.name for f in frames] == ["frame_0000.png", "frame_0001.png"]
    assert np.asarray(Image.open(frames[0])).std() > 1.0
