"""The trade curve of a stored broad run (lab/garment_lab/curve.py): a point per setting, the tracer's
points from the run's model, and which settings are on the lower envelope of both methods."""

import json
from pathlib import Path

import numpy as np
import pytest

from garment_lab import curve
from garment_lab.broad import BroadRow

ROOT = Path(__file__).resolve().parents[1]


def _row(scene, preset, ms, err, floor=0.03, rate=50.0):
    return BroadRow(scene, "m.hdr", "held-out", "shirt", "sheen", "front", 256, preset, ms, err, 0.1, 0.0, 1.0, 0, 0,
                    1.0, 0.0, floor, 0.02, 1024, rate, None).__dict__


def _run(rows, cores=2, setup=100.0):
    scenes = sorted({r["scene"] for r in rows})
    return {"machine": {"gl_renderer": "llvmpipe (x)", "cores": cores, "date": "d1"}, "rows": rows,
            "retimed": {"cores": cores, "machine": {"gl_renderer": "llvmpipe (x)", "date": "d2"},
                        "tracer": {s: {"setup_ms": setup, "ms_per_spp": 50.0} for s in scenes}}}


def test_the_tracer_points_follow_the_runs_model_and_the_envelope_is_judged_against_both():
    rows = [_row(s, "fast", 50.0, 0.30) for s in "ab"] + [_row(s, "balanced", 100.0, 0.10) for s in "ab"]
    rows += [_row(s, "slow", 200.0, 0.12) for s in "ab"]              # slower and worse than balanced
    rows += [_row(s, "beaten", 5000.0, 0.05) for s in "ab"]           # the tracer is there sooner
    c = curve.trade_curve(_run(rows))
    t = {p["spp"]: p for p in c["tracer"]}
    # One render of N samples: floor / sqrt(2) x sqrt(1024 / N); its time: setup + N x rate / cores.
    assert t[64]["rel_rmse_median"] == pytest.approx(0.03 / np.sqrt(2) * 4)
    assert t[64]["time_ms_median"] == pytest.approx(100.0 + 64 * 50.0 / 2)
    p = {q["setting"]: q for q in c["points"]}
    assert p["balanced"]["on_envelope"] and p["fast"]["on_envelope"]
    assert p["slow"]["dominated_by"] == ["balanced"] and p["beaten"]["dominated_by"] == ["tracer"]
    # The tracer's time at balanced's error, interpolated in log-log between its points.
    # (about 46 samples: 1024 x (0.03 / sqrt(2) / 0.10)^2)
    assert 100.0 + 32 * 25.0 < p["balanced"]["tracer_ms_at_its_error"] < 100.0 + 64 * 25.0
    assert p["balanced"]["x_tracer"] == pytest.approx(p["balanced"]["tracer_ms_at_its_error"] / 100.0)
    # fast (50 ms at 0.30) leads the tracer, whose 4 samples take 150 ms for 0.34.
    assert p["fast"]["x_tracer"] > 150.0 / 50.0
    text = curve.markdown(c, "run.json")
    assert "| balanced | 100 (100) | 0.100 (0.100) |" in text and "no: tracer" in text
    with pytest.raises(ValueError, match="no tuning rows"):
        curve.trade_curve(_run(rows), which="tuning")


def _rounded(value):
    """`value` with every float to 12 significant digits, in nested lists and dicts."""
    if isinstance(value, float):
        return float(f"{value:.12g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


@pytest.mark.parametrize("size", [256, 512])
def test_the_stored_curve_is_what_its_run_makes(size):
    stem, run = curve.curve_stem(size), f"docs/broad/broad-{size}.json"
    assert stem == ("trade_curve" if size == 256 else f"trade_curve-{size}")
    stored = json.loads((ROOT / "docs" / "broad" / f"{stem}.json").read_text())
    made = curve.trade_curve(json.loads((ROOT / run).read_text()), size)
    # Equal to the last bits another numpy or BLAS build sums in its own order (measured: 2e-16 relative).
    assert _rounded(stored) == _rounded(json.loads(json.dumps(made)))
    assert (ROOT / "docs" / "broad" / f"{stem}.md").read_text() == curve.markdown(made, run)


def test_a_retime_of_a_run_with_settings_this_code_lacks_is_refused(tmp_path):
    from garment_lab import broad

    run = _run([_row("shirt/sheen/front/m@256", "balanced:gone=1", 100.0, 0.1)])
    (tmp_path / "run.json").write_text(json.dumps(run))
    with pytest.raises(ValueError, match=r"balanced:gone=1.*run the benchmark again"):
        broad.retime(tmp_path / "run.json", tmp_path / "out" / "broad.json")
