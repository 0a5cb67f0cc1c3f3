"""The strict checks every loader uses: their exact error texts ("file: key: reason")."""
from __future__ import annotations

import math

import numpy as np
import pytest

from uam_fdm.errors import ConfigError
from uam_fdm.files import strict


def _message(fn, *args, **kwargs) -> str:
    with pytest.raises(ConfigError) as exc:
        fn(*args, **kwargs)
    return str(exc.value)


def test_key_paths() -> None:
    assert strict.key_path("", "name") == "name"
    assert strict.key_path("map.buildings[3]", "size") == "map.buildings[3].size"
    assert strict.key_path("", 7) == "7"


def test_mapping_errors() -> None:
    assert _message(strict.reject_unknown, {"b": 1, "colour": 2}, ("b", "a"), "f.yaml", "map") == \
        "f.yaml: map.colour: unknown key (allowed: b, a)"  # a tuple: its order (a format's own)
    assert _message(strict.reject_unknown, {"colour": 2}, {"b", "a"}, "f.yaml") == \
        "f.yaml: colour: unknown key (allowed: a, b)"
    assert _message(strict.require_keys, {"a": 1}, ("a", "c", "b"), "f.yaml", "bounds") == \
        "f.yaml: bounds.c: missing"
    assert _message(strict.require_keys, {}, ("name",), "f.yaml", reason="missing (required)") == \
        "f.yaml: name: missing (required)"
    assert _message(strict.mapping, [1, 2], "f.yaml", "atmosphere") == \
        "f.yaml: atmosphere: must be a mapping, got [1, 2]"
    assert _message(strict.mapping, 3, "f.yaml", "bounds", expected="a mapping {min, max}") == \
        "f.yaml: bounds: must be a mapping {min, max}, got 3"
    # unknown keys are reported before missing ones
    assert _message(strict.mapping, {"x": 1}, "f.yaml", "k", {"a"}, ("a",)) == \
        "f.yaml: k.x: unknown key (allowed: a)"
    assert _message(strict.mapping, {}, "f.yaml", "k", {"a"}, ("a",)) == "f.yaml: k.a: missing"
    assert strict.mapping({"a": 1}, "f.yaml", "k", {"a"}, ("a",)) == {"a": 1}
    assert _message(strict.root_mapping, None, "f.yaml", "vehicle parameters") == \
        "f.yaml: <root>: must be a mapping of vehicle parameters, got NoneType"


@pytest.mark.parametrize("fn, value, text", [
    (strict.number, "heavy", "f.yaml: k: must be a number, got 'heavy'"),
    (strict.number, True, "f.yaml: k: must be a number, got True"),
    (strict.number, math.nan, "f.yaml: k: must be finite, got nan"),
    (strict.positive, 0, "f.yaml: k: must be positive, got 0"),
    (strict.positive, -1.5, "f.yaml: k: must be positive, got -1.5"),
    (strict.non_negative, -1, "f.yaml: k: must be non-negative, got -1"),
    (strict.string, 7, "f.yaml: k: must be a string, got 7"),
    (strict.boolean, "yes", "f.yaml: k: must be true or false, got 'yes'"),
])
def test_scalar_errors(fn, value, text: str) -> None:
    assert _message(fn, value, "f.yaml", "k") == text


def test_scalars_pass_through() -> None:
    assert strict.number(3, "f", "k") == 3.0 and isinstance(strict.number(3, "f", "k"), float)
    assert strict.non_negative(0, "f", "k") == 0.0 and strict.positive(0.5, "f", "k") == 0.5
    assert strict.string("a", "f", "k") == "a" and strict.boolean(False, "f", "k") is False
    assert strict.is_number(1) and not strict.is_number(True) and not strict.is_number("1")
    assert strict.is_finite_number(1.5) and not strict.is_finite_number(math.inf)


def test_ranges() -> None:
    assert strict.number_in_range(5, (0.0, 10.0), "m", "f", "a.b") == 5.0
    text = _message(strict.number_in_range, 20000, (-500.0, 9000.0), "m above mean sea level", "f.yaml",
                    "atmosphere.elevation_m")
    assert text == ("f.yaml: atmosphere.elevation_m: elevation_m=20000.0 is outside the accepted range "
                    "[-500.0, 9000.0] m above mean sea level")
    assert _message(strict.number_in_range, 0, (0.0, 3600.0), "s", "f.yaml", "timeout_s", open_low=True) == \
        "f.yaml: timeout_s: timeout_s=0.0 is outside the accepted range (0.0, 3600.0] s"
    assert _message(strict.number_in_range, "3", (0.0, 1.0), "m", "f.yaml", "goal_radius_m") == \
        "f.yaml: goal_radius_m: goal_radius_m must be a number (m), got '3'"
    assert _message(strict.number_in_range, math.inf, (0.0, 1.0), "m", "f.yaml", "x") == \
        "f.yaml: x: x must be finite (m), got inf"
    # the dataclass form: a plain ValueError without a file, numpy numbers accepted
    with pytest.raises(ValueError, match=r"^dt_s must be a number \(s\), got None$") as exc:
        strict.checked_number("dt_s", None, (0.0, 1.0), "s")
    assert not isinstance(exc.value, ConfigError)
    assert strict.checked_number("n", np.int64(3), (0.0, 5.0), "") == 3.0


def test_pairs_and_triples() -> None:
    assert strict.numbers([1, 2.5], 2, "f", "k") == [1.0, 2.5]
    assert _message(strict.numbers, [math.nan, 5], 2, "f.yaml", "map.buildings[0].center") == \
        "f.yaml: map.buildings[0].center: must be 2 finite numbers, got [nan, 5]"
    assert _message(strict.numbers, [1, True, 0], 3, "f.yaml", "w",
                    what="3 finite numbers [x, y, z] (m/s)") == \
        "f.yaml: w: must be 3 finite numbers [x, y, z] (m/s), got [1, True, 0]"
    assert _message(strict.numbers, [0, 5], 2, "f.yaml", "s", what="two positive numbers",
                    all_positive=True) == "f.yaml: s: must be two positive numbers, got [0, 5]"
    assert _message(strict.numbers, "1, 2", 2, "f.yaml", "s") == \
        "f.yaml: s: must be 2 finite numbers, got '1, 2'"
    assert strict.number_list((1, "x"), 2, "f", "k") == [1, "x"]  # items are the caller's to check
    assert _message(strict.number_list, [0.1, 0.2], 3, "f.yaml", "rotors[2].position_m") == \
        "f.yaml: rotors[2].position_m: must be a list of 3 numbers, got [0.1, 0.2]"
