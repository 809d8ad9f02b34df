"""The preset files hold values and one line of reason each (issue 63); the measurements that chose
them are docs/presets.md, generated from the files and the stored broad run."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from garment_lab.preset_report import STORED, reasons, report
from renderer.preset_files import PRESET_DIR

ROOT = Path(__file__).resolve().parents[1]
# A measurement: a decimal, a percentage, a ratio, a size in pixels or texels squared.
MEASUREMENT = re.compile(r"\d+\.\d+|\d+ ?%|\d+(\.\d+)?x\b|\d+\^2|[+-]\d")


def test_the_report_is_made_from_the_files_and_the_stored_run():
    stored = json.loads(STORED.read_text())
    assert (ROOT / "docs" / "presets.md").read_text() == report(stored), \
        "docs/presets.md is stale: python -m garment_lab.preset_report"


def _faults(folder: Path) -> list[str]:
    import tomllib

    out = []
    for path in sorted(folder.glob("*.toml")):
        settings = tomllib.loads(path.read_text())["settings"]
        why = reasons(path)
        for key in settings:
            if len(why.get(key, [])) != 1:
                out.append(f"{path.name}: {key} has {len(why.get(key, []))} lines of reason (one, right above it)")
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if "#" in line and MEASUREMENT.search(line.split("#", 1)[1]):
                out.append(f"{path.name}:{n}: a measurement in a comment (docs/presets.md holds them)")
    return out


def test_each_setting_has_one_line_of_reason_and_no_measurement():
    assert _faults(PRESET_DIR) == []


def test_the_check_finds_a_measurement_and_a_missing_reason(tmp_path):
    for path in PRESET_DIR.glob("*.toml"):
        shutil.copy(path, tmp_path / path.name)
    p = tmp_path / "balanced.toml"
    text = p.read_text().replace("# where more lights start to buy less than they cost, within the budget\n",
                                 "# 48 lights cost 0.88x the frame\n")
    text = text.replace("# the PEMs' face: finer than the lobes the fabrics read need no more\n", "")
    p.write_text(text)
    faults = _faults(tmp_path)
    assert any("balanced.toml" in f and "measurement" in f for f in faults)
    assert any("face_size has 0 lines" in f for f in faults)


@pytest.mark.parametrize("name", ["fast", "balanced", "accurate", "paper"])
def test_every_setting_of_a_preset_is_in_its_section(name):
    section = (ROOT / "docs" / "presets.md").read_text().split(f"## {name}\n", 1)[1].split("\n## ", 1)[0]
    import tomllib

    for key in tomllib.loads((PRESET_DIR / f"{name}.toml").read_text())["settings"]:
        assert f"| `{key}` |" in section
