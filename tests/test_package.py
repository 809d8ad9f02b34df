"""The package as a user installs it: a wheel built from the checkout, installed into a fresh virtual
environment, renders a frame from outside the checkout (its shaders and data are in the wheel)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
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
    assert {"renderer/bench/measured.json", "service/viewer.html"} <= names
    presets = {p.relative_to(ROOT).as_posix() for p in (ROOT / "renderer" / "presets").glob("*.toml")}
    assert len(presets) == 4 and presets <= names
    assert "renderer/data/default_scene.npz" in names   # the bundled default scene
    modules = {p.relative_to(ROOT).as_posix() for top in ("renderer", "service", "simulation")
               for p in (ROOT / top).rglob("*.py")}
    assert modules <= names, sorted(modules - names)


@pytest.mark.gpu
def test_an_installed_wheel_renders_a_frame_outside_the_checkout(wheel, tmp_path):
    env_dir = tmp_path / "fresh"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    # The dependencies come from this environment (no network); the project only from the wheel: a
    # path named in a .pth file is searched after the fresh site-packages, and its own .pth files (the
    # checkout's editable install) are not read.
    Path(purelib, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], check=True,
                   timeout=300)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = subprocess.run([str(python), "-c", "import renderer, renderer.gpu.shaders as s; print(renderer.__file__); "
                            "print(s.SHADER_DIR)"], check=True, capture_output=True, text=True, cwd=work,
                           env=env).stdout.split()
    assert all(Path(p).is_relative_to(env_dir) for p in where), where
    done = subprocess.run([str(env_dir / "bin" / "garment-render"), "render", "--size", "48x48", "--out", "frame.png",
                           "--timings", "timings.json"], capture_output=True, text=True, cwd=work, env=env,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    image = np.asarray(Image.open(work / "frame.png"))
    assert image.shape[:2] == (48, 48) and image.std() > 1.0   # a shaded frame, not a blank one
    assert json.loads((work / "timings.json").read_text())["timings"]["frame_wall_ms"] > 0
