"""The broad benchmark (`garment-render bench --broad`): its fixed split, its scenes, the reference
cache and its report."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import HDRI, needs_assets

from garment_lab import broad, catalogue
from garment_lab.catalogue import MAPS, Scene, fit_body_inside, scenes, split
from garment_lab.scenes import TARGET_PROBES
from renderer import presets as presets_mod
from renderer.presets import PRESET_NAMES


def test_the_split_is_a_rule_not_a_choice():
    sets = split()
    assert set(sets) == set(MAPS) and len(MAPS) == 18
    # The maps the presets were tuned on before the benchmark existed are never held out.
    assert all(sets[m] == "tuning" for m in TARGET_PROBES.values())
    assert sum(v == "tuning" for v in sets.values()) == 8 and sum(v == "held-out" for v in sets.values()) == 10
    assert split(tuple(reversed(MAPS))) == sets          # the order the maps are listed in does not matter


@needs_assets
def test_every_shared_map_is_in_the_benchmark():
    on_disk = {p.name for p in HDRI.iterdir() if p.suffix in (".hdr", ".exr")}
    assert on_disk == set(MAPS)


def test_the_sweep_covers_every_map_garment_fabric_and_view():
    full = scenes()
    small = [s for s in full if s.size == 128]
    assert len(small) == len(MAPS) * 3 * 3 * 2 and len({(s.map, s.garment, s.fabric, s.view) for s in small}) == len(small)
    large = [s for s in full if s.size == 256]
    assert len(large) == len(MAPS) * 3 and {s.map for s in large} == set(MAPS)
    quick = scenes(quick=True)
    assert {split()[s.map] for s in quick} == {"tuning", "held-out"} and len(quick) == 8
    # The bench adds the held-out 256 x 256 scenes at 512 x 512, the same scenes but for their size.
    bench = broad.bench_scenes()
    largest = [s for s in bench if s.size == broad.LARGEST]
    assert bench[:len(full)] == full and len(bench) == len(full) + len(largest)
    assert {dataclasses.replace(s, size=256) for s in largest} == {s for s in large if split()[s.map] == "held-out"}
    assert len(largest) == sum(v == "held-out" for v in split().values()) * 3 and broad.bench_scenes(quick=True) == quick


def _cylinder(radius: float, y0: float, y1: float, n: int = 64) -> np.ndarray:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ys = np.linspace(y0, y1, 40)
    return np.array([[radius * np.cos(t), y, radius * np.sin(t)] for y in ys for t in a], np.float32)


def test_a_body_is_pulled_inside_its_garment_and_left_alone_elsewhere():
    garment = _cylinder(0.20, 1.0, 1.5)
    body = np.concatenate([_cylinder(0.25, 0.5, 1.8) + np.float32([0.03, 0.0, 0.0]),
                           np.float32([[0.55, 1.2, 0.0]])])   # an arm's vertex far out beside the garment
    fitted = fit_body_inside(body, garment, margin=0.01)
    within = (body[:, 1] >= 1.0) & (body[:, 1] <= 1.5)
    radius = np.hypot(fitted[:, 0], fitted[:, 2])
    assert radius[within][:-1].max() <= 0.19 + 1e-5          # inside the cloth, the margin behind it
    # Above and below the garment the body is only shifted across, centred as the garment is.
    shift = fitted[~within] - body[~within]
    assert np.allclose(shift[:, 1], 0.0) and np.allclose(shift, shift[0], atol=1e-6)
    assert shift[0, 0] == pytest.approx(-0.03, abs=1e-3)
    assert np.allclose(fitted[-1], body[-1] + shift[0])        # beyond reach: an arm, not the torso


@needs_assets
def test_the_shared_bodies_sit_inside_their_garments():
    for garment in ("polo", "dress"):
        cloth, body = catalogue.garment_meshes(garment)
        g, b = cloth.positions, body.positions
        lo, hi = g[:, 1].min(), g[:, 1].max()
        inside = (b[:, 1] > lo) & (b[:, 1] < hi)
        # The body's widest point inside the garment's height is inside the garment's widest.
        assert np.abs(b[inside][:, 2] - g[:, 2].mean()).max() < np.abs(g[:, 2] - g[:, 2].mean()).max(), garment


def test_references_are_cached_by_scene_samples_seed_pixel_samples_and_code(tmp_path, monkeypatch):
    monkeypatch.setattr(broad, "reference_inputs_digest", lambda scene: f"inputs of {scene}")
    cache = broad.ReferenceCache(tmp_path, pixel_samples=4)
    a, b = Scene("pisa.hdr", "shirt", "satin", "front", 128), Scene("pisa.hdr", "shirt", "satin", "front", 256)
    keys = {cache.key(a, 64, 1), cache.key(a, 64, 2), cache.key(a, 128, 1), cache.key(b, 64, 1),
            broad.ReferenceCache(tmp_path, pixel_samples=1).key(a, 64, 1)}
    assert len(keys) == 5
    assert cache.get(a, 64, 1) is None
    rng = np.random.default_rng(0)
    ref = {"image": rng.random((8, 8, 4)).astype(np.float32), "foreground": rng.random((8, 8, 4)).astype(np.float32),
           "edge": rng.random((8, 8)) > 0.5, "spp": 64}
    cache.put(a, 64, 1, ref, 1.5)
    got = cache.get(a, 64, 1)
    assert all(np.array_equal(got[k], ref[k]) for k in ref) and got["wall_s"] == 1.5 and got["edge"].dtype == bool
    # References of other strata are others: one point sample a pixel does not stand for sixteen.
    assert broad.ReferenceCache(tmp_path, pixel_samples=1).get(a, 64, 1) is None
    # Other reference code: another key, the old entry is not found.
    cache.code = "other code"
    assert cache.get(a, 64, 1) is None
    cache.code = broad.reference_code_digest()
    # A damaged file is rendered again, never trusted.
    cache.path(a, 64, 1).write_bytes(b"not an npz")
    assert cache.get(a, 64, 1) is None


def test_the_reference_code_digest_follows_the_files_that_make_a_reference():
    from pathlib import Path

    import renderer

    product, lab = Path(renderer.__file__).resolve().parent, Path(broad.__file__).resolve().parent
    places = broad._REFERENCE_SOURCES.values()
    covered = {p for place in places for p in (place.rglob("*.py") if place.is_dir() else [place])}
    assert product / "reference" / "montecarlo.py" in covered and lab / "catalogue.py" in covered
    assert lab / "broad.py" not in covered     # the report may change without rendering anew
    assert product / "shading" / "brdf.py" in covered and product / "envmap" / "cube.py" in covered
    # What the environment and mesh code make enters as data (below): they may get faster.
    assert product / "envmap" / "layouts.py" not in covered and product / "mesh.py" not in covered


def test_the_digest_names_a_source_not_its_place(tmp_path, monkeypatch):
    """A source moved and given its old name keeps the digest; a source given another name, or
    another content, changes it."""
    import shutil

    before = broad.reference_code_digest()
    moved = tmp_path / "lab_catalogue.py"
    shutil.copy(broad._REFERENCE_SOURCES["bench/catalogue.py"], moved)
    sources = {**broad._REFERENCE_SOURCES, "bench/catalogue.py": moved}
    monkeypatch.setattr(broad, "_REFERENCE_SOURCES", sources)
    assert broad.reference_code_digest() == before
    moved.write_text(moved.read_text() + "\n# changed\n")
    assert broad.reference_code_digest() != before
    renamed = {("bench/other.py" if name == "bench/scenes.py" else name): place
               for name, place in {**sources, "bench/catalogue.py": broad._LAB / "catalogue.py"}.items()}
    monkeypatch.setattr(broad, "_REFERENCE_SOURCES", renamed)   # the same files, one under another name
    assert broad.reference_code_digest() != before


@needs_assets
def test_a_move_of_the_references_code_renames_the_cached_references(tmp_path):
    """ReferenceCache.rekey (scripts/fill_reference_cache.py --rekey-from): an entry made under an
    earlier code digest is found again under today's, once; one today's code has is left alone."""
    cache = broad.ReferenceCache(tmp_path, pixel_samples=4)
    scene = catalogue.scenes(quick=True)[0]
    spp_of = broad.BroadConfig().spp_of
    ref = {"image": np.ones((2, 2, 3), np.float32), "foreground": np.ones((2, 2, 4), np.float32),
           "edge": np.zeros((2, 2), bool), "spp": 8}
    old = "0" * 64
    for seed in broad.SEEDS:
        (tmp_path / f"{cache.key(scene, spp_of(scene), seed, old)}.npz").write_bytes(b"x")
    cache.put(scene, spp_of(scene), broad.SEEDS[0], ref, 1.0)   # today's code has this one already
    assert cache.get(scene, spp_of(scene), broad.SEEDS[1]) is None
    assert cache.rekey([scene], spp_of, old) == 1
    assert cache.path(scene, spp_of(scene), broad.SEEDS[1]).read_bytes() == b"x"
    assert cache.get(scene, spp_of(scene), broad.SEEDS[0])["spp"] == 8   # kept, not overwritten
    assert cache.rekey([scene], spp_of, old) == 0


@needs_assets
def test_the_cube_the_key_reads_is_the_cube_the_tracer_renders(tmp_path, monkeypatch):
    monkeypatch.setenv("GARMENT_RENDER_CACHE_DIR", str(tmp_path))
    name = catalogue.MAPS[0]
    first = broad._reference_cube(name)       # made, and kept in the cache folder
    again = broad._reference_cube(name)       # read back
    assert np.array_equal(first, catalogue.environment_cube(name, catalogue.REFERENCE_FACE_SIZE))
    assert np.array_equal(again, first)


def test_a_references_inputs_are_keyed_by_what_the_tracer_reads(monkeypatch):
    from renderer.mesh import Mesh

    cube = np.ones((6, 4, 4, 3), np.float32)
    tri = Mesh.from_arrays(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
    meshes = {"shirt": (tri, tri)}
    monkeypatch.setattr(broad, "_reference_cube", lambda name: cube)
    monkeypatch.setattr(broad, "garment_meshes", lambda garment: meshes[garment])
    monkeypatch.setattr(catalogue, "garment_meshes", lambda garment: meshes[garment])

    def digest(scene):
        broad._cube_digest.cache_clear()
        broad._garment_digest.cache_clear()
        return broad.reference_inputs_digest(scene)

    scene = Scene("pisa.hdr", "shirt", "satin", "front", 128)
    first = digest(scene)
    assert digest(scene) == first
    assert digest(Scene("pisa.hdr", "shirt", "cotton", "front", 128)) != first      # the material
    assert digest(Scene("pisa.hdr", "shirt", "satin", "front", 256)) != first       # the size
    cube = cube.copy()
    cube[2, 1, 1] = 2.0                                                              # one texel of the cube
    assert digest(scene) != first
    cube[2, 1, 1] = 1.0
    assert digest(scene) == first
    moved = Mesh.from_arrays(tri.positions * 2, tri.faces)      # the body's shape (the camera frames the garment)
    meshes["shirt"] = (tri, moved)
    assert digest(scene) != first
    monkeypatch.setattr(broad, "FALLBACK_NORMAL", (0.0, 0.0, 1.0))   # the tracer's normal for degenerate points
    meshes["shirt"] = (tri, tri)
    assert digest(scene) != first


def _row(scene, preset, size=256, **metrics):
    values = {"rel_rmse": 0.01, "flip": 0.01, "artefact_share": 0.0, "frame_ms": 10.0, "equal_error_speedup": 100.0,
              **metrics}
    return broad.BroadRow(scene, "m", "held-out", "shirt", "satin", "front", size, preset, values["frame_ms"],
                          values["rel_rmse"], values["flip"], values["artefact_share"], 1.0, 0, 0, 1.0, 0.1, 0.02,
                          0.01, 64, 1.0, values["equal_error_speedup"])


def test_misses_name_the_scene_the_target_and_the_factor():
    rows = [_row("a", "balanced", rel_rmse=0.1), _row("b", "balanced", artefact_share=0.01),
            _row("c", "fast", frame_ms=80.0, equal_error_speedup=5.0), _row("d", "balanced", size=128, rel_rmse=1.0),
            _row("e", "accurate"), _row("f", "paper", rel_rmse=1.0),
            _row("g", "accurate", frame_ms=800.0, equal_error_speedup=4.0), _row("h", "accurate", equal_error_speedup=1.5)]
    misses = {(m["scene"], m["metric"]): m["factor"] for m in broad.target_misses(rows)}
    # Budgets (fast 40 ms, accurate 400 ms) are targets like the errors; accurate's equal-error one is 3x.
    assert misses == {("a", "rel_rmse"): pytest.approx(2.0), ("b", "artefact_share"): pytest.approx(2.0),
                      ("c", "frame_ms"): pytest.approx(2.0), ("c", "equal_error_speedup"): pytest.approx(2.0),
                      ("g", "frame_ms"): pytest.approx(2.0), ("h", "equal_error_speedup"): pytest.approx(2.0)}


def test_at_512_only_the_equal_error_targets_are_judged_and_every_size_reports_its_own():
    rows = [_row("x@512", "fast", 512, frame_ms=200.0, rel_rmse=0.5, equal_error_speedup=5.0),
            _row("y@512", "balanced", 512, frame_ms=400.0), _row("z@256", "fast", frame_ms=80.0)]
    misses = broad.all_misses(rows)
    assert {(m["scene"], m["size"], m["metric"]) for m in misses} == {("x@512", 512, "equal_error_speedup"),
                                                                       ("z@256", 256, "frame_ms")}
    lines = "\n".join(broad._target_lines([dataclasses.asdict(r) for r in rows], misses))
    assert "## Targets on the held-out set at 256 x 256" in lines and "## Targets on the held-out set at 512 x 512" in lines
    assert "- **balanced** (equal error >= 10x): met on all 1 scenes." in lines
    assert "- **fast** (equal error >= 10x): equal_error_speedup missed on 1 of 1 scenes" in lines
    # A miss is counted at its own row's size, whatever the scene is called.
    renamed = [{**m, "scene": "renamed"} for m in misses]
    assert "\n".join(broad._target_lines([dataclasses.asdict(r) for r in rows], renamed)) == lines.replace(
        "x@512)", "renamed)").replace("z@256)", "renamed)")
    # The knob table takes every size of the run (512 x 512 as 256 x 256).
    knobs = [dataclasses.asdict(_row("y@512", "balanced:lights=48", 512, frame_ms=800.0))] + \
        [dataclasses.asdict(rows[1])]
    assert [(t["knob"], t["size"], t["time_ratio"]) for t in broad.knob_table(knobs)] == [("balanced:lights=48", 512, 2.0)]


def test_the_excess_takes_the_truths_own_noise_out_in_quadrature():
    # The truth (the mean of the pair) is off by half the floor: an error e beyond it is measured as
    # sqrt(e^2 + (floor / 2)^2).
    for e, floor in ((0.08, 0.06), (0.2, 0.03), (0.01, 0.12)):
        assert broad.excess_rel_rmse(float(np.hypot(e, floor / 2)), floor) == pytest.approx(e)
    assert broad.excess_rel_rmse(0.02, 0.06) == 0.0   # within the truth's own noise


def _report(rows, config) -> str:
    data = {"machine": {"gl_renderer": "gl", "gl_version": "4.5", "cores": 2, "date": "today"}, "config": config,
            "presets": "p", "split": split(), "reference_s": 1.0, "summary": broad.summary(rows),
            "misses": broad.all_misses(rows), "rows": [dataclasses.asdict(r) for r in rows]}
    return broad.markdown(json.loads(json.dumps(data, default=float)))


def test_the_report_has_the_edge_columns_only_where_the_run_measured_them():
    old = [_row("a", "balanced", rel_rmse=0.08), _row("b", "balanced", rel_rmse=0.1), _row("a", "fast")]
    config = dataclasses.asdict(broad.BroadConfig())
    before = {k: v for k, v in config.items() if k != "pixel_samples"}
    text = _report(old, before)
    assert "silhouette" not in text and "windows" not in text and "strata" not in text
    new = [dataclasses.replace(r, silhouette_rel_rmse=sil, coverage_rmse=0.5 * sil, window_share=win)
           for r, sil, win in zip(old, (0.2, 0.4, 0.3), (0.01, 0.05, float("nan")))]
    summary = broad.summary(new)
    held = summary["held-out/256/balanced"]
    assert held["silhouette_rel_rmse_median"] == pytest.approx(0.3) and held["window_share_max"] == pytest.approx(0.05)
    assert np.isnan(summary["held-out/256/fast"]["window_share_max"])   # no judged window: no number
    text = _report(new, config)
    assert "each pixel over 4 x 4 strata" in text and "Silhouette: rel. RMSE of the frame over black" in text
    assert "| 0.300 (0.150) | 3.00 % / 5.00 % |" in text            # balanced's medians and worst window share
    assert "| a | held-out | balanced | 0.080 | 0.010 | 0.00 % | 0 / 0 | 0.200 (0.100) | 1.00 % |" in text
    # Every table row has its header's cells.
    for table in ("## Summary", "## Every preset's row"):
        block = text.split(table)[1].split("\n\n")[1].splitlines()
        assert len({line.count("|") for line in block}) == 1, table


@pytest.mark.system
@needs_assets
def test_the_broad_bench_end_to_end_on_two_small_scenes(tmp_path, monkeypatch):
    # The presets made small (their faces, maps and light counts; the knob variants over them as they
    # are): what is under test is the benchmark's plumbing, not the presets' values.
    import renderer.presets as presets_mod

    real = presets_mod.presets

    def small_presets():
        table, source = real()
        return {name: {**k, "face_size": min(k["face_size"], 32), "shadow_size": min(k["shadow_size"], 64),
                       "lights": min(k["lights"], 24)} for name, k in table.items()}, source

    monkeypatch.setattr(presets_mod, "presets", small_presets)
    sets = split()
    assert (sets["ennis.hdr"], sets["pisa.hdr"]) == ("tuning", "held-out")
    only = [Scene("ennis.hdr", "shirt", "cotton", "three-quarter", 32), Scene("pisa.hdr", "polo", "satin", "front", 32)]
    cfg = broad.BroadConfig(frames=1, frames_small=1, spp_small=8, spp_large=8, workers=1, cache=str(tmp_path / "refs"))
    assert cfg.pixel_samples == 4
    rows = broad.run_broad(tmp_path / "out", cfg, log=lambda *_: None, only=only)
    # The held-out satin scene also runs each knob variant (KNOB_SMALL_FABRIC).
    assert len(rows) == 2 * len(PRESET_NAMES) + len(broad.KNOB_VARIANTS)
    # Every preset, the paper's among them; the targets are the other three's.
    assert {r.preset for r in rows if ":" not in r.preset} == set(PRESET_NAMES) == set(catalogue.PRESETS) | {"paper"}
    assert {r.preset for r in rows if ":" in r.preset} == set(broad.KNOB_VARIANTS)
    assert all(r.scene == only[1].name for r in rows if ":" in r.preset)
    rows = [r for r in rows if ":" not in r.preset]
    for r in rows:
        assert np.isfinite([r.rel_rmse, r.flip, r.artefact_share, r.background_rel_rmse, r.ref_noise_rel_rmse]).all()
        assert 0.5 < r.mean_ratio < 2.0 and r.frame_ms > 0
        # The edges: each setting's frame over black against the references' foreground at their edge
        # pixels, and the 5 x 5 windows; 8 samples a pixel over 4 x 4 strata take 8 a stratum (one a batch).
        assert r.extra["edge_pixels"] > 0 and r.ref_spp == 16 * 8
        assert np.isfinite([r.silhouette_rel_rmse, r.coverage_rmse]).all() and r.silhouette_rel_rmse > 0
        assert r.silhouette_rel_rmse <= r.extra["silhouette_measured"] and 0 <= r.coverage_rmse <= 1
        assert r.window_share is None or np.isnan(r.window_share) or 0 <= r.window_share <= 1
    # Each row's error is its excess over the truth's own noise (half the pair's floor), the error
    # against the pair's mean kept beside it.
    for r in rows:
        measured = r.extra["rel_rmse_measured"]
        assert r.rel_rmse == pytest.approx(np.sqrt(max(measured ** 2 - 0.25 * r.ref_noise_rel_rmse ** 2, 0.0)))
        assert r.rel_rmse <= measured
    data = json.loads((tmp_path / "out" / "broad.json").read_text())
    assert {s["set"] for s in data["summary"].values()} == {"tuning", "held-out"}
    assert all(np.isfinite(s["silhouette_rel_rmse_median"]) and "window_share_max" in s
               for s in data["summary"].values())
    assert data["config"]["pixel_samples"] == 4
    # The tracer's rate is measured beside the presets' frames, scene by scene: not the references'
    # own times (rendered before, perhaps on another day).
    cache = broad.ReferenceCache(tmp_path / "refs", pixel_samples=cfg.pixel_samples)
    for r in rows:
        rate = data["tracer"][r.scene]
        assert r.ref_ms_per_spp == rate["ms_per_spp"] > 0 and rate["setup_ms"] >= 0
        own = 1e3 * np.mean([cache.get(s, 8, seed)["wall_s"] for s in only if s.name == r.scene
                             for seed in broad.SEEDS]) / 8
        assert r.ref_ms_per_spp != pytest.approx(own, rel=1e-9)
    # The held-out set ran first, whole, from the cold cache: its wall time is the run's own.
    assert data["rows"][0]["set"] == "held-out"
    timed = data["sets_timed"]
    assert list(timed["wall_s"]) == ["held-out", "tuning"] and all(t > 0 for t in timed["wall_s"].values())
    assert timed["references"] == {"held-out": {"rendered": 2, "in_all": 2}, "tuning": {"rendered": 2, "in_all": 2}}
    text = (tmp_path / "out" / "broad.md").read_text()
    assert "Held-out maps:" in text and "No held-out scene at 256 x 256" in text
    assert "| silhouette rel. RMSE (coverage) | 5 x 5 windows off 1.5x |" in text and "over 4 x 4 strata" in text
    assert "Wall time of each set, its references included: held-out " in text and "rendering 2 of its 2" in text
    # A second run renders no reference: every one is in the cache.
    assert len(list((tmp_path / "refs").glob("*.npz"))) == 4
    logged = []
    broad.ensure_references(only, cfg.spp_of, broad.ReferenceCache(tmp_path / "refs", pixel_samples=4), 1,
                            log=logged.append)
    assert logged == []   # what run_broad asks first: nothing to render
    # Retimed on this machine: every row's time measured again, the tracer's rate beside it, the errors
    # kept, and the speed-up at equal error the tracer's time on every core over the frame's.
    again = broad.retime(tmp_path / "out" / "broad.json", tmp_path / "retimed" / "broad.json", frames=1,
                         log=lambda *_: None)
    assert (tmp_path / "retimed" / "broad.md").read_text() == broad.markdown(again)
    before = {(r["scene"], r["preset"]): r for r in data["rows"]}
    cores = again["retimed"]["cores"]
    for r in again["rows"]:
        old = before[(r["scene"], r["preset"])]
        assert (r["rel_rmse"], r["artefact_share"], r["ref_spp"]) == (old["rel_rmse"], old["artefact_share"], old["ref_spp"])
        assert (r["silhouette_rel_rmse"], r["window_share"]) == (old["silhouette_rel_rmse"], old["window_share"])
        rate = again["retimed"]["tracer"][r["scene"]]
        assert r["frame_ms"] > 0 and r["ref_ms_per_spp"] == rate["ms_per_spp"] > 0
        if r["equal_error_speedup"] is not None:
            spp = max(1.0, r["ref_spp"] * (r["ref_noise_rel_rmse"] / np.sqrt(2.0) / r["rel_rmse"]) ** 2)
            assert r["equal_error_speedup"] == pytest.approx(
                (rate["setup_ms"] + spp * rate["ms_per_spp"] / cores) / r["frame_ms"])


def test_the_knob_table_sets_each_variant_against_its_preset_on_the_same_scenes():
    rows = [dataclasses.asdict(r) for r in (
        _row("a", "balanced", rel_rmse=0.10, frame_ms=100.0), _row("b", "balanced", rel_rmse=0.20, frame_ms=100.0),
        _row("a", "balanced:lights=48", rel_rmse=0.08, frame_ms=200.0),
        _row("b", "balanced:lights=48", rel_rmse=0.22, frame_ms=180.0),
        _row("a", "balanced:sub_lights=1", size=128, rel_rmse=0.5))]   # no balanced row at 128: none
    (t,) = broad.knob_table(rows)
    assert (t["knob"], t["size"], t["set"], t["scenes"], t["better"]) == ("balanced:lights=48", 256, "held-out", 2, 1)
    assert t["d_rel_rmse"] == pytest.approx(0.0) and t["time_ratio"] == pytest.approx(1.9)
    # Variants are rows of their own, never counted as presets.
    assert {m["preset"] for m in broad.target_misses([broad.BroadRow(**r) for r in rows])} == {"balanced"}
    assert "| balanced:lights=48 | 256 | held-out | 2 |" in "\n".join(broad.knob_lines(rows))
    # The 128 x 128 satin scenes' variants make rows of their own size.
    small = rows + [dataclasses.asdict(_row("a", "balanced", size=128, rel_rmse=0.3))]
    assert [(t["knob"], t["size"], t["scenes"]) for t in broad.knob_table(small)] == [
        ("balanced:lights=48", 256, 2), ("balanced:sub_lights=1", 128, 1)]
    # A variant of fast is set against fast on the same scene, not against balanced.
    with_fast = rows + [dataclasses.asdict(r) for r in (
        _row("a", "fast", rel_rmse=0.18, frame_ms=40.0), _row("a", "fast:lights=24", rel_rmse=0.15, frame_ms=46.0))]
    t = next(t for t in broad.knob_table(with_fast) if t["knob"] == "fast:lights=24")
    assert (t["scenes"], t["better"]) == (1, 1)
    assert t["d_rel_rmse"] == pytest.approx(-0.03) and t["time_ratio"] == pytest.approx(1.15)
    # Every variant names a preset and is that preset's knobs with its own values over them.
    knobs = broad.setting_knobs(presets_mod.presets()[0])
    for name, over in broad.KNOB_VARIANTS.items():
        assert broad.knob_base(name) in broad.PRESETS
        assert knobs[name] == {**knobs[broad.knob_base(name)], **over} != knobs[broad.knob_base(name)]
        # Its name says its values: "preset:knob=value,...", a switch "on" or "off".
        named = dict(part.split("=") for part in name.split(":", 1)[1].split(","))
        assert named == {k: _shown(v) for k, v in over.items()}


def _shown(value) -> str:
    """A knob's value as a variant's name writes it: a switch "on" or "off", a word as it is, a number by %g."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return value if isinstance(value, str) else f"{value:g}"
