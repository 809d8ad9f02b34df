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


def test_the_frame_and_the_pems_are_made_of_the_registry_and_hold_its_defaults_the_paper_preset():
    f, pem = FrameSettings(), PEMSettings()
    paper = {name: config.BY_NAME[name].default for name in config.NAMES}
    assert paper == preset("paper")
    for name in config.FRAME_SETTINGS:
        assert getattr(f, name) == paper[name], name
    for name in config.PEM_FIELDS:
        assert getattr(pem, name) == paper[name], name
    # Each setting is a field of one of the two, with its declared type; no quality field is declared apart.
    frame_fields = {x.name: x.type for x in dataclasses.fields(FrameSettings)}
    pem_fields = {x.name: x.type for x in dataclasses.fields(PEMSettings)}
    for name in config.NAMES:
        if name != "face_size":
            assert (frame_fields | pem_fields)[name] is config.BY_NAME[name].type, name
    assert set(frame_fields) - set(config.FRAME_SETTINGS) == {"width", "height", "bleed_reduction", "mode",
                                                               "background", "environment_rotation_deg", "aovs"}
    assert set(pem_fields) - set(config.PEM_FIELDS) == {"filter", "levels", "base_level"}
    # Both check their settings against the registry's limits, naming the setting.
    with pytest.raises(InvalidInputError, match=r"lights must be a whole number in \[6, 384\]"):
        PEMSettings(5)
    with pytest.raises(InvalidInputError, match="lights_from must be one of"):
        PEMSettings(lights_from="sky")
    assert (paper["diffuse"], paper["glossy"], paper["sub_lights"], paper["whole_sources"]) == ("pem", "pem", 1, False)
    # The presets are data no module takes its defaults from: only renderer/presets reads the files.
    import renderer
    readers = sorted(str(p.relative_to(Path(renderer.__file__).parent)) for p in Path(renderer.__file__).parent.rglob("*.py")
                     if "preset_files" in p.read_text() and p.name != "preset_files.py")
    assert readers == ["presets/__init__.py"], readers
    # ... and no product module takes a preset's values when it is imported or as a default argument
    # (the benchmarks measure around the presets: theirs is the point).
    assert _preset_defaults() == [], _preset_defaults()


# What reads a preset's values (renderer.presets' functions).
_PRESET_READERS = {"preset", "presets", "resolve", "frame_settings", "pem_settings", "preset_pems", "merge_knobs"}


def _preset_defaults(sources: dict[str, str] | None = None) -> list[str]:
    """'module:line' of every call to a preset reader at a module's top level (a class body included) or
    in a default argument, in renderer/ (but renderer/presets and the benchmarks) and service/."""
    import ast

    import renderer

    if sources is None:
        root = Path(renderer.__file__).parent
        files = [f for d in (root, root.parent / "service") for f in d.rglob("*.py")
                 if not {"presets", "bench"} & set(f.relative_to(root.parent).parts) and f.name != "preset_files.py"]
        sources = {str(f.relative_to(root.parent)): f.read_text() for f in files}
    found = []

    def calls(node):
        for sub in ast.walk(node):
            if isinstance(sub, ast.Call):
                f = sub.func
                # resolve(...) imported from renderer.presets, or presets.resolve(...): not Path.resolve().
                if (isinstance(f, ast.Name) and f.id in _PRESET_READERS) or (
                        isinstance(f, ast.Attribute) and f.attr in _PRESET_READERS and isinstance(f.value, ast.Name)
                        and "preset" in f.value.id.lower()):
                    yield sub

    def visit(body, name):
        for stmt in body:
            if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for d in stmt.args.defaults + [d for d in stmt.args.kw_defaults if d is not None]:
                    found.extend(f"{name}:{c.lineno}" for c in calls(d))
            elif isinstance(stmt, ast.ClassDef):
                visit(stmt.body, name)
            else:
                found.extend(f"{name}:{c.lineno}" for c in calls(stmt))

    for name, text in sources.items():
        visit(ast.parse(text).body, name)
    return found


def test_the_preset_defaults_check_finds_a_preset_read_at_import_or_as_a_default():
    assert _preset_defaults({"m.py": "from renderer.presets import preset\nBASE = preset('balanced')\n"}) == ["m.py:2"]
    assert _preset_defaults({"m.py": "from renderer import presets\ndef f(s=presets.resolve(None).frame(8, 8)):\n    pass\n"}) \
        == ["m.py:2"]
    assert _preset_defaults({"m.py": "class A:\n    k = presets.preset('fast')\n"}) == ["m.py:2"]
    assert _preset_defaults({"m.py": "def f():\n    return preset('fast')\n"}) == []   # at run time: the caller's choice
    assert _preset_defaults({"m.py": "ROOT = Path(__file__).resolve()\n"}) == []


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
    for n in (6, 7, 12, 16, 18, 24, 36, 384):   # any count from 6: the median cut's extra regions where the energy is
        assert config.check("lights", np.int64(n)) == n
    for n in (0, 5, 385, 768):
        with pytest.raises(InvalidInputError, match=r"lights must be a whole number in \[6, 384\]"):
            config.check("lights", n)


def test_the_bench_sweeps_settings_of_the_registry_in_its_order_and_each_value_is_valid():
    """The sweep's table is the lab's (lab/garment_lab/run.py), not the registry's: its rows name
    settings of the registry, in the registry's order, and every value passes the registry's check."""
    from garment_lab.run import SETTING_SWEEPS, SWEEPS

    assert list(SETTING_SWEEPS) == [n for n in config.NAMES if n in SETTING_SWEEPS]
    assert set(SETTING_SWEEPS) <= set(config.BY_NAME) and set(SETTING_SWEEPS) <= set(SWEEPS)
    for setting, values in SETTING_SWEEPS.items():
        for value in values:
            for name, v in (value.items() if isinstance(value, dict) else [(setting, value)]):
                config.check(name, v)
    assert not hasattr(config.SETTINGS[0], "sweep")


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


def test_the_options_no_preset_chooses_are_declared_once_and_read_by_every_side():
    from renderer.envmap.layouts import Layout
    from renderer.lighting.filters import Filter
    from renderer.renderer import ShadingMode
    from service.routes.environments import DEFAULT_FILTER, DEFAULT_LAYOUT
    from service.schemas import FilterName, LayoutName, ModeName

    opt = config.OPTION
    # The renderer's own enums hold the registry's values (layout's "auto" is a choice, not a layout).
    assert tuple(f.value for f in Filter) == opt["filter"].choices
    # The renderer's modes begin with the product's (the rest are the lab's baselines).
    assert tuple(m.value for m in ShadingMode)[:len(opt["mode"].choices)] == opt["mode"].choices
    assert ("auto",) + tuple(lay.value for lay in Layout) == opt["layout"].choices
    # The service's enums and defaults, and the command line's choices and defaults.
    for enum, name in ((FilterName, "filter"), (ModeName, "mode"), (LayoutName, "layout")):
        assert tuple(e.value for e in enum) == opt[name].choices
    assert (DEFAULT_FILTER.value, DEFAULT_LAYOUT.value) == (opt["filter"].default, opt["layout"].default)
    fields = QualitySpec.model_fields
    assert fields["bleed_reduction"].default == opt["bleed_reduction"].default == FrameSettings().bleed_reduction
    assert fields["mode"].default.value == opt["mode"].default and PEMSettings().filter.value == opt["filter"].default
    render = build_parser()._subparsers._group_actions[0].choices["render"]
    actions = {a.dest: a for a in render._actions}
    for name in ("filter", "mode", "layout"):
        assert tuple(actions[name].choices) == opt[name].choices
    assert actions["mode"].default == "full" and actions["layout"].default == "auto" and actions["filter"].default is None
    # One check, the registry's: [0, 1) for the bleed reduction, in the frame and on the command line.
    with pytest.raises(InvalidInputError, match=r"bleed_reduction must be a number in \[0, 1\)"):
        FrameSettings(bleed_reduction=1.0)
    assert render.parse_args(["--bleed-reduction", "0.5"]).bleed_reduction == 0.5
    with pytest.raises(SystemExit):
        render.parse_args(["--bleed-reduction", "1"])


def test_the_rules_between_settings_are_declared_once_and_applied_both_ways():
    side = config.MAX_SHADOW_SIDE
    assert config.shadow_side_error(side // 4, 4) is None and "at most" in config.shadow_side_error(side // 2, 4)
    assert config.fitted_small_light_scale(side // 2, 4) == 2 and config.fitted_small_light_scale(side, 8) == 1
    # A preset's scale yields to the caller's shadow_size; a scale the caller names is refused by the frame.
    knobs = presets.merge_knobs(preset("balanced"), {"shadow_size": side // 2})
    assert knobs["small_light_scale"] == 2
    knobs = presets.merge_knobs(preset("balanced"), {"shadow_size": side // 2, "small_light_scale": 4})
    with pytest.raises(InvalidInputError, match="shadow_size x small_light_scale"):
        presets.frame_settings(knobs, 64, 64)
    # The most lights that may get sharp maps, which the service's memory bound counts.
    assert config.most_sharp_lights(48, 1, 0.0) == 0 and config.most_sharp_lights(48, 2, 0.0) == 48
    assert config.most_sharp_lights(48, 2, 2.4) == 20 and config.most_sharp_lights(48, 2, 1e-320) == 48


def test_the_papers_baselines_are_the_labs_not_a_public_option():
    """The mode option (command line, service) offers the method and its no-occlusion twin; the
    ambient-occlusion and many-light baselines stay reachable through FrameSettings, for the lab."""
    from renderer.errors import InvalidInputError
    from renderer.settings import FrameSettings, ShadingMode

    assert config.OPTION["mode"].choices == ("full", "none")
    for research in ("ao", "ao-color", "many-lights"):
        with pytest.raises(InvalidInputError, match="one of full, none"):
            config.OPTION["mode"].check(research)
    assert FrameSettings(16, 16, mode=ShadingMode.MANY_LIGHTS).mode is ShadingMode.MANY_LIGHTS
