"""The smallest valid scenario, shared by the scenario, bad-input and wind-height tests (a module at
the root of tests/, importable from every test folder)."""
from __future__ import annotations

from typing import Any

# A 100 x 100 x 50 m box with one 20 x 20 x 30 m building (id 0) in the middle, x and y in [40, 60].
BASE: dict[str, Any] = {
    "name": "box",
    "map": {"buildings": [{"center": [50.0, 50.0], "size": [20.0, 20.0], "height": 30.0}]},
    "bounds": {"min": [0.0, 0.0, 0.0], "max": [100.0, 100.0, 50.0]},
    "vehicle": "small_quad",
    "episodes": [{"start": [10.0, 50.0, 10.0], "goal": [90.0, 50.0, 10.0]}],
}
