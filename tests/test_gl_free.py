"""What plans and judges a frame loads no GL (issue 63): the service validates a request, sizes a PEM
set and a frame's memory from renderer.settings, renderer.lighting.pem_plan and renderer.costs without
importing moderngl; only a process that renders does."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GL_FREE = ("renderer", "renderer.settings", "renderer.lighting.pem_plan", "renderer.costs", "renderer.presets",
           "service.schemas", "service.specs", "service.registry")


@pytest.mark.parametrize("module", GL_FREE)
def test_the_planning_side_imports_no_gl(module):
    code = f"import sys, {module}; print('moderngl' in sys.modules, 'renderer.renderer' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "False"], f"{module} pulls GL in: {out.stdout}"


def test_the_public_api_resolves_every_name_it_lists_and_gl_only_with_the_renderer():
    """`import renderer` names the API (renderer/__init__.py); each name is found on first use, and the
    planning names (quality, materials, maps, meshes) still load no GL."""
    code = ("import sys, renderer as gr; q = gr.quality('fast'); m = gr.Material((0.5, 0.5, 0.5)); "
            "f = q.frame(64, 64); p = q.pems(materials=[m]); c = gr.Camera((0, 0, 3), (0, 0, 0)); "
            "print('moderngl' in sys.modules, q.face_size, type(f).__name__, type(p).__name__); "
            "[getattr(gr, n) for n in gr.__all__]; print('moderngl' in sys.modules, sorted(gr.__all__) == gr.__all__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "64", "FrameSettings", "PEMSettings", "True", "True"], out.stdout


def test_the_check_can_fail():
    """The same probe on the module that renders says so."""
    code = "import sys, renderer.renderer; print('moderngl' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["True"]


def test_the_product_draws_no_figures():
    """Figures are the lab's (lab/garment_lab): rendering and the area lights load no matplotlib."""
    code = ("import sys, renderer.renderer, renderer.lighting.area_lights, renderer.cli, service.app; "
            "print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False"]
