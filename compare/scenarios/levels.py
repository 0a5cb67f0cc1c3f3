"""A scenario flown at another sensing or map-error level than its file's (`run --sensing`, `--map-error`).

The level replaces the file's key as a whole (its overrides too) and the scenario is checked again from its parsed
mapping, so the prior map is drawn from the same seed as a file stating the level would draw it.
"""
from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

from compare.scenarios.scenario import Scenario, scenario_from_dict
from uam_fdm.city.map_error import MAP_ERROR_PRESETS
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS

MAP_ERROR_LEVELS = tuple(MAP_ERROR_PRESETS)


def with_levels(sc: Scenario, sensing: str | None = None, map_error: str | None = None) -> Scenario:
    """`sc` at sensing level `sensing` and map-error level `map_error` (None: the scenario's own).

    Raises:
        ValueError: an unknown level (naming the levels); ConfigError: the scenario at that level is not flyable
            (e.g. a start inside a building of the prior map), naming the scenario's file.
    """
    if sensing is None and map_error is None:
        return sc
    if sensing is not None and sensing not in SENSING_LEVELS:
        raise ValueError(f"sensing level {sensing!r}: choose from {', '.join(SENSING_LEVELS)}")
    if map_error is not None and map_error not in MAP_ERROR_LEVELS:
        raise ValueError(f"map-error level {map_error!r}: choose from {', '.join(MAP_ERROR_LEVELS)}")
    data = copy.deepcopy(sc.raw)
    for key, level in (("sensing", sensing), ("map_error", map_error)):
        if level is not None:
            data[key] = level
    base_dir = Path(sc.source).parent if sc.source else Path(".")
    again = scenario_from_dict(data, sc.source, base_dir)
    return dataclasses.replace(again, pilots=sc.pilots, task_set=sc.task_set)  # what the run chose, kept
