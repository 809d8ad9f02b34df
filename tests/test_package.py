"""The package as a user installs it: a wheel built from the checkout, installed into a fresh virtual
environment, renders a frame from outside the checkout (its shaders and data are in the wheel); with
the `client` extra's dependencies alone (no GL, no server), the client sends frames to a real service."""

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
SHADER_SUFFIXES = {".glsl", ".vert", ".frag", ".comp"}


def _packages() -> list[str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]


def test_the_package_list_names_every_folder_of_code_and_shaders():
    on_disk = {p.parent.relative_to(ROOT).as_posix().replace("/", ".")
               for top in ("renderer", "service", "simulation") for p in (ROOT / top).rglob("*.py")}
    on_disk |= {p.parent.relative_to(ROOT).as_posix().replace("/", ".") for p in (ROOT / "renderer").rglob("*.npz")}
    on_disk |= {"renderer." + p.relative_to(ROOT).as_posix().replace("/", ".")
                for p in [ROOT / "shaders", *(d for d in (ROOT / "shaders").rglob("*") if d.is_dir())]}
    assert sorted(_packages()) == sorted(on_disk)


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
    modules = {p.relative_to(ROOT).as_posix() for top in ("renderer", "service", "simulation")
               for p in (ROOT / top).rglob("*.py")}
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


def _fresh_env(wheel: Path, folder: Path, requirements: list[str]) -> tuple[Path, dict]:
    """A new virtual environment in `folder` that holds the wheel and the installed distributions
    `requirements` need (linked from this environment: no network), nothing else; returns its
    python and an environment for its processes."""
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
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], check=True,
                   timeout=300)
    return python, {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}


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
    python, env = _fresh_env(wheel, tmp_path, _project()["dependencies"])
    work = tmp_path / "elsewhere"
    work.mkdir()
    assert _absent(python, env, work, ("matplotlib", "flip_evaluator", "ray", "httpx", "pytest")) == []
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


@pytest.mark.system
def test_the_client_extra_sends_frames_without_gl_or_the_server(wheel, tmp_path):
    """A simulator's machine: a fresh environment that holds the wheel and the client extra's
    dependencies (httpx, numpy, Pillow for `Frame.pil`) and nothing else, so that an import of GL,
    of the renderer or of the server's libraries fails there; the README's client example runs in it,
    as written, against a real service."""
    python, env = _fresh_env(wheel, tmp_path / "client", _project()["optional-dependencies"]["client"])
    assert _absent(python, env, tmp_path, ("moderngl", "fastapi", "trimesh", "OpenEXR")) == []

    from service_server import ServiceProcess
    from test_readme import _block, write_example_files

    work = tmp_path / "simulator"
    work.mkdir()
    write_example_files(work)
    server = ServiceProcess(tmp_path)
    try:
        code = _block("RenderClient").replace("http://127.0.0.1:8000", server.url)
        done = subprocess.run([str(python), "-c", code], capture_output=True, text=True, cwd=work, env=env,
                              timeout=300)
    finally:
        server.stop()
    assert done.returncode == 0, done.stderr[-2000:]
    frames = sorted(work.glob("frame_*.png"))
    assert [f.name for f in frames] == ["frame_0000.png", "frame_0001.png"]
    assert np.asarray(Image.open(frames[0])).std() > 1.0
