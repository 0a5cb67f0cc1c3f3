"""Random legs: `episodes: {random: N, ...}` in a scenario file, drawn from a seed and checked like explicit ones.

The scenario loader (`compare.scenarios.scenario`) hands the mapping here before it checks the episodes; the legs
come back as the explicit list `[{start: [x, y, z], goal: [x, y, z]}, ...]` and go through every check an
explicit episode gets (start and goal free, in bounds, out of no-fly zones, clear of the prior map, a goal
outside the goal radius, hover feasible, the default timeout). Frames: world ENU metres, heights above the field
(ground z = 0). Keys, units and defaults: `RANDOM_KEYS`, docs/scenario_format.md.

How a leg is drawn (`draw_leg`; the benchmark sets' legs, `compare.scenarios.benchmark.draw_leg`, are the same
draws): candidates in batches of `_DRAW_BATCH`: a straight-line length, a start and a goal height, a heading,
then a start uniform over the places from which the goal stays inside the flyable area; both ends rounded to
0.1 m and at least `clearance_m` beyond the vehicle's collision radius from every building and the ground. The
first candidate whose straight line is blocked by a building wins (`prefer_blocked`), else the first free one.

Determinism: leg i comes from its own stream, `PCG64([seed, _STREAM_RANDOM_LEGS, i])`, so the same file draws the
same legs, and a file asking for more legs keeps its first ones. No leg after `MAX_RANDOM_LEG_DRAWS` candidates is
an error naming the file and the request.
"""
from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.map_error import unmapped_from_config
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import boolean, mapping, number_in_range

RANDOM_KEYS = ("random", "seed", "min_length_m", "max_length_m", "min_height_m", "max_height_m", "clearance_m",
               "margin_m", "prefer_blocked")
"""The keys of `episodes: {random: N, ...}`, in the documented order."""
MAX_RANDOM_LEGS = 1000
MAX_SEED = 2**32 - 1
MAX_RANDOM_LEG_DRAWS = 1024
"""Candidates per leg before a request is refused as impossible."""
MIN_DEFAULT_CLEARANCE_M = 2.0
"""The default `clearance_m` is the vehicle's collision radius, at least this [m]."""
_DRAW_BATCH = 32
_STREAM_RANDOM_LEGS = 0x7A9  # PCG64 stream tag: not the benchmark's (0x1E6) nor any other of a seed's streams


@dataclass(frozen=True)
class LegRanges:
    """What one leg is drawn from (world ENU, metres).

    Attributes:
        length_m: (shortest, longest) straight-line start-goal distance [m].
        height_m: (lowest, highest) start and goal height z above the ground [m].
        clearance_m: start and goal at least this far beyond the collision radius from every building and the
            ground [m].
        margin_m: start and goal centres at least this far inside the bounds' sides, horizontally [m].
    """

    length_m: tuple[float, float]
    height_m: tuple[float, float]
    clearance_m: float
    margin_m: float


@dataclass(frozen=True)
class RandomLegs:
    """A checked `episodes: {random: N, ...}` request.

    Attributes:
        count: how many legs.
        seed: the seed of the draws (default: the scenario's first seed).
        ranges: lengths, heights, clearance and side margin of every leg (`LegRanges`; its margin is the
            key `margin_m` plus the vehicle's collision radius).
        prefer_blocked: take the first candidate whose straight line a building blocks (else the first free one).
    """

    count: int
    seed: int
    ranges: LegRanges
    prefer_blocked: bool = True


def draw_leg(city: BuildingMap, rng: np.random.Generator, ranges: LegRanges, radius_m: float,
             max_draws: int = MAX_RANDOM_LEG_DRAWS, prefer_blocked: bool = True
             ) -> tuple[list[float], list[float]] | None:
    """One leg of `city`: start and goal [x, y, z] (ENU m, rounded to 0.1 m), or None after `max_draws` candidates.

    Both ends lie in bounds and outside no-fly zones with the collision sphere of radius `radius_m` [m], at least
    `ranges.clearance_m` beyond it from buildings and the ground, their distance in `ranges.length_m`.
    """
    d_lo, d_hi = ranges.length_m
    lo = np.asarray(city.bounds_min_m[:2]) + ranges.margin_m
    hi = np.asarray(city.bounds_max_m[:2]) - ranges.margin_m
    fallback = None
    for _ in range(max(1, max_draws // _DRAW_BATCH)):
        n = _DRAW_BATCH
        dist = rng.uniform(d_lo, d_hi, n)
        z = rng.uniform(*ranges.height_m, (n, 2))
        heading = rng.uniform(-math.pi, math.pi, n)
        u = rng.random((n, 2))
        horiz = np.sqrt(np.maximum(dist ** 2 - (z[:, 1] - z[:, 0]) ** 2, 1.0))
        step = horiz[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        # the start's range along each axis that keeps start and goal inside [lo, hi]
        s_lo, s_hi = np.maximum(lo, lo - step), np.minimum(hi, hi - step)
        fits = np.all(s_hi > s_lo, axis=1)
        start_xy = s_lo + u * (s_hi - s_lo)
        starts = np.round(np.column_stack([start_xy, z[:, 0]]), 1)
        goals = np.round(np.column_stack([start_xy + step, z[:, 1]]), 1)
        ok = fits & np.all((goals[:, :2] >= lo) & (goals[:, :2] <= hi), axis=1)
        ok &= np.all((starts[:, :2] >= lo) & (starts[:, :2] <= hi), axis=1)
        ok &= city.in_bounds(starts, radius_m) & city.in_bounds(goals, radius_m)
        if city.no_fly:
            ok &= ~(city.in_no_fly(starts, radius_m) | city.in_no_fly(goals, radius_m))
        if not np.any(ok):
            continue
        clear_a = city.clearance(starts, radius_m).distance_m
        clear_b = city.clearance(goals, radius_m).distance_m
        for k in np.flatnonzero(ok & (clear_a >= ranges.clearance_m) & (clear_b >= ranges.clearance_m)):
            d = math.dist(starts[k], goals[k])
            if not d_lo <= d <= d_hi:  # rounding at the range's ends
                continue
            leg = (starts[k].tolist(), goals[k].tolist())
            if not prefer_blocked or not city.segment_free(starts[k], goals[k], radius_m):
                return leg
            fallback = fallback or leg
    return fallback


def random_legs_from_config(value: Mapping, source: str, city: BuildingMap, radius_m: float, goal_radius_m: float,
                            default_seed: int) -> RandomLegs:
    """Check `episodes: {random: N, ...}` (keys `RANDOM_KEYS`) against the flight volume of `city` and the vehicle.

    Args:
        value: the parsed mapping.
        source: the file, for errors.
        city: the map the legs are drawn in (its bounds give the defaults).
        radius_m: the vehicle's collision radius [m].
        goal_radius_m: the scenario's goal radius [m]: every leg is longer.
        default_seed: the seed when the mapping gives none (the scenario's first seed).

    Raises:
        ConfigError: an unknown or missing key, a value out of range or ranges that cannot hold a leg, naming
            the file, the key (`episodes.min_length_m`) and the value.
    """
    if not isinstance(value, Mapping) or "random" not in value:
        raise ConfigError(source, "episodes", f"must be a non-empty list of {{start: [x, y, z], goal: [x, y, z]}} or "
                                              f"a mapping {{random: N, ...}}, got {value!r}")
    cfg = mapping(value, source, "episodes", RANDOM_KEYS)
    count = _integer(cfg["random"], 1, MAX_RANDOM_LEGS, source, "episodes.random")
    seed = _integer(cfg["seed"], 0, MAX_SEED, source, "episodes.seed") if "seed" in cfg else default_seed
    lo, hi = np.asarray(city.bounds_min_m, float), np.asarray(city.bounds_max_m, float)
    clearance = (_number(cfg["clearance_m"], (0.0, 1000.0), source, "clearance_m") if "clearance_m" in cfg
                 else max(MIN_DEFAULT_CLEARANCE_M, radius_m))
    margin = _number(cfg["margin_m"], (0.0, 10_000.0), source, "margin_m") if "margin_m" in cfg else clearance
    side = radius_m + margin
    span = hi[:2] - lo[:2] - 2.0 * side
    if not np.all(span > 0.0):
        raise ConfigError(source, "episodes.margin_m", f"{margin:g} m plus the collision radius {radius_m:g} m from "
                                                       f"each side leaves no room in the bounds' {hi[0] - lo[0]:g} x "
                                                       f"{hi[1] - lo[1]:g} m")
    floor, ceiling = float(lo[2]) + radius_m, float(hi[2]) - radius_m
    z_lo = (_number(cfg["min_height_m"], (floor, ceiling), source, "min_height_m") if "min_height_m" in cfg
            else min(float(lo[2]) + radius_m + clearance, ceiling))
    z_hi = (_number(cfg["max_height_m"], (floor, ceiling), source, "max_height_m") if "max_height_m" in cfg
            else max(float(hi[2]) - radius_m - clearance, z_lo))
    if z_hi < z_lo:
        raise ConfigError(source, "episodes.max_height_m", f"{z_hi:g} m is below min_height_m {z_lo:g} m")
    longest = float(math.hypot(span[0], span[1], z_hi - z_lo))  # the flyable box's diagonal
    given_lo = (_number(cfg["min_length_m"], (0.0, math.inf), source, "min_length_m", open_low=True)
                if "min_length_m" in cfg else None)
    d_hi = (_number(cfg["max_length_m"], (0.0, math.inf), source, "max_length_m", open_low=True)
            if "max_length_m" in cfg else max(0.5 * float(min(span)), given_lo or 0.0))
    d_lo = given_lo if given_lo is not None else min(max(0.25 * d_hi, 2.0 * goal_radius_m), d_hi)
    if d_lo <= goal_radius_m:
        raise ConfigError(source, "episodes.min_length_m", f"{d_lo:g} m is within the goal radius {goal_radius_m:g} m "
                                                           f"(a leg that short has nothing to fly); make it longer")
    if d_hi < d_lo:
        raise ConfigError(source, "episodes.max_length_m", f"{d_hi:g} m is shorter than min_length_m {d_lo:g} m")
    if d_lo > longest:
        raise ConfigError(source, "episodes.min_length_m", f"{d_lo:g} m is longer than the flyable volume's diagonal "
                                                           f"{longest:.1f} m (bounds less the collision radius and "
                                                           f"margin_m {margin:g} m, heights {z_lo:g}-{z_hi:g} m)")
    prefer = boolean(cfg["prefer_blocked"], source, "episodes.prefer_blocked") if "prefer_blocked" in cfg else True
    return RandomLegs(count, seed, LegRanges((d_lo, d_hi), (z_lo, z_hi), clearance, side), prefer)


def draw_random_legs(request: RandomLegs, city: BuildingMap, radius_m: float, source: str) -> list[dict[str, Any]]:
    """The legs of `request` in `city` as explicit episodes, `[{"start": [x, y, z], "goal": [x, y, z]}, ...]`.

    Raises:
        ConfigError: a leg with no valid candidate in `MAX_RANDOM_LEG_DRAWS` draws, naming the file and the request.
    """
    legs = []
    for i in range(request.count):
        rng = np.random.Generator(np.random.PCG64([request.seed, _STREAM_RANDOM_LEGS, i]))
        leg = draw_leg(city, rng, request.ranges, radius_m, MAX_RANDOM_LEG_DRAWS, request.prefer_blocked)
        if leg is None:
            r = request.ranges
            raise ConfigError(source, "episodes", f"no valid leg {i} of random: {request.count} in "
                                                  f"{MAX_RANDOM_LEG_DRAWS} draws from seed {request.seed} "
                                                  f"(lengths {r.length_m[0]:g}-{r.length_m[1]:g} m, heights "
                                                  f"{r.height_m[0]:g}-{r.height_m[1]:g} m, clearance_m "
                                                  f"{r.clearance_m:g} beyond the collision radius {radius_m:g} m, "
                                                  f"{r.margin_m:g} m inside the sides): widen the lengths or "
                                                  f"heights, or lower clearance_m or margin_m")
        legs.append({"start": leg[0], "goal": leg[1]})
    return legs


def episode_list(data: Mapping, source: str, world: BuildingMap, radius_m: float, goal_radius_m: float,
                 default_seed: int) -> tuple[Any, bool]:
    """A scenario mapping's `episodes` as the file lists them (False), or as the explicit `{start, goal}` mappings
    of the legs its `{random: N, ...}` draws (True) in `world` (the map) with the file's `unmapped` buildings.

    Args:
        data: the scenario mapping.
        source: the file, for errors.
        world: the scenario's map.
        radius_m: the vehicle's collision radius [m].
        goal_radius_m: the scenario's goal radius [m].
        default_seed: the seed of the draws when `episodes.seed` is not given (the scenario's first seed).

    Raises:
        ConfigError: a bad request or one no leg fits (`random_legs_from_config`, `draw_random_legs`).
    """
    value = data["episodes"]
    if not isinstance(value, Mapping):
        return value, False
    request = random_legs_from_config(value, source, world, radius_m, goal_radius_m, default_seed)
    unmapped = unmapped_from_config(data["unmapped"], source, world) if "unmapped" in data else ()
    known = BuildingMap((*world.buildings, *unmapped), world.bounds_min_m, world.bounds_max_m, world.no_fly,
                        name=world.name) if unmapped else world
    return draw_random_legs(request, known, radius_m, source), True


@contextlib.contextmanager
def named_as_drawn(source: str) -> Iterator[None]:
    """Say an error about `episodes[i]...` as one about drawn leg i: the file has no `episodes[i]` to look up."""
    try:
        yield
    except ConfigError as exc:
        found = re.fullmatch(r"episodes\[(\d+)\]\.?(.*)", exc.key, flags=re.S)
        if found is None:
            raise
        what = f"drawn leg {found[1]}" + (f" ({found[2]})" if found[2] else "")
        raise ConfigError(source, "episodes", f"{what}: {exc.reason}") from None


def _integer(value: Any, low: int, high: int, source: str, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(source, key, f"must be an integer in [{low}, {high}], got {value!r}")
    return value


def _number(value: Any, bounds: tuple[float, float], source: str, name: str, open_low: bool = False) -> float:
    unit = ("m above the ground (the flight volume's floor and ceiling less the vehicle's collision radius)"
            if "height" in name else "m")
    return number_in_range(value, bounds, unit, source, f"episodes.{name}", open_low=open_low)
