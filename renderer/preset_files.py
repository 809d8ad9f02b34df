"""The preset files (renderer/presets/*.toml), read and checked against the registry: what the
presets are, never how a request resolves them (renderer/presets). Data: no module takes its defaults
from them (FrameSettings' and PEMSettings' are the registry's)."""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path

from . import config
from .errors import InvalidInputError

PRESET_DIR = Path(__file__).parent / "presets"
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
    for path in sorted(Path(folder or PRESET_DIR).glob("*.toml")):
        data = tomllib.loads(path.read_text())
        h.update(path.name.encode() + b"\0" + json.dumps(data, sort_keys=True).encode() + b"\0")
    return h.hexdigest()[:16]


def preset(name: str) -> dict:
    """One preset's settings (a copy)."""
    if name not in PRESET_NAMES:
        raise ValueError(f"unknown preset {name!r}; the presets are {', '.join(PRESET_NAMES)}")
    return dict(_presets()[name])
