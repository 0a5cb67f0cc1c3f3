"""Scenario files: a strict loader that checks everything before anything flies.

A scenario is one YAML file: a city, a vehicle, the air it flies in, and the episodes (start, goal)
each pilot flies, once per seed; or `episodes: {random: N, ...}`, N legs drawn from a seed
(`compare.scenarios.random_legs`) and checked as explicit ones. World frame ENU (x east, y north, z up),
metres above the field (ground at z = 0), seconds, SI units. Every key, its unit, range and default:
docs/scenario_format.md.

Every value is checked when the file is loaded, and the first problem raises
`uam_fdm.errors.ConfigError` naming the file, the dotted key and the reason with the bad value,
e.g. ``runs/x.yaml: episodes[2].start: [10.0, 20.0, 5.0] is inside building 3``.  Rejected:
unknown keys at any level, duplicate keys, wrong types (booleans and strings are not numbers),
non-finite numbers, out-of-range values; a start or goal whose collision sphere (the vehicle's
`collision_radius_m`) leaves the bounds, touches a building or the ground (clearance <= radius),
or overlaps a no-fly zone; a goal within the goal radius of its start; duplicate seeds; an
unknown pilot; an unknown vehicle (the presets are listed); a vehicle that cannot hover (maximum
thrust <= weight) at the highest start or goal in this atmosphere.

Built-in scenario sets live in ``compare/scenarios/<set>/*.yaml``; the benchmark sets are generated
(`compare.scenarios.benchmark`) as the same mappings and checked by the same loader. Sets are named, listed and
resolved (a set name, a YAML file or a folder of YAML files) by `compare.scenarios.sets`, above this module and the
generator: this module resolves no names.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from compare.flying import pilots
from compare.flying.pilots import DEFAULT_PILOTS, PILOT_NAMES
from compare.results.run_info import TaskSetInfo
from compare.scenarios.random_legs import episode_list, named_as_drawn
from uam_fdm.air.atmosphere import (
    ELEVATION_RANGE_M,
    ISA_OFFSET_RANGE_K,
    Atmosphere,
    AtmosphereConditions,
)
from uam_fdm.air.shear import EXPONENT_RANGE, REFERENCE_HEIGHT_RANGE_M, ROUGHNESS_RANGE_M, ShearLaw, WindShear
from uam_fdm.air.wind import TurbulenceLevel, WindConditions
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.map_error import (
    KEEP_CLEAR_MARGIN_M,
    MapErrorConfig,
    apply_map_error,
    map_error_from_config,
    unmapped_from_config,
)
from uam_fdm.city.mapfile import map_from_config
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import (
    mapping,
    number_in_range,
    numbers,
    reject_unknown,
    require_keys,
    root_mapping,
    string,
)
from uam_fdm.files.yamlfile import load_yaml_file
from uam_fdm.pilot import Task
from uam_fdm.renamed import RenamedWarning
from uam_fdm.sensing.config import sensing_from_config
from uam_fdm.sensing.specs import SensingConfig, sensing_preset
from uam_fdm.vehicle.dynamics import (
    MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD,
    control_ratio_problem,
    motor_lag_problem,
)
from uam_fdm.vehicle.params import VehicleParams, load_vehicle, preset_names, vehicle_from_dict

DEFAULT_GOAL_RADIUS_M = 3.0
DEFAULT_SEEDS = (0,)
DEFAULT_PHYSICS_HZ = 500.0
DEFAULT_CONTROL_HZ = 50.0
TIMEOUT_BASE_S = 20.0
TIMEOUT_FLIGHT_TIME_FACTOR = 2.5
MAX_TIMEOUT_S = 3600.0
MAX_PHYSICS_HZ = 10000.0
MAX_SEED = 2**32 - 1  # OMPL and most RNG seeding APIs take unsigned 32-bit seeds
# The name starts every output file name ("<name>__ep000__rrt_mpc__s4294967295.parquet"); file systems
# allow 255 bytes per name, so this leaves room for the rest.
MAX_NAME_CHARS = 100

_TOP_KEYS = ("name", "description", "map", "bounds", "vehicle", "atmosphere", "episodes", "goal_radius_m",
             "timeout_s", "seeds", "pilots", "physics_hz", "control_hz", "unmapped", "map_error", "sensing")
OLD_PILOTS_KEY = "methods"  # the key `pilots` before its rename: still read, with a warning, until the next release
_REQUIRED_KEYS = ("name", "map", "vehicle", "episodes")
_ATMOSPHERE_KEYS = ("elevation_m", "isa_offset_k", "wind_mps", "wind_reference_height_m", "wind_shear", "turbulence")
_SHEAR_KEYS = ("law", "exponent", "roughness_m")
_EPISODE_KEYS = ("start", "goal", "goal_radius_m", "timeout_s")
_NAME_RE = re.compile(r"[A-Za-z0-9_.-]+")
AIR_BELOW_FIELD_M = 50.0  # the atmosphere table's reach below the field (z = 0) [m]
AIR_ABOVE_CEILING_M = 100.0  # ... and above the flight volume's ceiling [m]


@dataclass(frozen=True)
class ScenarioEpisode:
    """One episode of a scenario: its index in the file and the task to fly (ENU metres, seconds)."""

    index: int
    task: Task


@dataclass(frozen=True, eq=False, repr=False)
class Scenario:
    """A checked scenario, ready to run.

    Attributes:
        name: the scenario's name (used in output file names).
        description: free text.
        source: path of the file it came from (or the name given to `scenario_from_dict`).
        vehicle: the vehicle's parameters.
        vehicle_name: the preset name when the scenario names a preset, else `vehicle.name`.
        city: the TRUE world: buildings (with the `unmapped` ones and the generated cranes and masts), bounds
            and no-fly zones (ENU metres); what the vehicle collides with and what scores.
        atmosphere: field elevation [m MSL] and ISA temperature offset [K].
        air: the atmosphere table flown in (`flight_atmosphere`), built once when the scenario is loaded.
        prior_map: the map the pilots are given (`uam_fdm.city.map_error`): `city` itself (the same object) when
            the scenario has no map error and no unmapped buildings.
        unmapped_ids: ids of `city`'s buildings absent from `prior_map` (unmapped, missing, cranes and masts).
        map_error: how `prior_map` differs from `city` (the `exact` preset by default).
        sensing: what the vehicle senses (the `perfect` level for its mass by default).
        wind: steady wind (ENU, m/s) at its reference height, its shear with height, turbulence level.
        episodes: the tasks, in file order (legs drawn by `episodes: {random: N, ...}`: in the order drawn).
        seeds: the seeds each episode is flown with.
        pilots: the pilots to fly, in `compare.flying.pilots.PILOT_NAMES` order.
        physics_hz: physics rate [Hz].
        control_hz: decision rate [Hz]; physics_hz is an integer multiple of it.
        raw: a copy of the parsed YAML mapping, for provenance.
        task_set: the published task set it belongs to (a benchmark set, `compare.scenarios.benchmark`), else None.
    """

    name: str
    description: str
    source: str
    vehicle: VehicleParams
    vehicle_name: str
    city: BuildingMap
    atmosphere: AtmosphereConditions
    wind: WindConditions
    episodes: tuple[ScenarioEpisode, ...]
    seeds: tuple[int, ...]
    pilots: tuple[str, ...]
    physics_hz: float
    control_hz: float
    air: Atmosphere
    prior_map: BuildingMap
    unmapped_ids: tuple[int, ...]
    map_error: MapErrorConfig
    sensing: SensingConfig
    raw: dict = field(default_factory=dict)
    task_set: TaskSetInfo | None = None

    def __repr__(self) -> str:
        return (f"Scenario({self.name!r}, {len(self.episodes)} episodes x {len(self.seeds)} seeds, "
                f"vehicle={self.vehicle_name!r}, map={self.city.name!r}, pilots={self.pilots}, "
                f"source={self.source!r})")


# ---- public entry points -----------------------------------------------------------------------------
def with_pilots(scenario: Scenario, added: tuple[str, ...]) -> Scenario:
    """`scenario` flying `added` pilots (registered or plug-ins, already checked) beside its own."""
    if not added:
        return scenario
    return dataclasses.replace(scenario, pilots=tuple(pilots.ordered((*scenario.pilots, *added))))


def load_scenario(path: str | Path) -> Scenario:
    """Load and check one scenario YAML file.

    Args:
        path: the file; relative paths inside it (vehicle, GeoJSON) resolve against its folder.

    Raises:
        ConfigError: naming the file, the key and the reason.
    """
    path = Path(path)
    data = load_yaml_file(path)
    return scenario_from_dict(data, str(path), path.parent)


def scenario_from_dict(data: Any, source: str, base_dir: Path) -> Scenario:
    """Check a parsed scenario mapping and build the `Scenario`.

    Args:
        data: the parsed YAML (see the module docstring for the schema).
        source: file name used in error messages and kept as `Scenario.source`.
        base_dir: folder against which relative paths (vehicle file, GeoJSON) are resolved.

    Raises:
        ConfigError: naming the file, the key and the reason.
    """
    root_mapping(data, source, f"scenario keys ({', '.join(_TOP_KEYS)})")
    pilots_key = _pilots_key(data, source)
    reject_unknown(data, tuple(pilots_key if k == "pilots" else k for k in _TOP_KEYS), source)
    require_keys(data, _REQUIRED_KEYS, source, reason="missing (required)")
    name = _name(data["name"], source)
    description = _optional(data, "description", "", source, string)
    vehicle, vehicle_name = _vehicle(data["vehicle"], source, Path(base_dir))
    sensing = (sensing_from_config(data["sensing"], vehicle.mass_kg, source) if "sensing" in data
               else sensing_preset("perfect", vehicle.mass_kg))
    map_error = _optional(data, "map_error", MapErrorConfig(), source, map_error_from_config)
    if "bounds" in data and data["bounds"] is None:
        raise ConfigError(source, "bounds", "must be a mapping {min: [x, y, z], max: [x, y, z]}, got None")
    city = map_from_config(data["map"], data.get("bounds"), source, Path(base_dir))
    atmosphere, wind = _atmosphere(data.get("atmosphere", {}), source)
    goal_radius = _optional(data, "goal_radius_m", DEFAULT_GOAL_RADIUS_M, source, _goal_radius)
    timeout = None if data.get("timeout_s") is None else _timeout(data["timeout_s"], source, "timeout_s")
    seeds = _optional(data, "seeds", DEFAULT_SEEDS, source, _seeds)
    flown = _optional(data, pilots_key, DEFAULT_PILOTS, source, _pilots)
    physics_hz, control_hz = _rates(data, source, vehicle)
    legs, drawn = episode_list(data, source, city, vehicle.collision_radius_m, goal_radius, seeds[0])
    with named_as_drawn(source) if drawn else contextlib.nullcontext():  # drawn legs: checked as explicit ones
        city, prior, unmapped_ids = _true_and_prior(data, source, city, map_error, seeds, vehicle, legs)
        episodes = _episodes(legs, source, city, vehicle, goal_radius, timeout)
        if prior is not city:
            _check_prior(episodes, prior, vehicle.collision_radius_m, source)
        air = flight_atmosphere(atmosphere, city)
        _check_hover(episodes, vehicle, air, source)
    return Scenario(name=name, description=description, source=source, vehicle=vehicle,
                    vehicle_name=vehicle_name, city=city, atmosphere=atmosphere, wind=wind,
                    episodes=episodes, seeds=seeds, pilots=flown, physics_hz=physics_hz,
                    control_hz=control_hz, air=air, prior_map=prior, unmapped_ids=unmapped_ids,
                    map_error=map_error, sensing=sensing, raw=copy.deepcopy(dict(data)))


def flight_atmosphere(conditions: AtmosphereConditions, city: BuildingMap) -> Atmosphere:
    """The atmosphere table a scenario is flown in: JSBSim's for `conditions`, from `AIR_BELOW_FIELD_M` below
    the field to `AIR_ABOVE_CEILING_M` above the flight volume's ceiling (a vehicle that leaves the volume
    ends its episode within a control period, well inside the table)."""
    top = float(city.bounds_max_m[2]) + AIR_ABOVE_CEILING_M
    return Atmosphere.from_jsbsim(conditions, z_max_m=top, z_min_m=-AIR_BELOW_FIELD_M)


# ---- sections ----------------------------------------------------------------------------------------
def _name(value: Any, source: str) -> str:
    name = string(value, source, "name")
    if not _NAME_RE.fullmatch(name) or name.startswith(".") or "__" in name:
        raise ConfigError(source, "name", f"must match [A-Za-z0-9_.-]+, not start with '.' (a hidden file the "
                                          f"readers skip) and not contain '__' (it is used in file names), "
                                          f"got {value!r}")
    if len(name) > MAX_NAME_CHARS:
        raise ConfigError(source, "name", f"{len(name)} characters long, {name[:20]!r}...; at most {MAX_NAME_CHARS} "
                                          f"(it starts the run's file names)")
    return name


def _vehicle(value: Any, source: str, base_dir: Path) -> tuple[VehicleParams, str]:
    """The vehicle from a preset name, a vehicle file (relative to base_dir) or an inline mapping."""
    presets = ", ".join(preset_names())
    if isinstance(value, Mapping):
        try:
            params = vehicle_from_dict(value, source)
        except ConfigError as exc:
            key = "vehicle" if exc.key.startswith("<") else f"vehicle.{exc.key}"
            raise ConfigError(source, key, exc.reason) from None
        return params, params.name
    if not isinstance(value, str) or not value:
        raise ConfigError(source, "vehicle", f"must be a preset name ({presets}), a vehicle file path or a "
                                             f"mapping of vehicle parameters, got {value!r}")
    if value in preset_names():
        return load_vehicle(value), value
    path = Path(value)
    path = path if path.is_absolute() else base_dir / path
    if not path.is_file():
        raise ConfigError(source, "vehicle", f"unknown vehicle {value!r}: not a preset ({presets}) "
                                             f"and no vehicle file {path}")
    try:
        params = load_vehicle(path)
    except ConfigError as exc:
        raise ConfigError(source, "vehicle", f"in vehicle file {exc.source}: {exc.key}: {exc.reason}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(source, "vehicle", f"cannot read vehicle file {path}: {exc}") from None
    return params, params.name


def _atmosphere(value: Any, source: str) -> tuple[AtmosphereConditions, WindConditions]:
    cfg = _mapping(value, _ATMOSPHERE_KEYS, source, "atmosphere")
    elevation = number_in_range(cfg.get("elevation_m", 0.0), ELEVATION_RANGE_M, "m above mean sea level",
                                source, "atmosphere.elevation_m")
    offset = number_in_range(cfg.get("isa_offset_k", 0.0), ISA_OFFSET_RANGE_K, "K from the ISA day", source,
                             "atmosphere.isa_offset_k")
    wind = _vector3(cfg.get("wind_mps", [0.0, 0.0, 0.0]), source, "atmosphere.wind_mps", "m/s, ENU")
    level = cfg.get("turbulence", "none")
    if not isinstance(level, str):
        raise ConfigError(source, "atmosphere.turbulence",
                          f"must be one of {', '.join(t.value for t in TurbulenceLevel)}, got {level!r}")
    try:
        turbulence = TurbulenceLevel.parse(level)
    except ValueError as exc:
        raise ConfigError(source, "atmosphere.turbulence", str(exc)) from None
    reference = number_in_range(cfg.get("wind_reference_height_m", 10.0), REFERENCE_HEIGHT_RANGE_M,
                                "m above the field", source, "atmosphere.wind_reference_height_m")
    shear = _wind_shear(cfg.get("wind_shear", {"law": "uniform"}), reference, source)
    try:
        steady = WindConditions(wind, turbulence, shear)
    except ValueError as exc:
        raise ConfigError(source, "atmosphere.wind_mps", str(exc)) from None
    return AtmosphereConditions(elevation, offset), steady


def _wind_shear(value: Any, reference_m: float, source: str) -> WindShear:
    """The steady wind's height profile from `atmosphere.wind_shear` (see the module docstring)."""
    key = "atmosphere.wind_shear"
    cfg = _mapping(value, _SHEAR_KEYS, source, key)
    laws = ", ".join(v.value for v in ShearLaw)
    law = cfg.get("law")
    if law is None:
        raise ConfigError(source, f"{key}.law", f"missing (required: one of {laws})")
    if not isinstance(law, str) or law not in {v.value for v in ShearLaw}:
        raise ConfigError(source, f"{key}.law", f"unknown shear law {law!r} (known: {laws})")
    needs = {"power": "exponent", "log": "roughness_m"}.get(law)
    for name in ("exponent", "roughness_m"):
        if name in cfg and name != needs:
            raise ConfigError(source, f"{key}.{name}", f"does not apply to the {law} law, got {cfg[name]!r}")
    if needs is not None and needs not in cfg:
        raise ConfigError(source, f"{key}.{needs}", f"missing (required by the {law} law)")
    exponent = (number_in_range(cfg["exponent"], EXPONENT_RANGE, "dimensionless", source, f"{key}.exponent")
                if needs == "exponent" else None)
    roughness = (number_in_range(cfg["roughness_m"], ROUGHNESS_RANGE_M, "m", source, f"{key}.roughness_m")
                 if needs == "roughness_m" else None)
    try:
        return WindShear(ShearLaw(law), reference_m, exponent, roughness)
    except ValueError as exc:  # what is left: a reference height below the log law's floor 2 z0
        raise ConfigError(source, "atmosphere.wind_reference_height_m", str(exc)) from None


def seeds_problem(values: Any) -> tuple[int | None, str] | None:
    """Why `values` is not a non-empty list of distinct integers in [0, MAX_SEED]: (index or None, reason), or None.

    Shared by the scenario key `seeds` and the command line's `--seeds`, so both take the same seeds.
    """
    if not isinstance(values, (list, tuple)) or not values:
        return None, f"must be a non-empty list of distinct integers, got {values!r}"
    seen: dict[int, int] = {}
    for i, s in enumerate(values):
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= MAX_SEED:
            return i, f"must be an integer in [0, {MAX_SEED}], got {s!r}"
        if s in seen:
            return i, f"duplicate seed {s} (also at index {seen[s]}); seeds must be distinct"
        seen[s] = i
    return None


def _seeds(value: Any, source: str, key: str) -> tuple[int, ...]:
    problem = seeds_problem(value)
    if problem is not None:
        index, reason = problem
        raise ConfigError(source, key if index is None else f"{key}[{index}]", reason)
    return tuple(value)


def _pilots_key(data: Mapping, source: str) -> str:
    """The key the file lists its pilots under: `pilots`, or its old name (`OLD_PILOTS_KEY`, read with a
    `RenamedWarning`, a DeprecationWarning naming the file and the new key). Both at once are refused, naming the
    file."""
    if OLD_PILOTS_KEY not in data:
        return "pilots"
    if "pilots" in data:
        raise ConfigError(source, OLD_PILOTS_KEY, "the old name of the key 'pilots', which is also given; keep only "
                                                  "'pilots'")
    warnings.warn(f"{source}: the key {OLD_PILOTS_KEY!r} is renamed 'pilots'; the old key is read until the next "
                  f"release", RenamedWarning, stacklevel=2)
    return OLD_PILOTS_KEY


def _pilots(value: Any, source: str, key: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(source, key, f"must be a non-empty list drawn from {', '.join(PILOT_NAMES)} or plug-in "
                                       f"pilots (module:Class), got {value!r}")
    for i, m in enumerate(value):
        if not isinstance(m, str):
            raise ConfigError(source, f"{key}[{i}]", f"a pilot is named by a string, got {m!r}")
        try:
            pilots.pilot(m)  # a plug-in is imported here: a broken one is an error before anything flies
        except ValueError as exc:
            raise ConfigError(source, f"{key}[{i}]", str(exc)) from None
        if m in value[:i]:
            raise ConfigError(source, f"{key}[{i}]", f"duplicate pilot {m!r}")
    return tuple(pilots.ordered(value))


def _rates(data: Mapping, source: str, vehicle: VehicleParams) -> tuple[float, float]:
    physics = _optional(data, "physics_hz", DEFAULT_PHYSICS_HZ, source,
                        lambda v, s, k: number_in_range(v, (0.0, MAX_PHYSICS_HZ), "Hz", s, k, open_low=True))
    control = _optional(data, "control_hz", DEFAULT_CONTROL_HZ, source,
                        lambda v, s, k: number_in_range(v, (0.0, physics), "Hz (at most physics_hz)", s, k,
                                                        open_low=True))
    ratio, most = physics / control, MAX_PHYSICS_STEPS_PER_CONTROL_PERIOD
    if not ratio <= most:  # before any rounding: a tiny control_hz overflows it
        raise ConfigError(source, "control_hz", f"control_hz {control:g} Hz gives {ratio:.3g} physics steps per "
                                                f"control period at {physics:g} Hz; at most {most} (control_hz >= "
                                                f"{physics / most:g} Hz)")
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(source, "physics_hz", f"must be an integer multiple of control_hz {control:g} Hz, "
                                                f"got {physics:g} Hz (ratio {ratio:g})")
    problem = control_ratio_problem(physics, control)
    if problem is not None:
        raise ConfigError(source, "control_hz", problem)
    problem = motor_lag_problem(vehicle, physics)
    if problem is not None:
        raise ConfigError(source, "physics_hz", f"too slow for vehicle {vehicle.name}: {problem}")
    return physics, control


def _episodes(value: Any, source: str, city: BuildingMap, vehicle: VehicleParams, goal_radius: float,
              timeout: float | None) -> tuple[ScenarioEpisode, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(source, "episodes", f"must be a non-empty list of {{start: [x, y, z], goal: [x, y, z]}} "
                                              f"or a mapping {{random: N, ...}}, got {value!r}")
    radius = vehicle.collision_radius_m
    parsed = []
    for i, item in enumerate(value):
        key = f"episodes[{i}]"
        cfg = _mapping(item, _EPISODE_KEYS, source, key)
        for k in ("start", "goal"):
            if k not in cfg:
                raise ConfigError(source, f"{key}.{k}", "missing (required)")
        start = _vector3(cfg["start"], source, f"{key}.start", "m, ENU")
        goal = _vector3(cfg["goal"], source, f"{key}.goal", "m, ENU")
        _check_point(start, city, radius, source, f"{key}.start")
        _check_point(goal, city, radius, source, f"{key}.goal")
        r_goal = _goal_radius(cfg["goal_radius_m"], source, f"{key}.goal_radius_m") if "goal_radius_m" in cfg \
            else goal_radius
        distance = math.dist(start, goal)
        if distance <= r_goal:
            raise ConfigError(source, f"{key}.goal", f"{list(goal)} is {distance:.2f} m from the start, within the "
                                                     f"goal radius {r_goal:g} m: nothing to fly")
        if "timeout_s" in cfg:
            t_max = _timeout(cfg["timeout_s"], source, f"{key}.timeout_s")
        elif timeout is not None:
            t_max = timeout
        else:
            t_max = TIMEOUT_BASE_S + TIMEOUT_FLIGHT_TIME_FACTOR * distance / vehicle.controller.max_speed_m_s
            if t_max > MAX_TIMEOUT_S:
                raise ConfigError(source, key, f"the default timeout, {TIMEOUT_BASE_S:g} s + "
                                               f"{TIMEOUT_FLIGHT_TIME_FACTOR:g} x {distance:.0f} m / "
                                               f"{vehicle.controller.max_speed_m_s:g} m/s (the vehicle's "
                                               f"max_speed_m_s) = {t_max:.0f} s, exceeds {MAX_TIMEOUT_S:g} s: "
                                               f"set timeout_s or shorten the flight")
        parsed.append(ScenarioEpisode(i, Task(start_m=start, goal_m=goal, goal_radius_m=r_goal, timeout_s=t_max)))
    return tuple(parsed)


def _check_point(p: tuple[float, float, float], city: BuildingMap, radius: float, source: str, key: str) -> None:
    """Raise unless the collision sphere at p is clear of buildings and ground, in bounds and outside no-fly zones."""
    pts = np.array([p], dtype=float)
    c = city.clearance(pts, radius)
    if c.distance_m[0] <= 0.0:
        bid = int(c.building_id[0])
        what = "the ground" if bid < 0 else f"building {bid}"
        gap = float(c.distance_m[0]) + radius  # centre-to-surface distance, negative inside
        if gap >= 0.0:
            where = f"is {gap:.2f} m from {what}"
        else:
            where = "is below the ground" if bid < 0 else f"is inside {what}"
        raise ConfigError(source, key, f"{list(p)} {where}: must be more than the vehicle's collision radius "
                                       f"{radius:g} m from every building and the ground")
    if not city.in_bounds(pts, radius)[0]:
        lo, hi = city.bounds_min_m + radius, city.bounds_max_m - radius
        raise ConfigError(source, key, f"{list(p)} is out of bounds: with the vehicle's collision radius "
                                       f"{radius:g} m it must lie in x [{lo[0]:g}, {hi[0]:g}], "
                                       f"y [{lo[1]:g}, {hi[1]:g}], z [{lo[2]:g}, {hi[2]:g}] m")
    if city.in_no_fly(pts, radius)[0]:
        raise ConfigError(source, key, f"{list(p)} is in a no-fly zone (or within the vehicle's collision radius "
                                       f"{radius:g} m of one)")


def _true_and_prior(data: Mapping, source: str, world: BuildingMap, config: MapErrorConfig, seeds: tuple[int, ...],
                    vehicle: VehicleParams, legs: Any) -> tuple[BuildingMap, BuildingMap, tuple[int, ...]]:
    """The true city, the pilots' prior map and the ids only the truth has, from `map` (`world`), `unmapped` and
    `map_error` (drawn from `map_error.seed`, else the first of `seeds`, clear of every start and goal of `legs`,
    the episodes, and of `map_error.keep_clear`, by the collision radius plus `KEEP_CLEAR_MARGIN_M`). Without either
    key: (world, world, ())."""
    if "unmapped" not in data and config.exact:
        return world, world, ()
    unmapped = unmapped_from_config(data.get("unmapped", []), source, world)
    keep = _episode_points(legs, source) + list(config.keep_clear)
    seed = seeds[0] if config.seed is None else config.seed
    result = apply_map_error(world, unmapped, config, seed, keep, vehicle.collision_radius_m + KEEP_CLEAR_MARGIN_M)
    return result.truth, result.prior, result.unmapped_ids


def _episode_points(value: Any, source: str) -> list[tuple[float, float, float]]:
    """Every well-formed start and goal of `episodes` (ENU m); the rest is left for `_episodes` to name."""
    points = []
    for i, item in enumerate(value if isinstance(value, list) else []):
        for k in ("start", "goal"):
            if isinstance(item, Mapping) and k in item:
                points.append(_vector3(item[k], source, f"episodes[{i}].{k}", "m, ENU"))
    return points


def _check_prior(episodes: tuple[ScenarioEpisode, ...], prior: BuildingMap, radius: float, source: str) -> None:
    """Raise when a start or goal touches a building of the prior map: a pilot would believe it starts (or must
    end) inside one."""
    for ep in episodes:
        for k, p in (("start", ep.task.start_m), ("goal", ep.task.goal_m)):
            c = prior.clearance(np.array([p], dtype=float), radius)
            if c.distance_m[0] <= 0.0 and c.building_id[0] >= 0:
                raise ConfigError(source, f"episodes[{ep.index}].{k}",
                                  f"{list(p)} is within the vehicle's collision radius {radius:g} m of building "
                                  f"{int(c.building_id[0])} of the prior map (the map the pilots are given: map "
                                  f"with map_error and without unmapped)")


def _check_hover(episodes: tuple[ScenarioEpisode, ...], vehicle: VehicleParams, air: Atmosphere, source: str) -> None:
    """Raise when the vehicle's maximum thrust does not exceed its weight at the highest start or goal."""
    z_top = max(max(e.task.start_m[2], e.task.goal_m[2]) for e in episodes)
    conditions = air.conditions
    sigma = float(air.density_ratio(z_top))
    if vehicle.max_thrust_N(sigma) <= vehicle.weight_N:
        raise ConfigError(source, "atmosphere", f"{vehicle.name} cannot hover at z = {z_top:g} m above a field at "
                                                f"{conditions.elevation_m:g} m MSL, ISA{conditions.isa_offset_k:+g} K: "
                                                f"density ratio {sigma:.3f} gives at most "
                                                f"{vehicle.max_thrust_N(sigma):.1f} N of thrust for a weight of "
                                                f"{vehicle.weight_N:.1f} N")


# ---- value helpers (the checks themselves: uam_fdm.files.strict) -------------------------------------
def _mapping(value: Any, known: tuple[str, ...], source: str, key: str) -> Mapping:
    return mapping(value, source, key, known, expected=f"a mapping with keys from {', '.join(known)}")


def _optional(data: Mapping, key: str, default: Any, source: str, parse: Any) -> Any:
    """`parse(data[key], source, key)` when the key is present, else the default."""
    return parse(data[key], source, key) if key in data else default


def _goal_radius(value: Any, source: str, key: str) -> float:
    return number_in_range(value, (0.0, math.inf), "m", source, key, open_low=True)


def _timeout(value: Any, source: str, key: str) -> float:
    return number_in_range(value, (0.0, MAX_TIMEOUT_S), "s", source, key, open_low=True)


def _vector3(value: Any, source: str, key: str, unit: str) -> tuple[float, float, float]:
    x, y, z = numbers(value, 3, source, key, what=f"3 finite numbers [x, y, z] ({unit})")
    return (x, y, z)
