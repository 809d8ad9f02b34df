"""docs/presets.md: each preset's values, the one line of reason its file gives each, and the
measurements that chose them, generated from the preset files and the stored broad run
(docs/broad/broad-256.json): each preset's held-out frame and error against its targets, and the rows
of the run's knob table that change one of its settings (a preset with that knob changed, against the
preset on the same scenes). The preset files hold values and reasons, no numbers; a rerun changes this
report, never them (scripts/stored-runs.sh makes it after the broad run; tests/test_preset_report.py
holds it to its inputs).

    python -m garment_lab.preset_report            # writes docs/presets.md
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from renderer import presets as _presets

from .broad import KNOB_VARIANTS, knob_base, knob_table
from .catalogue import TARGETS

ROOT = Path(__file__).resolve().parents[2]
PRESET_DIR = Path(_presets.__file__).parent   # the preset files' folder
STORED = ROOT / "docs" / "broad" / "broad-256.json"
OUT = ROOT / "docs" / "presets.md"
ORDER = ("paper", "fast", "balanced", "accurate")
SETTING = re.compile(r"^([a-z_]+)\s*=")


def reasons(path: Path) -> dict[str, list[str]]:
    """Each setting of a preset file's [settings] and the comment lines right above it (its reason)."""
    out: dict[str, list[str]] = {}
    comments: list[str] = []
    in_settings = False
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if line.startswith("["):
            in_settings, comments = line == "[settings]", []
        elif line.startswith("#"):
            comments.append(line.lstrip("#").strip())
        elif in_settings and (m := SETTING.match(line)):
            out[m.group(1)], comments = comments, []
        elif not line:
            comments = []
    return out


def _values(path: Path) -> dict:
    import tomllib

    return tomllib.loads(path.read_text())["settings"]


def _show(v) -> str:
    return str(v).lower() if isinstance(v, bool) else f'"{v}"' if isinstance(v, str) else f"{v:g}"


def report(stored: dict, folder: Path = PRESET_DIR, stored_name: str = "docs/broad/broad-256.json") -> str:
    names = [n for n in ORDER if (folder / f"{n}.toml").exists()]
    rows = stored["rows"]
    machine = stored["machine"]
    lines = ["# Presets: their values and what chose them", "",
             f"Made by `python -m garment_lab.preset_report` from the preset files (renderer/presets/) and the "
             f"stored broad run `{stored_name}` (`garment-render bench --broad --size 256` on {machine['gl_renderer']}, "
             f"{machine['cores']} cores, {machine['date']}). The files hold each value and one line of reason; the "
             "measurements are here, made again with the runs.", "",
             "## The presets on the broad benchmark's held-out scenes at 256 x 256", "",
             "| preset | frame: budget, median | rel. RMSE beyond the reference's noise: target, median / worst | "
             "pixels > 2x off, median | scenes |", "|---|---|---|---|---|"]
    for name in names:
        s = stored["summary"].get(f"held-out/256/{name}")
        if s is None:
            continue
        t = TARGETS.get(name, {})
        budget = f"{t['frame_ms']:.0f} ms, " if t.get("frame_ms") else ""
        target = f"{t['rel_rmse']:.2f}, " if t.get("rel_rmse") else ""
        lines.append(f"| {name} | {budget}{s['frame_ms_median']:.1f} ms | {target}{s['rel_rmse_median']:.3f} / "
                     f"{s['rel_rmse_max']:.3f} | {100 * s['artefact_share_median']:.2f} % | {s['scenes']} |")
    table = knob_table(rows)
    for name in names:
        path = folder / f"{name}.toml"
        why, values = reasons(path), _values(path)
        lines += ["", f"## {name}", "", "| setting | value | why | the knob table at 256 x 256: change against the "
                  "preset, tuning / held-out |", "|---|---|---|---|"]
        for key, value in values.items():
            rows_of = [k for k in KNOB_VARIANTS if knob_base(k) == name and key in KNOB_VARIANTS[k]]
            cells = []
            for variant in rows_of:
                parts = {t["set"]: t for t in table if t["knob"] == variant and t["size"] == 256}
                if not parts:
                    continue
                pair = [parts.get(s) for s in ("tuning", "held-out")]
                rel = " / ".join(f"{p['d_rel_rmse']:+.4f}" if p else "-" for p in pair)
                time = " / ".join(f"{p['time_ratio']:.2f}x" if p else "-" for p in pair)
                cells.append(f"`{variant.split(':', 1)[1]}`: rel. RMSE {rel}, frame {time}")
            lines.append(f"| `{key}` | {_show(value)} | {' '.join(why.get(key, []))} | {'; '.join(cells) or '-'} |")
    lines += ["", "The reasons rest on these reports as well, each made from its own stored run: docs/sweep.md (the knob "
              "sweep), docs/area-bench.md (area lights, penumbrae), docs/shadow-maps-bench.md (the maps against the "
              "casters), docs/materials-bench.md and docs/brdf-lobes.md (the lobes), docs/edges-bench.md "
              "(anti-aliasing)."]
    return "\n".join(lines) + "\n"


def main() -> int:
    OUT.write_text(report(json.loads(STORED.read_text())))
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
