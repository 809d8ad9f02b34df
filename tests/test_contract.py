"""The Python/GLSL contract (renderer/gpu/contract.py) is the only place either side writes a binding
point, a mode's number, a light kind's bit or the wide-lobe rule's constant, and every lighting
variant compiles with it."""

from __future__ import annotations

import ast
import itertools
import re
from pathlib import Path

import pytest

from renderer.gpu import contract
from renderer.gpu.shaders import compose
from renderer.renderer import ShadingMode

ROOT = Path(__file__).resolve().parents[1]
BIND_CALLS = {"bind_to_storage_buffer", "bind_to_uniform_block", "bind_to_image", "bind_image", "bind_sampler"}


def test_no_shader_writes_a_binding_or_a_mode_as_a_number():
    numbered = []
    for path in sorted((ROOT / "shaders").rglob("*")):
        if path.is_file():
            for i, line in enumerate(path.read_text().splitlines(), 1):
                if re.search(r"binding\s*=\s*\d", line) or re.search(r"\bMODE\s*[=!<>]=?\s*\d", line):
                    numbered.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert numbered == []


def test_no_python_binds_a_unit_by_a_number():
    numbered = []
    for path in sorted((ROOT / "renderer").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
                continue
            args = list(node.args)
            if node.func.attr == "use":
                args = [k.value for k in node.keywords if k.arg == "location"]
            elif node.func.attr not in BIND_CALLS:
                continue
            if args and isinstance(args[0], ast.Constant) and isinstance(args[0].value, int):
                numbered.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert numbered == []


def test_each_program_uses_a_binding_point_once_and_every_name_is_defined():
    for enum, _ in contract._PREFIXES:
        assert len(enum.__members__) == len(list(enum)), f"{enum.__name__} has two names for one value"
    defines = contract.glsl_defines()
    source, _ = compose("shading/lighting.frag")
    head = source.split("\n#line", 1)[0]
    assert all(f"#define {k} {v}" in head for k, v in defines.items())
    used = set(re.findall(r"\b((?:BUF|TEX|IMG|MODE|KIND)_(?!LOOP\b)[A-Z0-9_]+)\b",
                          "".join(p.read_text() for p in (ROOT / "shaders").rglob("*") if p.is_file())))
    assert used <= set(defines), sorted(used - set(defines))


def _variants():
    """Every value of every dimension of the lighting program, one at a time from balanced's own
    variant, and each mode with every other switch on."""
    base = {"mode": ShadingMode.FULL, "diffuse": "lights", "two_textures": False, "glossy": "wide", "contact": True,
            "sub_lights": 2, "lobes": None, "blocker": False, "oracle": False}
    options = {"mode": list(ShadingMode), "diffuse": ["pem"], "two_textures": [True], "glossy": ["pem"],
               "contact": [False], "sub_lights": [1], "lobes": [(1, 0), (1, 1), (2, 0), (2, 2)], "blocker": [True],
               "oracle": [True]}
    out = [base]
    for key, values in options.items():
        out += [{**base, key: v} for v in values]
    out += [{**base, "mode": m, "two_textures": True, "lobes": (2, 2), "blocker": True} for m in ShadingMode]
    return out


@pytest.mark.parametrize("lighting_pass", ["fragment", "compute"])
def test_every_lighting_variant_compiles(renderer, lighting_pass):
    kept = renderer.lighting_pass
    renderer.lighting_pass = lighting_pass
    try:
        for v in _variants():
            prog, vao = renderer._shade_variant(**v)
            assert prog is not None and (vao is None) == (lighting_pass == "compute"), v
    finally:
        renderer.lighting_pass = kept


def test_the_light_kinds_are_the_shaders_bits():
    bits = [int(k) for k in contract.LightKind]
    assert sorted(bits) == [1, 2, 4, 8] and 2 ** len(bits) == contract.N_LIGHT_KINDS
    kinds = {sum(c) for r in range(len(bits) + 1) for c in itertools.combinations(bits, r)}
    assert kinds == set(range(contract.N_LIGHT_KINDS))
