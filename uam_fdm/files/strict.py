"""Checks for values read from the files users give us (vehicles, maps, generators, scenarios).

`uam_fdm.files.yamlfile` reads such a file strictly; the helpers here check what it holds, so
every loader rejects the same things with the same words.  Each raises
`ConfigError(file, key, reason)` ("file: key: reason"), the key a dotted path into the document
(`map.buildings[3].size`; `key_path` builds it), the reason quoting the bad value.  The one
exception is `checked_number`, the range check of frozen dataclasses built from Python as well
as from files: it raises a plain ValueError naming the field (`number_in_range` turns it into a
ConfigError for a file).

What counts as a number: an int or a float (YAML's two), never a boolean or a string, and, where
finite is asked for, not NaN or infinite.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Collection, Iterable, Mapping
from itertools import accumulate
from pathlib import Path
from typing import Any

from uam_fdm.errors import ConfigError


def key_path(parent: str, key: object) -> str:
    """The dotted key of `key` inside `parent` ("" for the document's top level)."""
    return f"{parent}.{key}" if parent else str(key)


# ---- mappings ------------------------------------------------------------------------------------
def reject_unknown(cfg: Mapping, known: Collection[str], source: str, parent: str = "") -> None:
    """Raise for the first key of `cfg` not in `known`, listing the allowed keys: in the order given
    (a tuple or list, e.g. a file format's documented order), or sorted (a set)."""
    for k in cfg:
        if k not in known:
            allowed = sorted(known) if isinstance(known, (set, frozenset)) else known
            raise ConfigError(source, key_path(parent, k), f"unknown key (allowed: {', '.join(allowed)})")


def require_keys(cfg: Mapping, required: Iterable[str], source: str, parent: str = "",
                 reason: str = "missing") -> None:
    """Raise `reason` for the first of `required` (in the order given) that `cfg` lacks."""
    for k in required:
        if k not in cfg:
            raise ConfigError(source, key_path(parent, k), reason)


def mapping(value: Any, source: str, key: str, known: Collection[str] | None = None,
            required: Iterable[str] = (), *, expected: str = "a mapping") -> Mapping:
    """`value` checked to be a mapping (else "must be <expected>, got <value>") with only `known`
    keys (None: any) and every `required` key; returned as is."""
    if not isinstance(value, Mapping):
        raise ConfigError(source, key, f"must be {expected}, got {value!r}")
    if known is not None:
        reject_unknown(value, known, source, key)
    require_keys(value, required, source, key)
    return value


def root_mapping(doc: Any, source: str, what: str) -> Mapping:
    """A whole document checked to be a mapping (key ``<root>``); the error names the type found,
    not the value (a wrong document can be long).

    Args:
        doc: the parsed document.
        source: the file, for the error message.
        what: what the mapping should hold, e.g. "vehicle parameters".
    """
    if not isinstance(doc, Mapping):
        raise ConfigError(source, "<root>", f"must be a mapping of {what}, got {type(doc).__name__}")
    return doc


# ---- numbers -------------------------------------------------------------------------------------
def is_number(value: Any) -> bool:
    """An int or a float, not a boolean (YAML's true is an int to Python)."""
    return not isinstance(value, bool) and isinstance(value, (int, float))


def is_finite_number(value: Any) -> bool:
    """`is_number` and neither NaN nor infinite (an integer too large for a float is not finite either)."""
    if not is_number(value):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond a float's range
        return False


def json_object_file(path: Path) -> dict[str, Any]:
    """The JSON object in file `path` (`strict_json_loads`).

    Raises:
        ValueError: unreadable, not JSON, or not an object, naming the file.
    """
    try:
        loaded = strict_json_loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: unreadable ({exc})") from None
    if not isinstance(loaded, dict):
        raise ValueError(f"{path}: not a JSON object")
    return loaded


def strict_json_loads(text: str) -> Any:
    """`json.loads` of a file a user or another run wrote, refusing what no file of ours holds: an integer longer
    than `MAX_JSON_INT_CHARS` digits (as a float it would overflow, and converting it can take seconds) and arrays
    or objects nested deeper than `MAX_JSON_DEPTH` (the parser recurses, and a deep enough file ends it in a
    RecursionError instead of a message).

    Raises:
        json.JSONDecodeError: (a ValueError) not JSON, or either of the above; a reader that names its file for
            malformed JSON names it for these too.
    """
    deep = _too_deep(text)
    if deep is not None:
        raise json.JSONDecodeError(f"nested deeper than {MAX_JSON_DEPTH} levels", text, deep)

    def parse_int(digits: str) -> int:
        if len(digits.lstrip("-")) > MAX_JSON_INT_CHARS:
            raise json.JSONDecodeError(f"an integer of {len(digits)} digits ({digits[:12]}...): too large, at most "
                                       f"{MAX_JSON_INT_CHARS}", text, max(text.find(digits), 0))
        return int(digits)

    return json.loads(text, parse_int=parse_int)


def _too_deep(text: str) -> int | None:
    """The offset in `text` of the first bracket opening level `MAX_JSON_DEPTH` + 1 (brackets inside strings
    do not count), or None when it nests no deeper."""
    if text.count("[") + text.count("{") <= MAX_JSON_DEPTH:  # the common case: no scan at all
        return None
    brackets = _NOT_A_BRACKET.sub("", _STRING.sub("", text))
    if max(accumulate(map(_DEPTH_STEP.__getitem__, brackets)), default=0) <= MAX_JSON_DEPTH:
        return None
    depth = 0  # too deep: where (a second pass, only for the message)
    for m in _BRACKET_OR_STRING.finditer(text):
        depth += _DEPTH_STEP.get(m.group(), 0)
        if depth > MAX_JSON_DEPTH:
            return m.start()
    return None


MAX_JSON_INT_CHARS = 20  # 2**63 has 19 digits
MAX_JSON_DEPTH = 64  # our deepest files (run.json, a summary) nest under ten levels
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')  # a whole JSON string: brackets in it do not nest
_NOT_A_BRACKET = re.compile(r"[^\[\]{}]+")
_BRACKET_OR_STRING = re.compile(_STRING.pattern + r"|[\[\]{}]")
_DEPTH_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


def number(value: Any, source: str, key: str) -> float:
    """A finite number as a float ("must be a number" / "must be finite" otherwise)."""
    if not is_number(value):
        raise ConfigError(source, key, f"must be a number, got {value!r}")
    if not is_finite_number(value):
        raise ConfigError(source, key, f"must be finite, got {value!r}")
    return float(value)


def positive(value: Any, source: str, key: str) -> float:
    """A finite number > 0, as a float."""
    x = number(value, source, key)
    if x <= 0.0:
        raise ConfigError(source, key, f"must be positive, got {value!r}")
    return x


def non_negative(value: Any, source: str, key: str) -> float:
    """A finite number >= 0, as a float."""
    x = number(value, source, key)
    if x < 0.0:
        raise ConfigError(source, key, f"must be non-negative, got {value!r}")
    return x


def checked_number(name: str, value: Any, bounds: tuple[float, float], unit: str,
                   open_low: bool = False) -> float:
    """``value`` as a float, or a ValueError naming ``name`` unless it is a finite number in ``bounds``
    (``open_low``: the lower bound itself is excluded)."""
    # Strings and booleans convert to float silently; in a scenario they are mistakes.
    if isinstance(value, (str, bytes, bool)):
        raise ValueError(f"{name} must be a number ({unit}), got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"{name} must be finite ({unit}), got an integer of {len(str(value))} digits") from None
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number ({unit}), got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite ({unit}), got {value!r}")
    lo, hi = bounds
    if not ((lo < v if open_low else lo <= v) and v <= hi):
        low = "(" if open_low else "["
        raise ValueError(f"{name}={v} is outside the accepted range {low}{lo}, {hi}] {unit}")
    return v


def number_in_range(value: Any, bounds: tuple[float, float], unit: str, source: str, key: str,
                    open_low: bool = False) -> float:
    """`checked_number` for a value read from a file: the same reason, as a ConfigError at `key`.

    Args:
        value: the value read.
        bounds: (low, high), both included unless `open_low` excludes low.
        unit: the unit, shown in the reason (e.g. "m above the field").
        source: the file.
        key: the dotted key; its last part names the value in the reason.
    """
    try:
        return checked_number(key.rsplit(".", 1)[-1], value, bounds, unit, open_low=open_low)
    except ValueError as exc:
        raise ConfigError(source, key, str(exc)) from None


def numbers(value: Any, n: int, source: str, key: str, *, what: str | None = None,
            all_positive: bool = False) -> list[float]:
    """A list of exactly n finite numbers (a pair, a triple), as floats; checked as a whole.

    Args:
        value: the value read.
        n: how many numbers.
        source: the file.
        key: the dotted key.
        what: what the reason says it must be (default "<n> finite numbers").
        all_positive: every number must also be > 0.

    Raises:
        ConfigError: "must be <what>, got <value>".
    """
    if (not isinstance(value, (list, tuple)) or len(value) != n
            or not all(is_finite_number(v) and (not all_positive or v > 0) for v in value)):
        raise ConfigError(source, key, f"must be {what or f'{n} finite numbers'}, got {value!r}")
    return [float(v) for v in value]


def number_list(value: Any, n: int, source: str, key: str) -> list:
    """A list of n items, not yet checked item by item ("must be a list of <n> numbers" otherwise):
    for loaders that name the bad item itself."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigError(source, key, f"must be a list of {n} numbers, got {value!r}")
    return list(value)


# ---- other scalars -------------------------------------------------------------------------------
def string(value: Any, source: str, key: str) -> str:
    """A string."""
    if not isinstance(value, str):
        raise ConfigError(source, key, f"must be a string, got {value!r}")
    return value


def boolean(value: Any, source: str, key: str) -> bool:
    """true or false."""
    if not isinstance(value, bool):
        raise ConfigError(source, key, f"must be true or false, got {value!r}")
    return value
