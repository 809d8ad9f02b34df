"""Quality presets: versioned files beside this module (fast.toml, balanced.toml, accurate.toml, paper.toml),
each naming every quality setting with the measurement behind it (read by renderer/preset_files.py),
and the one rule that resolves a preset or a budget with a caller's overrides into the settings of a
frame and of a PEM set. Used by the command line, the service and the benchmark alike; the measured
table (measured.json beside this module, budget.py) serves budgets only, never the presets."""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

from .. import config
from ..preset_files import (  # noqa: F401 (the presets' public names)
    PRESET_DIR,
    PRESET_NAMES,
    PRESET_VERSION,
    preset,
    presets,
    presets_digest,
)
from .budget import STORED


def knob_defaults() -> dict:
    """Every quality setting (renderer/config.py) and its default, in the registry's order."""
    return {st.name: st.default for st in config.SETTINGS}


def merge_knobs(base: dict, explicit: dict) -> dict:
    """A preset's or budget's knobs (`base`) over the defaults, with the caller's explicit values
    (None: not given) over both: the one rule the command line, the service and the benchmark share."""
    knobs = {**knob_defaults(), **{k: v for k, v in base.items() if k in config.BY_NAME}}
    given = {k: v for k, v in explicit.items() if v is not None}
    knobs.update(given)
    # The registry's rule on the sharp maps' side: a scale the caller did not name yields to it; one
    # they named is kept, and FrameSettings refuses it if the pair breaks the rule.
    if "small_light_scale" not in given:
        knobs["small_light_scale"] = config.fitted_small_light_scale(knobs["shadow_size"], knobs["small_light_scale"])
    return knobs


def frame_settings(knobs: dict, width: int, height: int, **output):
    """The FrameSettings of resolved knobs (`merge_knobs`) for a width x height image; `output` are
    the settings no preset chooses (mode, background, bleed_reduction)."""
    from ..settings import FrameSettings

    return FrameSettings(width=width, height=height, **{k: knobs[k] for k in config.FRAME_SETTINGS}, **output)


def pem_settings(knobs: dict, filter, levels: int | None, materials=None):
    """The PEM set's settings of resolved knobs: with the scene's materials, only the levels their
    glossiness reads (the same image, a fraction of the memory and 4 % less frame time held out:
    docs/broad-benchmark.md); without materials, the whole chain."""
    from ..lighting.filters import Filter
    from ..lighting.pem_plan import PEMSettings

    config.check("face_size", knobs["face_size"])   # the others PEMSettings checks
    pem = PEMSettings(**{name: knobs[name] for name in config.PEM_FIELDS}, filter=Filter.parse(filter), levels=levels)
    if materials is not None:
        pem = pem.for_materials(int(knobs["face_size"]), materials)
    return pem


def base_knobs(preset: str, preset_knobs: dict, preset_source: str | None, frame_budget_ms: float | None,
               error_budget: float | None, table: dict | None | str = STORED,
               size: tuple[int, int] | None = None, device: str | None = None) -> tuple[dict, str | None, str]:
    """What a request's knobs go over (`merge_knobs`): the measured setting that meets its budgets
    when it names one (`budget_knobs`, chosen from `table`), else its preset's knobs (from
    `preset_knobs`, the presets in use); `size`: the frame's (width, height), which a budget's table
    must have been measured at, on `device` (the GL renderer's name; None: not checked). Returns (knobs, the measured PEM filter, or None when the
    preset chose them, and where they came from)."""
    if frame_budget_ms is not None or error_budget is not None:
        from .budget import budget_knobs

        return budget_knobs(frame_budget_ms, error_budget, table, size, device)
    return preset_knobs[preset], None, f"preset {preset}" + (f", {preset_source}" if preset_source else "")


DEFAULT_FILTER = config.OPTION["filter"].default   # the registry's (renderer/config.py)


@dataclass(frozen=True)
class Quality:
    """A preset or a budget resolved with a caller's overrides (`resolve`): every quality setting of
    the registry, the PEM filter, and where they came from. What a change of each invalidates is the
    registry's (`key`)."""

    knobs: MappingProxyType          # every registry setting -> its value
    filter: str                      # the PEM set's MIP filter
    preset: str | None               # None: a budget chose the knobs
    source: str                      # where they came from, as a frame reports it
    measured_on: str | None = None   # a budget's table: the GL renderer it was measured on

    def __getitem__(self, name: str):
        return self.knobs[name]

    @property
    def face_size(self) -> int:
        """The PEM faces' side: the cube an environment map is resampled to (load_environment)."""
        return int(self.knobs["face_size"])

    def key(self, invalidates: str) -> tuple:
        """The values of the settings whose change makes `invalidates` anew (config.INVALIDATES: the
        PEM set's key with its filter, the shadow maps', a shader variant's)."""
        names = [st.name for st in config.SETTINGS if st.invalidates == invalidates]
        return tuple(self.knobs[n] for n in names) + ((self.filter,) if invalidates == "pem set" else ())

    def frame(self, width: int, height: int, **output):
        """FrameSettings for a width x height image; `output`: mode, background, bleed_reduction."""
        return frame_settings(self.knobs, width, height, **output)

    def pems(self, levels: int | None = None, materials=None):
        """PEMSettings; with the scene's materials, only the levels they read."""
        return pem_settings(self.knobs, self.filter, levels, materials)

    def as_dict(self) -> dict:
        """Every setting, the filter and the source (and a budget's device) as one flat dict."""
        out = {**self.knobs, "filter": self.filter, "source": self.source}
        if self.measured_on is not None:
            out["measured_on"] = self.measured_on
        return out


def resolve(preset: str | None = None, overrides: dict | None = None, *, frame_budget_ms: float | None = None,
            error_budget: float | None = None, filter: str | None = None, in_use: tuple[dict, str] | None = None,
            table: dict | None | str = STORED, size: tuple[int, int] | None = None,
            device: str | None = None) -> Quality:
    """The one rule from what a caller asks to the settings of a frame and a PEM set, shared by the
    command line, the service, the simulation's preview and the Python API: a budget (the measured
    setting that meets it, from `table`, measured at `size` on `device`) when one is given, else the
    preset (balanced unless named; `in_use`: (presets, where they come from), default the files),
    over the registry's defaults; `overrides` (None values: not given) over both (`merge_knobs`).
    The PEM filter: `filter`, else a budget's measured one, else DEFAULT_FILTER."""
    name = preset or "balanced"
    if in_use is None:
        in_use = presets()
    budget = frame_budget_ms is not None or error_budget is not None
    if budget and table == STORED:
        from .budget import load_table

        table = load_table()   # read once: the choice and the device it was measured on
    base, measured_filter, source = base_knobs(name, *in_use, frame_budget_ms, error_budget, table, size, device)
    knobs = merge_knobs(base, dict(overrides or {}))
    measured_on = table["machine"].get("gl_renderer") if budget else None
    return Quality(MappingProxyType(knobs), filter or measured_filter or DEFAULT_FILTER, None if budget else name,
                   source, measured_on)


def preset_frame(name: str = "balanced", width: int = 512, height: int = 512, **output):
    """A preset's FrameSettings for a width x height image (balanced unless named); `output`: mode,
    background, bleed_reduction."""
    return resolve(name).frame(width, height, **output)


def preset_pems(name: str = "balanced", materials=None, filter: str = DEFAULT_FILTER, levels: int | None = None):
    """A preset's PEMSettings (balanced unless named): with the scene's materials, only the levels
    they read."""
    return resolve(name, filter=filter).pems(levels, materials)


def reference_table() -> str:
    """docs/settings.md: every setting with its group, limits, the paper's value, what a change makes
    anew and its doc (tests/test_config.py checks the stored file against it)."""
    values = {name: preset(name) for name in PRESET_NAMES}
    head = ["# Quality settings", "",
            "Generated from the registry (`renderer/config.py`) by `renderer.presets.reference_table`; each is a `--flag` of `render`, `sequence` and "
            "`reference` (dashes for underscores) and a field of the service's `quality`. `FrameSettings()` and "
            "`PEMSettings()` hold the paper's values (a preset's come from `presets.resolve`); the paper's column is the method as the paper states it (the bias, which it does not "
            "state, is the presets'); the presets' values are their files' (`renderer/presets/*.toml`).", "",
            "| setting | group | values | paper | " + " | ".join(PRESET_NAMES) + " | a change makes anew | what it does |",
            "|---|---|---|---|" + "---|" * len(PRESET_NAMES) + "---|---|"]
    rows = [f"| `{s.name}` | {s.group} | {s.limits()} | {config._show(s.default)} | "
            + " | ".join(config._show(values[p][s.name]) for p in PRESET_NAMES) + f" | {s.invalidates} | {s.doc} |"
            for s in config.SETTINGS]
    options = ["", "## Options no preset chooses", "",
               "Declared in the same registry (`config.OPTIONS`): a `--flag` and a field of the service's `quality` "
               "(`layout`: of an environment's upload) alike, the same for every preset.", "",
               "| option | group | values | default | a change makes anew | what it does |", "|---|---|---|---|---|---|"]
    options += [f"| `{o.name}` | {o.group} | {o.limits()} | {config._show(o.default)} | {o.invalidates} | {o.doc} |"
                for o in config.OPTIONS]
    return "\n".join(head + rows + options) + "\n"
