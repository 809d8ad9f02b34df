"""The benchmark's outputs: the Pareto front, the plot and the settings sweep."""

import numpy as np
import pytest
from PIL import Image

from garment_lab.report import pareto_front, write_pareto
from garment_lab.run import BALANCED, QUICK_SWEEPS, SWEEPS, Row, _settings_list
from renderer.presets import presets


def _row(knob, value, ms, err, mode="full", scene="s"):
    return Row(scene, "env", knob, value, mode, dict(BALANCED), ms, {}, 1.0, 1, 1, err, 0.1, 0.03, 0.02)


def test_pareto_front_keeps_only_undominated_settings():
    t = np.array([10.0, 20.0, 15.0, 30.0, 12.0])
    e = np.array([0.5, 0.1, 0.3, 0.05, 0.6])
    assert pareto_front(t, e).tolist() == [0, 2, 1, 3]   # 12 ms / 0.6 is beaten by 10 ms / 0.5


def test_plot_is_written_per_scene(tmp_path):
    rows = [_row("lights", 6, 30, 0.2), _row("balanced", "balanced", 120, 0.12),
            _row("sharp_large_lights", "sharp_large_lights=True, small_light_min_energy=4.8", 100, 0.13),
            _row("baseline", "none", 25, 0.19, mode="none"), _row("lights", 6, 40, 0.4, scene="t")]
    path = tmp_path / "pareto.png"
    write_pareto(path, rows)
    w, h = Image.open(path).size
    assert w > 1.8 * h                                   # two scenes side by side


def test_every_sweep_value_is_one_setting_that_differs_from_balanced():
    for sweeps in (QUICK_SWEEPS, SWEEPS):
        settings = _settings_list(sweeps)
        assert settings[0][0] == "balanced"
        for knob, value, s in settings[1:]:
            assert s != BALANCED and set(s) == set(BALANCED), (knob, value)
        keys = [tuple(sorted(s.items())) for _, _, s in settings]
        assert len(keys) == len(set(keys))               # no setting measured twice


@pytest.mark.system
def test_speed_times_every_variant_side_by_side(tmp_path):
    import json

    from garment_lab.speed import UPLOAD_VARIANTS, VARIANTS, markdown, run_speed

    result = run_speed(tmp_path / "speed.json", rounds=2, size=16, shared=False, log=lambda *_: None)
    rows = result["scenes"]["studio-dress"]
    # The normals rows only where frames upload positions (--large).
    assert set(rows) == set(VARIANTS) - set(UPLOAD_VARIANTS) and rows["balanced"]["ratio_to_balanced"] == 1.0
    assert all(r["p10_ms"] <= r["median_ms"] <= r["p90_ms"] and r["median_ms"] > 0 for r in rows.values())
    assert json.loads((tmp_path / "speed.json").read_text())["rounds"] == 2
    assert markdown(result).count("\n") == 2


@pytest.mark.system
def test_speed_times_the_gpu_targets_large_scene(tmp_path):
    from conftest import asset

    from garment_lab.speed import markdown, run_speed
    from renderer.errors import InvalidInputError

    asset("sim", "newton_shirt_drape_f060.obj")
    # The shirt (12,736 triangles) subdivided once: 50,944 (the command's default asks for 100k: 203,776).
    variants = ["balanced", "fast", "balanced, normals on the CPU", "balanced, normals on the GPU"]
    result = run_speed(None, rounds=1, size=16, large=True, min_triangles=20_000, variants=variants,
                       log=lambda *_: None)
    assert result["garment_triangles"] == 4 * 12_736 and result["triangles"] > result["garment_triangles"]
    (name, rows), = result["scenes"].items()
    assert name == "newton-shirt-50944/hard-sun" and set(rows) == set(variants)
    assert rows["fast"]["median_ms"] > 0 and result["pem_build"]["lights"] == presets()[0]["balanced"]["lights"]
    assert result["pem_build"]["wall_ms"] > 0
    # GPU time only where the driver's timer queries mean something.
    assert (rows["balanced"]["gpu_ms"] is not None) == result["gpu_timers"]
    assert markdown(result).count("\n") == 2
    with pytest.raises(InvalidInputError, match="balanced"):
        run_speed(None, variants=["fast"])


def test_error_split_summary_says_which_part_is_larger():
    from garment_lab.split import CLASSES, summary

    def config(exact_excess, maps_vs_exact):
        classes = {c: {"pixels": 1 / 3, "share": 1 / 3, "rel_rmse": 0.1} for c in CLASSES}
        return {"lights": 48, "lights_alone": 0.05, "exact": 0.1, "exact_excess": exact_excess, "maps": 0.12,
                "maps_excess": 0.1, "maps_vs_exact": maps_vs_exact, "exact_classes": classes,
                "maps_vs_exact_classes": classes}

    rows = [{"configs": {"balanced": config(0.08, 0.05)}}, {"configs": {"balanced": config(0.04, 0.06)}},
            {"configs": {"balanced": config(0.02, 0.09)}}]
    (s,) = summary(rows, ["balanced"])
    assert s["scenes"] == 3 and s["exact_excess"] == 0.04 and s["maps_vs_exact"] == 0.06
    assert abs(s["maps_dominate"] - 2 / 3) < 1e-12

def test_the_assets_folder_can_be_named(monkeypatch, tmp_path):
    from conftest import asset

    from garment_lab import scenes

    real = asset("sim", "newton_shirt_drape_f060.obj").parents[1]
    monkeypatch.setenv(scenes.ASSETS_VARIABLE, str(tmp_path))      # an empty folder: no target scenes
    assert scenes.shared_assets() == tmp_path and scenes.shared_scenes() == [] and scenes.large_scene() is None
    monkeypatch.setenv(scenes.ASSETS_VARIABLE, str(real))
    found = scenes.shared_scenes()
    assert [s.name for s in found] == [f"newton-shirt/{k}" for k in scenes.TARGET_PROBES]
    monkeypatch.delenv(scenes.ASSETS_VARIABLE)
    assert scenes.shared_assets() == scenes.SHARED_ASSETS


@pytest.mark.system
def test_speed_large_equal_error_sets_each_setting_against_a_reference_ladder():
    from conftest import asset

    from garment_lab.speed import run_speed

    asset("sim", "newton_shirt_drape_f060.obj")
    logged = []
    result = run_speed(None, rounds=1, size=8, large=True, min_triangles=20_000, variants=["balanced", "fast"],
                       equal_error={"truth_spp": 4, "workers": 2, "ladder": (1, 2, 4)}, log=logged.append)
    e = result["equal_error"]
    assert e["workers"] == 2 and e["truth_spp"] == 8 and e["truth_rel_rmse"] == pytest.approx(e["noise_floor_rel_rmse"] / 2)
    # 4 spp would be half the truth's 8: the ladder stops at a quarter.
    assert [r["spp"] for r in e["ladder"]] == [1, 2] and any("stops at 2 spp" in line for line in logged)
    assert all(r["ms"] > 0 and r["rel_rmse"] > 0 for r in e["ladder"])
    for name in ("balanced", "fast"):
        row = e["presets"][name]
        assert row["rel_rmse"] > 0 and row["frame_ms"] > 0
        if row["ref_spp"] is not None:   # the first rung at least as close as the setting
            rung = next(r for r in e["ladder"] if r["spp"] == row["ref_spp"])
            assert row["resolved"] and rung["rel_rmse"] <= row["rel_rmse"]
            assert row["speedup"] == pytest.approx(rung["ms"] / row["frame_ms"])


@pytest.mark.system
def test_bench_end_to_end_writes_its_three_outputs(tmp_path):
    # `garment-render bench --quick`'s sweep on the bundled scene, made small (24x24, one timed
    # frame, a reference of 2 x 8 spp): every quick setting and the four baselines become rows with
    # timings, memory and errors; bench.md names the machine, the metric's eps, the noise floor and
    # the targets; pareto.png is an image.
    import json

    from garment_lab.run import BASELINE_MODES, BenchConfig, run_bench

    cfg = BenchConfig(quick=True, size=24, frames=1, ref_spp=8, ladder=(1, 4), shared=False)
    rows = run_bench(tmp_path, cfg, log=lambda *a: None)
    data = json.loads((tmp_path / "bench.json").read_text())
    assert set(data) == {"machine", "presets_digest", "config", "rows", "refused"} and data["machine"]["gl_renderer"]
    assert data["refused"] == []   # nothing in the quick sweep is beyond the driver
    from renderer.presets import presets_digest

    assert data["presets_digest"] == presets_digest()
    assert len(data["rows"]) == len(rows) == len(_settings_list(QUICK_SWEEPS)) + len(BASELINE_MODES)
    knobs = {r["knob"] for r in data["rows"]}
    assert {"lights", "face_size", "shadow_size", "blur_scale", "filter", "baseline", "balanced"} <= knobs
    assert {r["value"] for r in data["rows"] if r["knob"] == "baseline"} == {m.value for m in BASELINE_MODES}
    for r in data["rows"]:
        assert r["frame_ms"] > 0 and r["pem_build_ms"] > 0 and r["pem_bytes"] > 0, r["knob"]
        assert {"geometry", "shading", "readback"} <= set(r["stages_ms"]), r["knob"]
        assert np.isfinite(r["rel_rmse"]) and 0 < r["flip"] < 1, r["knob"]
        assert np.isfinite(r["ref_noise_rel_rmse"]) and r["ref_noise_rel_rmse"] > 0
        assert r["extra"]["ref_ladder_top_ms"] > 0
        # The artefact share of every row (NaN only where no pixel could be judged).
        share, judged = r["extra"]["artefact_share"], r["extra"]["artefact_judged"]
        assert 0 < judged <= 1 and 0 <= share <= 1, r["knob"]
    md = (tmp_path / "bench.md").read_text()
    assert "| artefacts |" in md
    for text in ("Machine:", "eps = 0.01", "Reference noise floor", "## Targets at the balanced preset",
                 "| balanced | balanced | full |"):
        assert text in md, text
    w, h = Image.open(tmp_path / "pareto.png").size
    assert w > 100 and h > 100


def test_a_setting_the_renderer_refuses_is_reported_under_its_scene(tmp_path):
    # The sweep goes on past a setting whose maps the driver cannot hold (run.bench_scene); the report
    # names it, with the renderer's reason, under the scene that refused it.
    from garment_lab.report import write_markdown
    from garment_lab.run import BenchConfig

    rows = [_row("balanced", "balanced", 90.0, 0.05, scene="a"), _row("balanced", "balanced", 95.0, 0.06, scene="b")]
    why = "35 shadow maps of 2048^2 (2240 MiB of moments in one texture array) are more than this GL driver allocates"
    write_markdown(tmp_path / "bench.md", rows, {"cpu": "x", "gl_renderer": "gl", "gl_version": "4.5", "date": "d"},
                   BenchConfig(), [{"scene": "b", "knob": "lights", "value": 384, "mode": "full", "why": why}])
    md = (tmp_path / "bench.md").read_text()
    section_b = md[md.index("## b (env)"):]
    assert f"- lights = 384 [full]: {why}" in section_b and "Not run" not in md[:md.index("## b (env)")]


def test_a_preset_over_its_frame_budget_is_a_missed_row():
    from garment_lab.catalogue import TARGETS
    from garment_lab.speed import budget_rows, markdown

    def row(ms):
        return {"median_ms": ms, "p10_ms": ms, "p90_ms": ms}

    result = {"size": 256, "large": False, "scenes": {
        "a": {"balanced": row(90.0), "fast": row(35.0), "accurate": row(500.0)},
        "b": {"balanced": row(130.0), "fast": row(30.0), "accurate": row(450.0)},
        "c": {"balanced": row(120.0), "fast": row(45.0), "accurate": row(300.0)}}}
    got = {b["preset"]: b for b in budget_rows(result)}
    assert got["balanced"]["budget_ms"] == TARGETS["balanced"]["frame_ms"] == 100.0
    assert not got["balanced"]["met"] and got["balanced"]["median_ms"] == 120.0 and got["balanced"]["over"] == ["b", "c"]
    assert got["fast"]["met"] and got["fast"]["over"] == ["c"]
    assert not got["accurate"]["met"] and got["accurate"]["over"] == ["a", "b"]
    text = markdown(result)
    assert "| balanced | 100 ms | 120 ms | MISSED by 20 ms (1.20x) | b, c |" in text
    assert "| fast | 40 ms | 35 ms | met | c |" in text
    # Another size is judged by no budget here.
    assert budget_rows({**result, "size": 512}) == []


def test_the_one_shot_targets_are_rows_met_or_missed():
    from garment_lab.one_shot import CACHED_TARGET_S, NEW_MAP_TARGET_S, STATES, markdown, targets

    def row(name, new, cached):
        walls = {"first run": [5.0], "new map": [new], "cached": [cached]}
        return {"scene": name, "wall_s": walls, "median_s": {s: v[0] for s, v in walls.items()}}

    rows = [row("x", 2.0, 1.2), row("y", 3.0, 1.6), row("z", 2.4, 1.4)]
    got = {t["state"]: t for t in targets(rows)}
    assert got["cached"]["limit_s"] == CACHED_TARGET_S and got["cached"]["met"] and got["cached"]["scenes_over"] == ["y"]
    assert got["new map"]["limit_s"] == NEW_MAP_TARGET_S and got["new map"]["met"]
    assert got["new map"]["scenes_over"] == ["y"]
    rows.append(row("w", 3.5, 2.0))
    got = {t["state"]: t for t in targets(rows)}
    assert not got["new map"]["met"] and got["new map"]["median_s"] == 2.7
    text = markdown({"machine": {"gl_renderer": "llvmpipe", "cores": 2, "date": "2026-12-03"}, "rounds": 1,
                     "size": 256, "preset": "balanced", "rows": rows, "targets": targets(rows)})
    assert "MISSED by 0.20 s" in text and all(s in text for s in STATES)
