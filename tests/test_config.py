"""The settings registry (renderer/config.py): one declaration per setting, read by the frame's
checks, the presets, the command line, the service's model and the generated docs."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from renderer import config, presets
from renderer.cli import build_parser
from renderer.errors import InvalidInputError
from renderer.lighting.pem import PEMSettings
from renderer.presets import PRESET_NAMES, preset
from renderer.renderer import FrameSettings
from service.schemas import QualitySpec

ROOT = Path(__file__).resolve().parents[1]


def test_the_stored_settings_reference_is_what_the_registry_generates():
    assert (ROOT / "docs" / "settings.md").read_text() == presets.reference_table(), \
        "docs/settings.md is stale: regenerate it with renderer.presets.reference_table()"


def test_every_setting_reaches_the_frame_or_the_pem_set_the_command_line_and_the_service():
    frame_fields = {f.name for f in dataclasses.fields(FrameSettings)}
    pem_fields = {f.name for f in dataclasses.fields(PEMSettings)} | {"lights", "face_size"}
    assert set(config.FRAME_SETTINGS) <= frame_fields
    assert set(config.PEM_SETTINGS) <= pem_fields and not set(config.PEM_SETTINGS) & frame_fields
    render = build_parser()._subparsers._group_actions[0].choices["render"]
    dests = {a.dest for a in render._actions}
    assert set(config.NAMES) <= dests
    assert set(config.NAMES) <= set(QualitySpec.model_fields)
    for name in PRESET_NAMES:   # each preset names every setting, within its limits
        knobs = preset(name)
        assert list(knobs) == list(config.NAMES)
        for k, v in knobs.items():
            assert config.check(k, v) == v


def test_the_frame_and_the_pems_default_to_balanced_and_the_paper_preset_is_the_registrys_defaults():
    f, pem, balanced = FrameSettings(), PEMSettings(), preset("balanced")
    for name in config.FRAME_SETTINGS:
        assert getattr(f, name) == balanced[name], name
        config.check(name, config.BY_NAME[name].default)
    assert (pem.n_lights, pem.whole_sources, pem.lights_from) == (balanced["lights"], balanced["whole_sources"],
                                                       balanced["lights_from"]) == (24, True, "auto")
    paper = {name: config.BY_NAME[name].default for name in config.NAMES}
    assert paper == preset("paper")
    assert (paper["diffuse"], paper["glossy"], paper["sub_lights"], paper["whole_sources"]) == ("pem", "pem", 1, False)


@pytest.mark.parametrize("st", config.SETTINGS, ids=lambda s: s.name)
def test_each_setting_refuses_what_it_cannot_be_and_names_itself(st):
    bad = [None, "8", [1], math.nan, math.inf]
    if st.type is bool:
        bad += [1, 0.0]
    elif st.choices is not None:
        bad += [st.choices[0].upper(), True]
    else:
        bad += [True, st.minimum - 1, st.maximum * 2 + 1]
        if st.above_minimum:
            bad.append(st.minimum)
        if st.type is int:
            bad.append(float(st.default))   # a whole number, not a float
    for value in bad:
        with pytest.raises(InvalidInputError, match=st.name):
            st.check(value)
    assert st.check(st.default) == st.default


def test_numpy_scalars_pass_as_their_python_kind():
    assert config.check("shadow_size", np.int64(512)) == 512 and type(config.check("shadow_size", np.int64(512))) is int
    assert config.check("caster_detail", np.float32(0.5)) == 0.5
    assert config.check("sharp_large_lights", np.bool_(True)) is True
    for n in (6, 12, 24, 48, 96, 192, 384):
        assert config.check("lights", n) == n
    for n in (0, 7, 18, 36, 768):
        with pytest.raises(InvalidInputError, match="6 \\* 2\\^k"):
            config.check("lights", n)


def test_the_bench_sweeps_every_setting_that_declares_values_and_each_value_is_valid():
    from renderer.bench.run import SWEEPS

    declared = [st for st in config.SETTINGS if st.sweep]
    assert [st.name for st in declared] == [k for k in SWEEPS if k in config.BY_NAME]
    for st in declared:
        for value in st.sweep:
            for name, v in (value.items() if isinstance(value, dict) else [(st.name, value)]):
                config.check(name, v)


def test_a_removed_setting_is_no_longer_one_and_says_what_replaced_it():
    assert config.RETIRED and not set(config.RETIRED) & set(config.NAMES)
    assert all(reason.startswith("removed") and len(reason) > 20 for reason in config.RETIRED.values())


def test_one_rule_resolves_a_request_for_the_command_line_the_service_and_the_python_api():
    """renderer.presets.resolve is the one rule: the command line's flags, the service's request and a
    Python caller asking the same get the same settings, and each setting lands in the key of what
    its change makes anew (the registry's `invalidates`)."""
    from renderer.cli import build_parser, resolve_quality
    from renderer.presets import presets, resolve
    from service.schemas import OutputSpec, QualitySpec
    from service.settings import ServiceSettings
    from service.specs import resolve_quality as request_quality

    q = resolve("fast", {"lights": 48, "contact_shadow_texels": None})   # None: not given
    assert q["lights"] == 48 and q["contact_shadow_texels"] == preset("fast")["contact_shadow_texels"]
    assert q.preset == "fast" and q.filter == "sqrt-cosine" and "preset fast" in q.source
    flags = resolve_quality(build_parser().parse_args(["render", "--preset", "fast", "--lights", "48"]))
    assert flags == q.as_dict()
    request = request_quality(QualitySpec(preset="fast", lights=48), OutputSpec(width=64, height=64),
                              presets()[0], None, ServiceSettings())
    assert request.knobs == dict(q.knobs) and request.pem == q.pems() and request.frame == q.frame(64, 64)
    keys = {kind: q.key(kind) for kind in config.INVALIDATES}
    assert sum(map(len, keys.values())) == len(config.NAMES) + 1   # every setting once, and the filter
    assert resolve("fast", {"lights": 96}).key("pem set") != keys["pem set"]
    assert resolve("fast", {"lights": 96}).key("shadow maps") == keys["shadow maps"]
    assert resolve("fast", {"shadow_size": 64}).key("shadow maps") != keys["shadow maps"]
    with pytest.raises(TypeError):
        q.knobs["lights"] = 6   # frozen
