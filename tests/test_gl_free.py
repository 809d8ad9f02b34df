"""What plans and judges a frame loads no GL (issue 63): the service validates a request, sizes a PEM
set and a frame's memory from renderer.settings, renderer.lighting.pem_plan and renderer.costs without
importing moderngl; only a process that renders does."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GL_FREE = ("renderer", "renderer.settings", "renderer.lighting.pem_plan", "renderer.costs", "renderer.plan",
           "renderer.presets",
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


def test_a_frame_is_planned_on_the_cpu_and_kept_while_its_boxes_stay():
    """renderer/plan.py: a frame's lights and maps from a map's median cut and a scene's boxes with no GL
    loaded; the plan is kept while the snapped boxes stay and made anew when the garment leaves its cells."""
    code = """if True:
        import sys, types
        import numpy as np
        from renderer.lighting.median_cut import median_cut
        from renderer.plan import LightPlanner
        from renderer.settings import FrameSettings
        rng = np.random.default_rng(3)
        cube = rng.random((6, 16, 16, 3)).astype(np.float32)
        cube[2, 7:9, 7:9] = 4000.0                        # a sun: its region bright enough for a sharp map
        regions = median_cut(cube, 24, True)
        pems = types.SimpleNamespace(regions=regions, scale=np.ones(regions.n_regions))
        box = [np.array([-0.3, 0.0, -0.2]), np.array([0.3, 1.6, 0.2])]
        scene = types.SimpleNamespace(bounds=lambda casters_only=False: tuple(box), footprint_unit=1.0,
                                      max_glossiness=0.5)
        settings = FrameSettings(small_light_scale=4, small_light_min_energy=2.0, sharp_large_lights=True,
                                 contact_shadow_texels=8.0)
        planner = LightPlanner()
        a = planner.plan(scene, pems, settings, None)
        b = planner.plan(scene, pems, settings, None)
        box[0] = box[0] + 1e-4                             # within its cells: kept
        c = planner.plan(scene, pems, settings, None)
        box[1] = box[1] + 0.5                              # out of them: planned anew
        d = planner.plan(scene, pems, settings, None)
        print('moderngl' in sys.modules, planner.hits, a.n, a.n_shadowed, int(a.plan.sharp.sum()) > 0,
              sorted(a.order.tolist()) == list(range(a.n)), int(a.kind_end[-1]) == a.n, a.contact_radius > 0,
              a.lights.tobytes() == c.lights.tobytes(), a.lights.tobytes() != d.lights.tobytes())
    """
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "2", "24", "24", "True", "True", "True", "True", "True", "True"], out.stdout
