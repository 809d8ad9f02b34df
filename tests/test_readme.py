"""The README's Python examples run as written: the client against a real service on 127.0.0.1, the
library API in this process, each with the files and the `simulation` it names."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from service_server import ServiceProcess

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)


def _block(marker: str) -> str:
    (block,) = [b for b in BLOCKS if marker in b]
    return block


def write_example_files(folder: Path) -> list[np.ndarray]:
    """The examples' files as the README makes them (`python -m simulation.examples`: the bundled
    studio, dress and mannequin, and two frames of the dress's simulation) in `folder`; returns the
    `simulation` the library example iterates: those frames in shirt.obj's own units and axes
    (centimetres, Y up), the same topology."""
    from simulation.examples import write_examples

    write_examples(folder, frames=2)
    with np.load(folder / "drape.npz") as z:   # metres, Z up: back to the mesh file's frame
        return [np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1) * np.float32(100.0) for p in z["positions"]]


@pytest.fixture
def files(tmp_path, monkeypatch):
    """The examples' files where they look for them (write_example_files)."""
    monkeypatch.chdir(tmp_path)
    return {"simulation": write_example_files(tmp_path)}


def test_the_readme_makes_the_files_its_examples_name(files, tmp_path):
    """The first command of the README's render example writes every file the page's examples read,
    and the render command runs on them as written."""
    import shlex
    import subprocess
    import sys

    (sh,) = [b for b in re.findall(r"```sh\n(.*?)```", (ROOT / "README.md").read_text(), re.S) if "simulation.examples" in b]
    lines = sh.replace("\\\n", " ").splitlines()
    assert "python -m simulation.examples" in lines[0]
    for name in ("studio.exr", "shirt.obj", "body.obj", "drape.npz"):
        assert (tmp_path / name).stat().st_size > 1000, name
    render = shlex.split(lines[1].split("#")[0])
    assert render[0].endswith("garment-render") and render[1] == "render"
    render[render.index("--size") + 1] = "96x96"   # as written, smaller
    done = subprocess.run([sys.executable, "-m", "renderer.cli", *render[1:]], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and "warning" not in done.stderr, done.stderr
    assert (tmp_path / "frame.png").stat().st_size > 1000 and (tmp_path / "frame.exr").exists()


def test_the_readme_client_example_drives_a_real_service(files, tmp_path):
    server = ServiceProcess(tmp_path)
    try:
        code = _block("RenderClient").replace("http://127.0.0.1:8000", server.url)
        exec(compile(code, "README.md (client)", "exec"), {})   # as written: it names its own files
    finally:
        server.stop()
    frames = sorted(tmp_path.glob("frame_*.png"))
    assert [f.name for f in frames] == ["frame_0000.png", "frame_0001.png"] and all(f.stat().st_size > 1000 for f in frames)


def test_the_readme_client_example_reads_the_shared_simulation_as_it_is():
    """The client example's data names are the shared cloth simulation's own."""
    from conftest import asset

    with np.load(asset("sim", "newton_shirt_drape_60f.npz")) as sim:
        assert sim["positions"].ndim == 3 and sim["positions"].shape[2] == 3 and sim["triangles"].shape[1] == 3
    code = _block("RenderClient")
    assert 'sim["positions"]' in code and 'sim["triangles"]' in code and 'up="z"' in code


def test_the_readme_library_example_renders_every_frame(files):
    names = dict(files, simulation=[p * np.float32(0.01) for p in files["simulation"]])   # metres, as loaded
    code = _block("Renderer()").replace("frame.image, frame.timings", "seen.append((frame.image, frame.timings))")
    names["seen"] = seen = []
    exec(compile(code, "README.md (library)", "exec"), names)
    assert len(seen) == 2
    for image, timings in seen:
        assert image.shape == (512, 512, 4) and np.isfinite(image).all() and image[..., 3].sum() > 1000
        assert timings["frame_wall_ms"] > 0


def test_the_readme_is_a_newcomers_page_whose_links_lead_somewhere():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    links = [link for link in re.findall(r"\]\(([^)#\s]+)\)", text) if "://" not in link]
    assert len(links) > 10
    assert [link for link in links if not (ROOT / link).exists()] == []


def test_the_readme_quality_table_is_the_one_the_stored_held_out_run_makes():
    """The README's measured numbers come from the stored run (garment_lab.broad.readme_table), made
    with today's preset files (tests/test_stored_runs.py): a number there cannot outlive its run."""
    import json

    from garment_lab import broad
    from renderer.presets import presets_digest

    text = (ROOT / "README.md").read_text()
    data = json.loads((ROOT / broad.README_RUN).read_text())
    assert broad.with_readme_table(text, data) == text
    assert data["presets_digest"] == presets_digest()
