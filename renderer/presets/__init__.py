"""Quality presets: versioned files beside this module (fast.toml, balanced.toml, accurate.toml, paper.toml),
each naming every quality setting with the measurement behind it. Used by the command line, the
service and the benchmark alike; the measured table (renderer/bench/measured.json) serves budgets
only, never the presets."""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path

from .. import config
from ..errors import InvalidInputError


def knob_defaults() -> dict:
    """Every quality setting (renderer/config.py) and its default, in the registry's order."""
    return {st.name: st.default for st in config.SETTINGS}


def merge_knobs(base: dict, explicit: dict) -> dict:
    """A preset's or budget's knobs (`base`) over the defaults, with the caller's explicit values
    (None: not given) over both: the one rule the command line, the service and the benchmark share."""
    from ..config import MAX_SHADOW_SIDE

    knobs = {**knob_defaults(), **{k: v for k, v in base.items() if k in config.BY_NAME}}
    given = {k: v for k, v in explicit.items() if v is not None}
    knobs.update(given)
    # A preset's small-light scale yields to an explicit large shadow map (the sharp maps stay within
    # MAX_SHADOW_SIDE); a scale the caller names is kept, and FrameSettings refuses it if too large.
    if "small_light_scale" not in given and int(knobs["shadow_size"]) * int(knobs["small_light_scale"]) > MAX_SHADOW_SIDE:
        knobs["small_light_scale"] = max(1, MAX_SHADOW_SIDE // int(knobs["shadow_size"]))
    return knobs


def frame_settings(knobs: dict, width: int, height: int, **output):
    """The FrameSettings of resolved knobs (`merge_knobs`) for a width x height image; `output` are
    the settings no preset chooses (mode, background, bleed_reduction)."""
    from ..renderer import FrameSettings

    return FrameSettings(width=width, height=height, **{k: knobs[k] for k in config.FRAME_SETTINGS}, **output)


def pem_settings(knobs: dict, filter, levels: int | None, materials=None):
    """The PEM set's settings of resolved knobs: with the scene's materials, only the levels their
    glossiness reads (the same image, a fraction of the memory and 4 % less frame time held out:
    docs/broad-benchmark.md); without materials, the whole chain."""
    from ..lighting.filters import Filter
    from ..lighting.pem import PEMSettings

    for name in config.PEM_SETTINGS:
        config.check(name, knobs[name])
    pem = PEMSettings(knobs["lights"], Filter.parse(filter), levels, whole_sources=knobs["whole_sources"],
                      lights_from=knobs["lights_from"])
    if materials is not None:
        pem = pem.for_materials(int(knobs["face_size"]), materials)
    return pem


# `table=STORED`: read the package's measured table now (renderer/bench/measured.json); a long-running
# caller passes the table it read at start-up (None: none was stored), so that every budget chooses from one.
STORED = "stored"


PRESET_DIR = Path(__file__).parent
# fast, balanced and accurate trade time for error; paper is the method as published (every setting
# the registry's default), the reference point the others are measured against.
PRESET_NAMES = ("fast", "balanced", "accurate", "paper")
# The version of the preset files' format (their `version`): a file of another version is refused.
PRESET_VERSION = 1


def _read_preset(name: str) -> dict:
    path = PRESET_DIR / f"{name}.toml"
    data = tomllib.loads(path.read_text())
    if data.get("version") != PRESET_VERSION:
        raise ValueError(f"{path}: preset format version {data.get('version')!r}, this code reads {PRESET_VERSION}")
    settings = data.get("settings", {})
    want = set(config.NAMES)
    if set(settings) != want:
        raise ValueError(f"{path}: a preset names every quality setting; missing {sorted(want - set(settings))}, "
                         f"unknown {sorted(set(settings) - want)}")
    try:
        return {name: config.check(name, settings[name]) for name in config.NAMES}
    except InvalidInputError as exc:
        raise ValueError(f"{path}: {exc}") from None


@functools.cache
def _presets() -> dict[str, dict]:
    return {name: _read_preset(name) for name in PRESET_NAMES}


def presets() -> tuple[dict, str]:
    """The presets (name -> every quality setting) and where they come from: the versioned files
    beside this module (renderer/presets/*.toml), read once, never re-chosen at run time."""
    return {name: dict(knobs) for name, knobs in _presets().items()}, \
        f"preset files renderer/presets/*.toml, version {PRESET_VERSION}"


def presets_digest(folder: Path | None = None) -> str:
    """A short hash of the preset files' names and contents (in `folder`; None: beside this module),
    their comments left out: a stored benchmark run records it, and a test fails when a preset's
    settings change and the run does not (tests/test_stored_runs.py)."""
    import hashlib
    import json

    h = hashlib.sha256()
    for path in sorted(Path(folder or Path(__file__).parent).glob("*.toml")):
        data = tomllib.loads(path.read_text())
        h.update(path.name.encode() + b"\0" + json.dumps(data, sort_keys=True).encode() + b"\0")
    return h.hexdigest()[:16]


def balanced(name: str):
    """A setting's default in the Python API (FrameSettings, PEMSettings): the balanced preset's."""
    return _presets()["balanced"][name]


def preset(name: str) -> dict:
    """One preset's settings (a copy)."""
    if name not in PRESET_NAMES:
        raise ValueError(f"unknown preset {name!r}; the presets are {', '.join(PRESET_NAMES)}")
    return dict(_presets()[name])


def base_knobs(preset: str, preset_knobs: dict, preset_source: str | None, frame_budget_ms: float | None,
               error_budget: float | None, table: dict | None | str = STORED,
               size: tuple[int, int] | None = None, device: str | None = None) -> tuple[dict, str | None, str]:
    """What a request's knobs go over (`merge_knobs`): the measured setting that meets its budgets
    when it names one (`budget_knobs`, chosen from `table`), else its preset's knobs (from
    `preset_knobs`, the presets in use); `size`: the frame's (width, height), which a budget's table
    must have been measured at, on `device` (the GL renderer's name; None: not checked). Returns (knobs, the measured PEM filter, or None when the
    preset chose them, and where they came from): the one rule the command line and the service share."""
    if frame_budget_ms is not None or error_budget is not None:
        from ..bench.budget import budget_knobs

        return budget_knobs(frame_budget_ms, error_budget, table, size, device)
    return preset_knobs[preset], None, f"preset {preset}" + (f", {preset_source}" if preset_source else "")



def preset_frame(name: str = "balanced", width: int = 512, height: int = 512, **output):
    """A preset's FrameSettings for a width x height image (balanced unless named); `output`: mode,
    background, bleed_reduction."""
    return frame_settings(merge_knobs(preset(name), {}), width, height, **output)


def preset_pems(name: str = "balanced", materials=None, filter: str = "sqrt-cosine", levels: int | None = None):
    """A preset's PEMSettings (balanced unless named): with the scene's materials, only the levels
    they read."""
    return pem_settings(merge_knobs(preset(name), {}), filter, levels, materials)
