"""The U3M document: JSON, read within its bounds and checked against the spec's JSON schema for its
version (`schema`: "1.0" or "1.1"). The schemas are the spec's own files, unchanged, in schema/ (BSD-3,
Vizoo GmbH; schema/LICENSE). A violation is reported once, the most relevant one (jsonschema's
best_match), as the JSON path of the field and what was wrong with it.

Beyond the schema: a key twice in one object, NaN, Infinity and numbers that overflow a float are
refused (JSON allows the first, Python's json module reads the others; each makes a document mean two
things)."""

from __future__ import annotations

import functools
import json
import math
import reprlib
from pathlib import Path

from jsonschema import Draft7Validator
from jsonschema.exceptions import ValidationError, best_match

from ..errors import MaterialError

SCHEMA_DIR = Path(__file__).parent / "schema"
SCHEMA_FILES = {"1.0": "u3m_schema_version1.json", "1.1": "u3m_schema.json"}
VERSIONS = tuple(SCHEMA_FILES)

_repr = reprlib.Repr()   # values quoted in messages, cut short (a value can be a whole visualisation)
_repr.maxstring, _repr.maxother, _repr.maxlist, _repr.maxdict, _repr.maxlevel = 80, 80, 4, 4, 2
_short = _repr.repr


class _Refused(ValueError):
    pass


def parse_document(data: bytes, file: str) -> dict:
    """The document's JSON object."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise MaterialError(f"neither a U3M document (JSON, UTF-8) nor a U3MA archive (zip): byte {e.start} is not "
                            "UTF-8", file=file) from None
    if not text.lstrip().startswith("{"):
        raise MaterialError("neither a U3M document (a JSON object) nor a U3MA archive (zip)", file=file)

    def unique(pairs: list[tuple[str, object]]) -> dict:
        out: dict = {}
        for key, value in pairs:
            if key in out:
                raise _Refused(f"the key {key!r} appears twice in one object")
            out[key] = value
        return out

    def finite(text: str) -> float:
        value = float(text)
        if not math.isfinite(value):
            raise _Refused(f"the number {text[:40]} overflows a float")
        return value

    def constant(name: str) -> float:
        raise _Refused(f"{name} is not a JSON number")

    try:
        return json.loads(text, object_pairs_hook=unique, parse_float=finite, parse_constant=constant)
    except _Refused as e:
        raise MaterialError(str(e), file=file) from None
    except json.JSONDecodeError as e:
        raise MaterialError(f"is not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}", file=file) from None
    except RecursionError:
        raise MaterialError("is not a U3M document: its JSON is nested too deeply", file=file) from None
    except ValueError as e:   # e.g. an integer with more digits than Python converts
        raise MaterialError(f"is not valid JSON: {e}", file=file) from None


@functools.lru_cache(maxsize=len(SCHEMA_FILES))
def _validator(version: str) -> Draft7Validator:
    return Draft7Validator(json.loads((SCHEMA_DIR / SCHEMA_FILES[version]).read_text(encoding="utf-8")))


def validate_document(document: dict, file: str) -> str:
    """The document's schema version, once the document is valid against that version's schema."""
    version = document.get("schema")
    if version not in SCHEMA_FILES:
        raise MaterialError(f"is {_short(version)}; this reader reads U3M {' and '.join(VERSIONS)}", file=file,
                            field="schema")
    error = best_match(_validator(version).iter_errors(document))
    if error is not None:
        field, reason = _explain(error, version)
        raise MaterialError(reason, file=file, field=field)
    return version


def json_path(parts) -> str:
    """`material.front.basecolor` from the keys and indices of a path."""
    out = ""
    for part in parts:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(the document)"


def _explain(error: ValidationError, version: str) -> tuple[str, str]:
    """(field, reason) for a schema violation, in words a user can act on."""
    path = list(error.absolute_path)
    kind, expected, value = error.validator, error.validator_value, error.instance
    if kind == "required" and isinstance(value, dict):
        missing = next((name for name in expected if name not in value), "?")
        return json_path([*path, missing]), f"is missing (U3M {version} requires it)"
    if kind == "additionalProperties" and isinstance(value, dict):
        known = error.schema.get("properties", {})
        extra = next((name for name in value if name not in known), "?")
        return json_path([*path, extra]), f"is not a field of U3M {version}"
    if kind == "pattern":
        described = error.schema.get("description", "")
        if "path" in described:
            return json_path(path), (f"{_short(value)} is not a path the spec allows (relative, '/'-separated, no "
                                     "'.', '..' or '~' component, no drive letter, no reserved device name)")
        return json_path(path), f"{_short(value)} is not of the form the schema gives ({described or expected})"
    if kind == "not" and path == ["material"]:
        return "material", ("front, back, side and physics are all null; a U3M holds at least one visualisation "
                            "or physics")
    if kind == "const":
        return json_path(path), f"is {_short(value)}; U3M {version} has {expected!r} here"
    if kind == "type":
        wanted = " or ".join(expected) if isinstance(expected, list) else expected
        return json_path(path), f"is {_short(value)}, not of type {wanted}"
    if kind == "enum":
        return json_path(path), f"is {_short(value)}, not one of {', '.join(map(repr, expected))}"
    if kind in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        return json_path(path), f"is {_short(value)}; its {kind} is {expected}"
    message = error.message
    return json_path(path), message if len(message) <= 300 else message[:300] + "..."
