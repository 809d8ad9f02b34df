"""Stored benchmark runs cannot go stale unnoticed: each records the preset files' digest
(renderer.presets.presets_digest), and a run whose presets are no longer the files' fails here until
it is made again (the command that made it is in its report)."""

import json
import re
import shutil
from pathlib import Path

from renderer.presets import presets_digest

ROOT = Path(__file__).resolve().parents[1]
# The runs the README and docs read their current numbers from.
CURRENT = ("docs/error-split/error_split.json", "docs/one-shot/one_shot.json", "docs/broad/broad-256.json",
           "docs/broad/broad-512.json", "docs/energy/energy.json", "docs/materials-bench.json", "docs/sweep.json",
           "docs/views-bench.json", "docs/scale-out.json", "docs/area-bench.json",
           "docs/shadow-maps-bench.json")


def _stamped() -> dict[str, str]:
    out = {}
    for path in sorted((ROOT / "docs").rglob("*.json")):
        data = json.loads(path.read_text())
        if isinstance(data, dict) and "presets_digest" in data:
            out[str(path.relative_to(ROOT))] = data["presets_digest"]
    return out


def test_every_stamped_run_was_made_with_the_preset_files_of_today():
    stamped = _stamped()
    assert set(CURRENT) <= set(stamped)
    now = presets_digest()
    assert {p: d for p, d in stamped.items() if d != now} == {}


def test_the_script_that_makes_them_again_names_every_one():
    """scripts/stored-runs.sh makes every stamped run again (a preset change stales them all): it names
    each one's file, and refuses a run it does not know before it sets anything up."""
    import subprocess

    script = ROOT / "scripts" / "stored-runs.sh"
    text = script.read_text()
    # The file itself, or the folder a command writes it into.
    assert [p for p in _stamped()
            if p not in text and not re.search(rf"--out {re.escape(Path(p).parent.as_posix())}\s", text)] == []
    done = subprocess.run(["bash", str(script), "broad-1024"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "unknown run 'broad-1024'" in done.stderr and "one-shot" in done.stderr
    assert "broad-256-retime" in done.stderr   # the retimed runs are named too (never run by default)


def test_a_changed_preset_file_changes_the_digest(tmp_path):
    folder = tmp_path / "presets"
    shutil.copytree(ROOT / "renderer" / "presets", folder, ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    assert presets_digest(folder) == presets_digest()
    balanced = folder / "balanced.toml"
    balanced.write_text("# a comment changes no setting\n" + balanced.read_text())
    assert presets_digest(folder) == presets_digest()
    # Whatever the preset's light count, one more is another setting.
    text = balanced.read_text()
    count = int(re.search(r"^lights = (\d+)$", text, re.M).group(1))
    balanced.write_text(re.sub(r"^lights = \d+$", f"lights = {count + 1}", text, count=1, flags=re.M))
    assert presets_digest(folder) != presets_digest()


def test_the_stored_reports_are_what_their_runs_make():
    """Each current report is generated from its stored run: no number in it was typed."""
    from garment_lab import area, broad, one_shot, shadow_maps, split, views
    from service import load

    for run, make in (("docs/error-split/error_split.json", split.markdown),
                      ("docs/one-shot/one_shot.json", one_shot.markdown),
                      (broad.README_RUN, broad.markdown), ("docs/broad/broad-512.json", broad.markdown),
                      ("docs/views-bench.json", views.markdown), ("docs/area-bench.json", area.markdown),
                      ("docs/shadow-maps-bench.json", shadow_maps.markdown)):
        data = json.loads((ROOT / run).read_text())
        assert (ROOT / run).with_suffix(".md").read_text() == make(data), run
    data = json.loads((ROOT / "docs/scale-out.json").read_text())
    assert (ROOT / "docs/scale-out.md").read_text() == load.markdown(data["rows"], data["machine"], data["command"], data["date"])


def test_the_stored_sweep_report_is_what_its_run_makes(tmp_path):
    from garment_lab.report import write_markdown
    from garment_lab.run import BenchConfig, Row

    data = json.loads((ROOT / "docs/sweep.json").read_text())
    cfg = BenchConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in data["config"].items()})
    write_markdown(tmp_path / "bench.md", [Row(**r) for r in data["rows"]], data["machine"], cfg, data["refused"])
    assert (tmp_path / "bench.md").read_text() == (ROOT / "docs/sweep.md").read_text()
