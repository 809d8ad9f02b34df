"""The GPU layer: struct mirrors, shader composition and error reporting."""

import numpy as np
import pytest

from renderer.errors import ShaderError
from renderer.gpu.contract import Mode, ProbeBuffer
from renderer.gpu.shaders import _rewrite_log, compose, compute_shader
from renderer.shadows.lights import (
    FOOTPRINT_STEPS_PER_OCTAVE,
    LIGHT_DTYPE,
    MIN_DEPTH_TEXELS,
    fit_light_view_projs,
    pack_lights,
    texel_sizes,
)


def test_light_struct_mirror_matches_glsl_std430(gl):
    rng = np.random.default_rng(0)
    n = 5
    vp = rng.random((n, 4, 4))
    arr = pack_lights(rng.random((n, 3)), rng.random(n), rng.random(n), rng.random((n, 3)), vp,
                      rng.random(n), np.arange(n) - 1, rng.random(n), rng.integers(1, 4, n), rng.random((n, 2)))
    assert LIGHT_DTYPE.itemsize == 128
    ctx = gl.ctx
    src = ctx.buffer(arr.tobytes())
    out = ctx.buffer(reserve=n * 8 * 16)
    src.bind_to_storage_buffer(ProbeBuffer.LIGHTS)
    out.bind_to_storage_buffer(ProbeBuffer.OUT)
    cs = compute_shader(ctx, "common/light_layout_probe.comp")
    cs.run(n)
    got = np.frombuffer(out.read(), np.float32).reshape(n, 8, 4)
    for obj in (cs, src, out):
        obj.release()
    # GLSL mat4 columns are the rows of the numpy (row-major) matrix transposed.
    np.testing.assert_allclose(got[:, :4, :], np.transpose(vp, (0, 2, 1)), rtol=1e-6)
    np.testing.assert_allclose(got[:, 4], arr["dir_scale"])
    np.testing.assert_allclose(got[:, 5], arr["params"])
    np.testing.assert_allclose(got[:, 6], arr["energy"])
    np.testing.assert_allclose(got[:, 7], arr["shadow"])


def test_light_projection_maps_the_casters_box_into_clip_space():
    lo, hi = np.array([-1.0, 0.0, -2.0]), np.array([3.0, 2.0, 1.0])
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    dirs = np.array([[0, 1, 0], [1, 1, 1], [0, -1, 0.001], [-0.3, 0.2, -1]], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ms = fit_light_view_projs(dirs, lo, hi, np.full(len(dirs), 2.0), 256)
    for d, m in zip(dirs, ms):
        c = corners @ m.T
        assert np.all(np.abs(c[:, :2]) <= 1.0) and np.all((c[:, 2] >= 0) & (c[:, 2] <= 1))
        # Tight and square: the box fills the map on its wider axis up to the blur's margin, the half
        # texel the centre's rounding needs and the footprint's size step, and x and y have the same scale.
        margin = (1.0 + 2.0 * (3.0 * 2.0 + 1.0) / 256) * (1.0 + 1.0 / 256)
        assert np.abs(c[:, :2]).max() * margin >= 2.0 ** (-1.0 / FOOTPRINT_STEPS_PER_OCTAVE)
        assert np.linalg.norm(m[0, :3]) == pytest.approx(np.linalg.norm(m[1, :3]))
        # Depth grows away from the light: the corner furthest along the light direction is nearest.
        dist = corners[:, :3] @ np.asarray(d, float)
        assert c[np.argmax(dist), 2] == pytest.approx(c[:, 2].min())


def test_texel_grid_stays_put_while_the_casters_box_changes_a_little():
    # The cloth moves the casters' box every frame; static geometry must see the same texel grid
    # (else its shadow edges shimmer): the footprint keeps its size within a size step and its
    # centre moves by whole texels.
    dirs = np.array([[0.9, 0.03, 0.43], [-0.3, 0.9, 0.2]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lo = np.array([-1.5, 0.0, -1.5])
    grids = []
    for top in np.linspace(1.95, 1.90, 6):              # the cloth's top coming down by 5 cm
        m = fit_light_view_projs(dirs, lo, np.array([1.5, top, 1.5]), np.zeros(2), 256)
        grids.append(m)
    for m in grids[1:]:
        np.testing.assert_allclose(m[:, :2, :3], grids[0][:, :2, :3])   # the same texel size and axes
        # A world point's texel coordinate moves by a whole number of texels.
        p = np.array([0.3, 0.2, -0.7, 1.0])
        shift = ((m @ p)[:, :2] - (grids[0] @ p)[:, :2]) * 256 / 2
        np.testing.assert_allclose(shift, np.round(shift), atol=1e-6)


def test_texel_sizes_are_one_texel_of_each_map_in_world_and_depth_units():
    lo, hi = np.array([-1.0, 0.0, -2.0]), np.array([3.0, 2.0, 1.0])
    dirs = np.array([[0, 1, 0], [1, 1, 1], [-0.3, 0.2, -1]], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    sizes = np.array([256, 1024, 64])
    ms = fit_light_view_projs(dirs, lo, hi, np.zeros(len(dirs)), sizes)
    texel = texel_sizes(ms, sizes)
    for m, (world, depth), size in zip(ms, texel, sizes):
        inv = np.linalg.inv(m)
        # The map's two x edges (clip x = -1, 1) mapped back to world space lie size texels apart.
        a, b = inv @ np.array([-1.0, 0.0, 0.5, 1.0]), inv @ np.array([1.0, 0.0, 0.5, 1.0])
        assert np.linalg.norm(b[:3] - a[:3]) == pytest.approx(world * size)
        # The near and far planes (z = 0, 1) lie 1 / depth texels apart.
        n, f = inv @ np.array([0.0, 0.0, 0.0, 1.0]), inv @ np.array([0.0, 0.0, 1.0, 1.0])
        assert np.linalg.norm(f[:3] - n[:3]) == pytest.approx(world / depth)


def test_a_thin_box_keeps_a_depth_range_of_several_texels():
    # A flat sheet lit along its normal: the casters' box has no depth. Its projection keeps
    # MIN_DEPTH_TEXELS texels of depth, so that a texel is a small share of the range (the variance
    # floor is in texels) and nothing divides by zero.
    lo, hi = np.array([-0.5, 1.0, -0.5]), np.array([0.5, 1.0, 0.5])
    m = fit_light_view_projs(np.array([[0.0, 1.0, 0.0]]), lo, hi, np.zeros(1), 256)
    world, depth = texel_sizes(m, 256)[0]
    assert np.all(np.isfinite(m)) and depth == pytest.approx(1.0 / (1.02 * MIN_DEPTH_TEXELS))


def test_composed_shader_carries_line_directives_per_file():
    src, files = compose("pem/filter.comp", {"X": 1})
    assert src.startswith("#version 450 core\n#define ")
    assert src.split("\n#line 1 0", 1)[0].endswith("\n#define X 1")   # the caller's defines after the contract's
    assert files == ["pem/filter.comp", "common/cube.glsl", "pem/tiles.glsl"]
    assert "#line 100001 1" in src


def test_compile_errors_name_the_file_and_line():
    log = "0:12(3): error: `foo' undeclared\n1:7(1): error: syntax error\n0:100009(2): error: x"
    text = _rewrite_log(log, ["pem/filter.comp", "common/cube.glsl"])
    assert "pem/filter.comp:12" in text and "common/cube.glsl:7" in text and "common/cube.glsl:9" in text


def test_a_fragment_stage_error_names_the_fragment_file(gl, monkeypatch):
    from renderer.gpu import shaders

    sources = {"t/ok.vert": "void main() { gl_Position = vec4(0.0); }",
               "t/bad.frag": "out vec4 o;\nvoid main() {\n    o = vec4(undeclared_name);\n}"}
    monkeypatch.setattr(shaders, "_read", lambda name: sources[name])
    with pytest.raises(ShaderError) as info:
        shaders.program(gl.ctx, "t/ok.vert", "t/bad.frag")
    assert "t/bad.frag:3" in str(info.value) and "t/ok.vert:" not in str(info.value), str(info.value)


def test_missing_include_is_a_shader_error():
    with pytest.raises(ShaderError, match="not found"):
        compose("no/such.glsl")


def test_a_second_context_on_the_thread_does_not_steal_the_first(renderer):
    from renderer.gpu.context import GLContext
    from renderer.lighting.pem import PEMSettings

    other = GLContext()   # e.g. a CLI command run inside a process that already holds a renderer
    cube = np.ones((6, 8, 8, 3), np.float32)
    pems = renderer.build_pems(cube, PEMSettings(6))
    try:
        level0 = pems.read_level(0).sum(axis=0)
        np.testing.assert_allclose(level0, 1.0, rtol=1e-3)
    finally:
        pems.release()
        other.release()


def test_the_lighting_pass_visits_every_light_once_grouped_by_kind():
    from renderer.lighting.pem import REGIONS_PER_TEXTURE
    from renderer.plan import FrameSettings, ShadingMode, light_kinds

    n = REGIONS_PER_TEXTURE + 8
    lights = np.zeros(n, LIGHT_DTYPE)
    small = np.arange(n) % 5 == 0                     # angular radius ~3 degrees, else ~30
    lights["params"][:, 3] = np.where(small, 0.05, 0.5)
    lights["shadow"][:, 3] = small                    # pack_lights' flag (shadows/lights.py, small_lights)
    lights["shadow"][:, 0] = np.where(np.arange(n) % 7 == 0, -1, 0)   # every 7th without a shadow map
    sharp = small & (np.arange(n) % 2 == 0)

    def kinds(max_glossiness=1.0, **kw):
        order, end = light_kinds(lights, sharp, FrameSettings(**kw), max_glossiness)
        assert sorted(order) == list(range(n)) and end[-1] == n and np.all(np.diff(end) >= 0)
        kind = np.zeros(n, int)
        kind[order] = np.searchsorted(end, np.arange(n), side="right")   # the kind of each light
        return kind

    # "wide": small lights' glossy term in closed form; the large lights read their glossy PEM (the
    # shader picks the closed form per pixel)...
    k = kinds(diffuse="pem", glossy="wide")
    np.testing.assert_array_equal(k & 1, np.ones(n, bool))     # diffuse from the PEMs
    np.testing.assert_array_equal(k >> 1 & 1, ~small)
    np.testing.assert_array_equal(k >> 2 & 1, sharp)
    np.testing.assert_array_equal(k >> 3 & 1, np.arange(n) >= REGIONS_PER_TEXTURE)
    assert np.all(kinds(diffuse="pem", glossy="pem") & 3 == 3)
    assert np.all(kinds(diffuse="lights", glossy="wide") & 3 == np.where(small, 0, 2))
    # ... unless the lobe is wider than their disc at every pixel: at g <= 0.8 (1/s >= 0.2) a disc of
    # sine 0.5 is (a^2 / 4 = 0.0625); at g = 1 - 0.0625 only without the margin.
    for g in (0.8, 0.76, 0.0):
        np.testing.assert_array_equal(kinds(diffuse="pem", glossy="wide", max_glossiness=g), k & ~2)
    np.testing.assert_array_equal(kinds(diffuse="pem", glossy="wide", max_glossiness=1.0 - 0.0625), k)
    np.testing.assert_array_equal(kinds(diffuse="pem", glossy="pem", max_glossiness=0.0) & 2, np.full(n, 2))
    # The baselines read both PEMs of every light.
    assert np.all(kinds(diffuse="lights", glossy="wide", mode=ShadingMode.AO_GREY) & 3 == 3)


def test_a_uniform_no_source_declares_is_an_error_and_one_a_variant_dropped_is_not(gl):
    from renderer.config import MAX_LIGHTS
    from renderer.errors import ShaderError
    from renderer.gpu.shaders import program, set_uniform

    prog = program(gl.ctx, "shading/background.vert", "shading/lighting.frag",
                   {"GLOSS_TABLE_SIZE": 257, "REGIONS_PER_TEXTURE": 192, "MODE": int(Mode.NO_OCCLUSION),
                    "TWO_PEM_TEXTURES": 0, "MAX_LIGHTS": MAX_LIGHTS})
    try:
        assert "u_contact_radius" not in prog                 # declared under CONTACT_SHADOWS: dropped here
        set_uniform(prog, "u_contact_radius", 1.0)            # ... and setting it is no error
        set_uniform(prog, "u_diffuse_level", 3.0)
        assert prog["u_diffuse_level"].value == 3.0
        with pytest.raises(ShaderError, match="u_diffuse_levels'"):
            set_uniform(prog, "u_diffuse_levels", 3.0)         # a typo
    finally:
        prog.release()
