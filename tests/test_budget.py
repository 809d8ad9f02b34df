import pytest

from renderer.errors import InvalidInputError
from renderer.presets import preset
from renderer.presets.budget import budget_knobs, choose, summarize


def _row(scene, lights, ms, err, mode="full"):
    s = {"lights": lights, "face_size": 128, "shadow_size": 256, "blur_scale": 1.0, "filter": "sqrt-cosine"}
    return {"scene": scene, "mode": mode, "settings": s, "frame_ms": ms, "rel_rmse": err}


BENCH = {"machine": {"gl_renderer": "test"}, "config": {"size": 256}, "rows": [
    _row("a", 6, 10, 0.20), _row("b", 6, 12, 0.15),
    _row("a", 24, 30, 0.08), _row("b", 24, 32, 0.06),
    _row("a", 48, 60, 0.04), _row("b", 48, 62, 0.045),
    _row("a", 96, 120, 0.02), _row("b", 96, 118, 0.03),
    _row("a", 48, 5, 0.9, mode="none"),          # baselines never become presets
]}


def test_summary_takes_the_worst_scene_and_skips_baselines():
    table = summarize(BENCH)
    by_lights = {e["settings"]["lights"]: e for e in table["entries"]}
    assert set(by_lights) == {6, 24, 48, 96}
    assert by_lights[24]["worst_rel_rmse"] == 0.08
    assert by_lights[48]["worst_rel_rmse"] == 0.045


def test_budgets_choose_from_the_measured_table():
    table = summarize(BENCH)
    assert choose(table, error_budget=0.05)["settings"]["lights"] == 48      # fastest within 5 %
    assert choose(table, frame_budget_ms=40)["settings"]["lights"] == 24     # most accurate within 40 ms
    assert choose(table, frame_budget_ms=100, error_budget=0.1)["settings"]["lights"] == 48
    with pytest.raises(InvalidInputError, match="relax"):
        choose(table, frame_budget_ms=5, error_budget=0.01)


def test_the_presets_are_their_files_whatever_the_measured_table_holds(monkeypatch):
    import renderer.presets.budget as budget
    from renderer.cli import build_parser, resolve_quality
    from renderer.presets import PRESET_DIR, presets

    found, source = presets()
    assert "renderer/presets" in source and set(found) == {"fast", "balanced", "accurate", "paper"}
    for name, knobs in found.items():
        text = (PRESET_DIR / f"{name}.toml").read_text()
        assert f"lights = {knobs['lights']}" in text
    # A table that would have made another balanced changes nothing: presets are not chosen at run time.
    monkeypatch.setattr(budget, "load_table", lambda path=None: summarize(BENCH))
    assert resolve_quality(build_parser().parse_args(["render"]))["lights"] == found["balanced"]["lights"]


def test_a_preset_file_that_misses_a_setting_or_names_an_unknown_one_is_refused(tmp_path, monkeypatch):
    import renderer.preset_files as presets_mod

    good = (presets_mod.PRESET_DIR / "fast.toml").read_text()
    monkeypatch.setattr(presets_mod, "PRESET_DIR", tmp_path)
    (tmp_path / "fast.toml").write_text(good.replace("sub_lights = 1\n", ""))
    with pytest.raises(ValueError, match=r"missing \['sub_lights'\]"):
        presets_mod._read_preset("fast")
    (tmp_path / "fast.toml").write_text(good + "shadow_bias = 2.0\n")
    with pytest.raises(ValueError, match=r"unknown \['shadow_bias'\]"):
        presets_mod._read_preset("fast")
    (tmp_path / "fast.toml").write_text(good.replace("version = 1", "version = 2"))
    with pytest.raises(ValueError, match="version 2"):
        presets_mod._read_preset("fast")


def test_a_budget_sets_every_measured_knob_unless_a_flag_says_otherwise(monkeypatch):
    import renderer.presets.budget as budget
    from renderer.cli import build_parser, resolve_quality


    rows = [dict(_row("a", 24, 30, 0.08)), dict(_row("a", 48, 60, 0.04))]
    rows[1]["settings"] = {**rows[1]["settings"], "sub_lights": 4, "whole_sources": False, "caster_detail": 0.1}
    table = summarize({**BENCH, "rows": rows})
    monkeypatch.setattr(budget, "load_table", lambda path=None: table)

    def knobs(*flags):
        q = resolve_quality(build_parser().parse_args(["render", "--size", "256x256", *flags]))
        return q, (q["sub_lights"], q["whole_sources"], q["caster_detail"])

    q, k = knobs("--error-budget", "0.05")
    assert (q["lights"], k) == (48, (4, False, 0.1))
    assert "budget" in q["source"]
    assert knobs("--error-budget", "0.05", "--sub-lights", "8", "--whole-sources")[1] == (8, True, 0.1)
    q, k = knobs()                                              # no budget: the balanced preset's file
    file = preset("balanced")
    assert k == (file["sub_lights"], file["whole_sources"], file["caster_detail"]) and "preset balanced" in q["source"]
    assert q["small_light_scale"] == file["small_light_scale"]


def test_a_presets_small_light_scale_yields_to_a_large_shadow_map():
    from renderer.presets import frame_settings, merge_knobs, preset

    assert preset("balanced")["small_light_scale"] == 4
    knobs = merge_knobs(preset("balanced"), {"shadow_size": 4096})
    assert knobs["small_light_scale"] == 2 and frame_settings(knobs, 8, 8).shadow_size == 4096
    assert merge_knobs(preset("balanced"), {"shadow_size": 1024})["small_light_scale"] == 4
    # A scale the caller names is kept, and the frame settings refuse what cannot be made.
    knobs = merge_knobs(preset("balanced"), {"shadow_size": 4096, "small_light_scale": 4})
    with pytest.raises(InvalidInputError, match="8192"):
        frame_settings(knobs, 8, 8)


def test_a_budget_brings_its_measured_filter_unless_one_is_named(monkeypatch):
    import renderer.presets.budget as budget
    from renderer.cli import build_parser, pem_settings, resolve_quality
    from renderer.shading.material import Material

    box = dict(_row("a", 48, 40, 0.05))
    box["settings"] = {**box["settings"], "filter": "box"}
    table = summarize({**BENCH, "rows": [box, dict(_row("a", 24, 30, 0.3))]})
    monkeypatch.setattr(budget, "load_table", lambda path=None: table)

    args = build_parser().parse_args(["render", "--size", "256x256", "--error-budget", "0.1"])
    q = resolve_quality(args)
    assert q["filter"] == "box" and q["lights"] == 48
    assert pem_settings(args, q, [Material()]).filter.value == "box"   # the PEMs are built as measured
    args = build_parser().parse_args(["render", "--size", "256x256", "--error-budget", "0.1", "--filter", "gauss"])
    assert resolve_quality(args)["filter"] == "gauss"
    assert resolve_quality(build_parser().parse_args(["render"]))["filter"] == "sqrt-cosine"


def test_the_service_chooses_budgets_from_the_table_it_read_at_start_up():
    from renderer.presets import presets as resolved_presets
    from service.schemas import OutputSpec, QualitySpec
    from service.settings import ServiceSettings
    from service.specs import resolve_quality

    table = summarize(BENCH)             # not the package's stored table
    found, _ = resolved_presets()
    settings = ServiceSettings()
    q = resolve_quality(QualitySpec(error_budget=0.1), OutputSpec(width=256, height=256), found, table, settings)
    assert q.knobs["lights"] == 24 and "on test" in q.info["source"]
    # None stored when the service started: a budget is refused with what to do, whatever the disk holds now.
    with pytest.raises(InvalidInputError, match="none is stored"):
        resolve_quality(QualitySpec(frame_budget_ms=100), OutputSpec(width=16, height=16), found, None, settings)


def test_a_budget_for_a_frame_size_the_table_was_not_measured_at_is_refused(monkeypatch):
    import renderer.presets.budget as budget
    from renderer.cli import build_parser, resolve_quality


    table = summarize(BENCH)   # measured at 256 x 256
    monkeypatch.setattr(budget, "load_table", lambda path=None: table)
    assert resolve_quality(build_parser().parse_args(["render", "--size", "256x256", "--error-budget", "0.1"]))
    with pytest.raises(InvalidInputError, match="measured at 256x256 on test; a 512x384 frame"):
        resolve_quality(build_parser().parse_args(["render", "--size", "512x384", "--error-budget", "0.1"]))
    # A preset is not a measurement of one size: any size takes it.
    assert resolve_quality(build_parser().parse_args(["render", "--size", "512x384"]))["lights"] == preset("balanced")["lights"]


def test_a_budget_measured_on_another_device_is_refused(renderer):
    from renderer.cli import build_parser, check_budget_device, resolve_quality
    from renderer.presets.budget import check_device

    table = summarize(BENCH)   # measured on "test"
    with pytest.raises(InvalidInputError, match="measured on test; this renderer runs on"):
        budget_knobs(None, 0.1, table, (256, 256), renderer.gl.renderer_name)
    assert budget_knobs(None, 0.1, table, (256, 256), "test")[0]["lights"] == 24
    # The package's table was measured on this kind of machine: the command line takes it here, and
    # would refuse it on another GPU.
    q = resolve_quality(build_parser().parse_args(["render", "--size", "256x256", "--error-budget", "0.3"]))
    assert q["source"].startswith("budget")
    check_budget_device(q, renderer)
    with pytest.raises(InvalidInputError, match="this renderer runs on another GPU"):
        check_device(q["measured_on"], "another GPU")
