"""The learned pilot's world distribution: procedurally generated cities and start/goal pairs.

Every training or evaluation city is `uam_fdm.city.generator.generate_city` with generator parameters
drawn from one seed, so a city is named by an integer and the same seed gives the same city on
any machine. Training draws from one seed range, evaluation from a disjoint one (held-out
cities): `TRAIN_SEEDS` and `EVAL_SEEDS`.

The parameter ranges span the shipped maps' styles (suburb: low, sparse; downtown: a tall core;
canyon: long narrow blocks), at a smaller extent so that an episode crosses a few blocks.

A task's cities come from one `CityDistribution`, or from a `CityMixture` of several (a vehicle trained in
its own districts and in smaller, narrower-street ones): each city seed names its component too.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.generator import CityGenConfig, generate_city
from uam_fdm.pilot import Task

TRAIN_SEEDS = range(100_000)
EVAL_SEEDS = range(1_000_000, 1_100_000)
# Draws of a start/goal pair before a city is declared to have none. A tall dense city at the shipped maps' scale
# needs ~800 on average (the canyon: free start and goal only in its building-free border); a city whose every
# pair is taken from the first few draws is drawn the same whatever this is.
MAX_TASK_DRAWS = 20_000
_MIXTURE_STREAM = 0xC17E5  # PCG64 stream tag of a city's component draw (apart from its parameters' 0x5EED)
_BOUNDS = {  # CityDistribution's numbers: (smallest, largest, whether the smallest itself is allowed)
    "extent_m": (0.0, math.inf, False), "ceiling_m": (0.0, math.inf, False), "margin_m": (0.0, math.inf, True),
    "block_size_m": (0.0, math.inf, False), "street_width_m": (0.0, math.inf, False), "density": (0.0, 1.0, True),
    "fill_low": (0.0, 0.9, False), "height_median_m": (0.0, math.inf, False), "height_sigma": (0.0, math.inf, True),
    "height_range_m": (0.0, math.inf, False), "core_probability": (0.0, 1.0, True),
    "core_height_factor": (0.0, math.inf, False), "merge_prob": (0.0, 1.0, True),
    "grid_yaw_deg": (-math.inf, math.inf, True), "yaw_jitter_deg": (0.0, math.inf, True)}
_SCALARS = ("ceiling_m", "margin_m", "core_probability")


def _number(v: Any) -> bool:
    """Whether `v` is a finite real number (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class CityDistribution:
    """Ranges of the generator parameters of training/evaluation cities (metres, degrees).

    Each city draws every parameter uniformly within its range from its own seed.

    Raises:
        ValueError: a range that is not [low, high] with low <= high inside its field's bounds, naming the field.
    """

    extent_m: tuple[float, float] = (260.0, 420.0)
    ceiling_m: float = 120.0
    margin_m: float = 20.0
    block_size_m: tuple[float, float] = (35.0, 120.0)
    street_width_m: tuple[float, float] = (12.0, 28.0)
    lots_per_block: tuple[int, int] = (1, 3)
    density: tuple[float, float] = (0.5, 0.95)
    fill_low: tuple[float, float] = (0.45, 0.75)
    height_median_m: tuple[float, float] = (12.0, 60.0)
    height_sigma: tuple[float, float] = (0.2, 0.5)
    height_range_m: tuple[float, float] = (8.0, 200.0)
    core_probability: float = 0.4
    core_height_factor: tuple[float, float] = (1.5, 3.5)
    merge_prob: tuple[float, float] = (0.0, 0.2)
    grid_yaw_deg: tuple[float, float] = (0.0, 90.0)
    yaw_jitter_deg: tuple[float, float] = (0.0, 8.0)

    def __post_init__(self) -> None:
        for name, (low, high, closed) in _BOUNDS.items():
            v = getattr(self, name)
            scalar = name in _SCALARS
            values = (v,) if scalar else tuple(v) if isinstance(v, (tuple, list)) and len(v) == 2 else ()
            if not (values and all(_number(x) and (low <= x if closed else low < x) and x <= high for x in values)
                    and values[0] <= values[-1]):
                what = "a number" if scalar else "a range [low, high] with low <= high"
                raise ValueError(f"{name} must be {what} in {'[' if closed else '('}{low:g}, {high:g}"
                                 f"{')' if math.isinf(high) else ']'}, got {v!r}")
        lots = self.lots_per_block
        if not (isinstance(lots, (tuple, list)) and len(lots) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) for v in lots) and 1 <= lots[0] <= lots[1]):
            raise ValueError(f"lots_per_block must be a range [low, high] of integers with 1 <= low <= high, "
                             f"got {lots!r}")

    def distribution(self, seed: int) -> CityDistribution:
        """The distribution city `seed` is drawn from: this one (as `CityMixture.distribution`)."""
        return self

    def params(self, seed: int) -> CityGenConfig:
        """The generator parameters of city `seed` (its own PCG64 stream, separate from the layout's)."""
        rng = np.random.Generator(np.random.PCG64([int(seed), 0x5EED]))

        def u(r: tuple[float, float]) -> float:
            return float(rng.uniform(r[0], r[1]))

        w, d = u(self.extent_m), u(self.extent_m)
        lots_lo, lots_hi = self.lots_per_block
        lots = (int(rng.integers(lots_lo, lots_hi + 1)), int(rng.integers(lots_lo, lots_hi + 1)))
        block = (u(self.block_size_m), u(self.block_size_m))
        fill_lo = u(self.fill_low)
        fill_hi = min(0.9, fill_lo + float(rng.uniform(0.05, 0.2)))
        core = rng.random() < self.core_probability
        core_factor = u(self.core_height_factor)
        return CityGenConfig(
            extent_m=(round(w, 1), round(d, 1)), margin_m=self.margin_m, ceiling_m=self.ceiling_m,
            block_size_m=(round(block[0], 1), round(block[1], 1)), street_width_m=round(u(self.street_width_m), 1),
            lots_per_block=lots, density=round(u(self.density), 3), fill_range=(round(fill_lo, 3), round(fill_hi, 3)),
            height_median_m=round(u(self.height_median_m), 1), height_sigma=round(u(self.height_sigma), 3),
            height_range_m=self.height_range_m, core_radius_m=round(0.3 * min(w, d), 1) if core else 0.0,
            core_height_factor=round(core_factor, 2) if core else 1.0, merge_prob=round(u(self.merge_prob), 3),
            grid_yaw_deg=round(u(self.grid_yaw_deg), 2), yaw_jitter_deg=round(u(self.yaw_jitter_deg), 2))

    def city(self, seed: int) -> BuildingMap:
        """City `seed`: deterministic, named `gen-<seed>`."""
        return generate_city(self.params(seed), int(seed), name=f"gen-{int(seed)}")



@dataclass(frozen=True)
class CityMixture:
    """Cities from several distributions: each city seed draws its component, by the weights, from its own
    PCG64 stream (apart from the one its parameters come from), so a seed names one city on any machine.

    Attributes:
        components: the distributions (at least one).
        weights: the share of cities from each, positive, summing to 1.

    Raises:
        ValueError: components and weights of different lengths, no component, or weights that are not
            positive or do not sum to 1, naming the key.
    """

    components: tuple[CityDistribution, ...]
    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "components", tuple(self.components))
        object.__setattr__(self, "weights", tuple(self.weights))
        if not self.components or not all(isinstance(c, CityDistribution) for c in self.components):
            raise ValueError(f"cities.components must be one or more city distributions, got {self.components!r}")
        w = self.weights
        if len(w) != len(self.components) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0 for v in w):
            raise ValueError(f"cities.weights must be {len(self.components)} positive numbers (one per component), "
                             f"got {list(w)}")
        if abs(sum(w) - 1.0) > 1e-9:
            raise ValueError(f"cities.weights must sum to 1, got {list(w)} (sum {sum(w):g})")

    def component(self, seed: int) -> int:
        """The index of the component city `seed` comes from."""
        u = np.random.Generator(np.random.PCG64([int(seed), _MIXTURE_STREAM])).random()
        edges = np.cumsum(self.weights)
        return min(int(np.searchsorted(edges, u, side="right")), len(edges) - 1)  # u ~ 1 - 1e-16 past a rounded sum

    def distribution(self, seed: int) -> CityDistribution:
        """The distribution city `seed` is drawn from: its component."""
        return self.components[self.component(seed)]

    def params(self, seed: int) -> CityGenConfig:
        """The generator parameters of city `seed`, drawn from its component."""
        return self.distribution(seed).params(seed)

    def city(self, seed: int) -> BuildingMap:
        """City `seed`: deterministic, named `gen-<seed>`."""
        return generate_city(self.params(seed), int(seed), name=f"gen-{int(seed)}")


def cities_from_dict(d: Any, key: str = "cities") -> CityDistribution | CityMixture:
    """The inverse of `dataclasses.asdict` for a task's cities: a `CityMixture` when `d` has components, else a
    `CityDistribution` (lists read as tuples).

    Raises:
        ValueError: unknown or bad settings, naming the key (e.g. "cities.components[1].street_width_m").
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"{key} must be a mapping of settings, got {d!r}")
    if "components" in d:
        bad = sorted(set(d) - {"components", "weights"})
        if bad:
            raise ValueError(f"unknown {key} settings {bad} (written by another version?)")
        parts = d["components"]
        if not isinstance(parts, list | tuple):
            raise ValueError(f"{key}.components must be a list of city distributions, got {parts!r}")
        weights = d.get("weights")
        if not isinstance(weights, list | tuple):
            raise ValueError(f"{key}.weights must be a list of numbers, got {weights!r}")
        return CityMixture(tuple(_distribution(c, f"{key}.components[{i}]") for i, c in enumerate(parts)),
                           tuple(weights))
    return _distribution(d, key)


def _distribution(d: Any, key: str) -> CityDistribution:
    """One `CityDistribution` from its settings (errors name `key`)."""
    if not isinstance(d, Mapping):
        raise ValueError(f"{key} must be a mapping of settings, got {d!r}")
    bad = sorted(set(d) - {f.name for f in fields(CityDistribution)})
    if bad:
        raise ValueError(f"unknown {key} settings {bad} (written by another version?)")
    values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    try:
        return CityDistribution(**values)
    except ValueError as exc:
        raise ValueError(f"{key}.{exc}") from None


@dataclass(frozen=True)
class TaskDistribution:
    """How start/goal pairs are drawn in free space of a city.

    Attributes:
        distance_m: straight-line start-goal distance range [m].
        altitude_m: start and goal altitude range above the ground [m].
        min_clearance_m: minimum clearance of start and goal from buildings and the ground [m]
            (on top of the vehicle's collision radius).
        bounds_margin_m: minimum distance of start and goal from the flight-volume sides [m].
        goal_radius_m: success radius [m].
        timeout_base_s, timeout_per_speed, timeout_per_climb: timeout = base + per_speed x distance /
            max speed + per_climb x |height difference| / max vertical speed [s] (the last term
            for a vehicle whose climb is much slower than its cruise; 0 for the small quad).
        timeout_cut_s: each leg's time limit is that rule's less a cut drawn uniformly in [0, timeout_cut_s] [s]
            (0: the rule's own), so that training covers time limits shorter than its own (a scenario's default
            rule, `compare.scenarios.scenario`, gives the UAM 11-14 s less). Drawn after the pair, so the pairs
            are those of no cut.
    """

    distance_m: tuple[float, float] = (40.0, 250.0)
    altitude_m: tuple[float, float] = (5.0, 30.0)
    min_clearance_m: float = 3.0
    bounds_margin_m: float = 15.0
    goal_radius_m: float = 3.0
    timeout_base_s: float = 20.0
    timeout_per_speed: float = 2.5
    timeout_per_climb: float = 0.0
    timeout_cut_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.timeout_cut_s < self.timeout_base_s:
            raise ValueError(f"timeout_cut_s must be in [0, timeout_base_s = {self.timeout_base_s:g}) s, got "
                             f"{self.timeout_cut_s!r}")

    def sample(self, city: BuildingMap, rng: np.random.Generator, radius_m: float, max_speed_m_s: float,
               attempts: int = MAX_TASK_DRAWS, difficulty: float = 1.0,
               max_vertical_speed_m_s: float | None = None, also: BuildingMap | None = None) -> Task:
        """A free start/goal pair in `city` drawn from `rng` (ENU metres).

        `also`: a second map of the same bounds the pair must be free in too (a map-error draw's prior, `city`
        being its truth); a pair free in `city` but not in `also` is drawn again. None (or `city` itself): the
        draws are those of `city` alone.

        `difficulty` in (0, 1] (the training curriculum) shrinks the distance range's upper end
        towards its lower end: d ~ U(d_min, d_min + difficulty x (d_max - d_min)). The draws from
        `rng` are the same whatever the difficulty.

        Raises:
            RuntimeError: no pair found within `attempts` draws (a city with no free space).
        """
        lo = np.asarray(city.bounds_min_m) + self.bounds_margin_m
        hi = np.asarray(city.bounds_max_m) - self.bounds_margin_m
        need = radius_m + self.min_clearance_m
        for _ in range(attempts):
            start = np.array([rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]), rng.uniform(*self.altitude_m)])
            d_lo, d_hi = self.distance_m
            dist = rng.uniform(d_lo, d_lo + difficulty * (d_hi - d_lo))
            heading = rng.uniform(-math.pi, math.pi)
            goal_alt = rng.uniform(*self.altitude_m)
            dz = goal_alt - start[2]
            horiz = math.sqrt(max(dist * dist - dz * dz, 1.0))
            goal = np.array([start[0] + horiz * math.cos(heading), start[1] + horiz * math.sin(heading), goal_alt])
            if not (np.all(goal[:2] >= lo[:2]) and np.all(goal[:2] <= hi[:2])):
                continue
            if (city.clearance_one(start[0], start[1], start[2], radius_m) < need
                    or city.clearance_one(goal[0], goal[1], goal[2], radius_m) < need):
                continue
            if also is not None and also is not city and (
                    also.clearance_one(start[0], start[1], start[2], radius_m) < need
                    or also.clearance_one(goal[0], goal[1], goal[2], radius_m) < need):
                continue
            d = float(np.linalg.norm(goal - start))
            timeout = self.timeout_s(d, dz, max_speed_m_s, max_vertical_speed_m_s)
            if self.timeout_cut_s:
                timeout -= rng.uniform(0.0, self.timeout_cut_s)
            return Task((float(start[0]), float(start[1]), float(start[2])),
                        (float(goal[0]), float(goal[1]), float(goal[2])), self.goal_radius_m, round(timeout, 2))
        raise RuntimeError(f"no free start/goal pair in {city.name!r} after {attempts} draws")

    def timeout_s(self, distance_m: float, climb_m: float, max_speed_m_s: float,
                  max_vertical_speed_m_s: float | None = None) -> float:
        """The time limit of a leg [s]: base + per_speed x distance / max speed + per_climb x |climb| / max
        vertical speed (distance: straight start-goal [m]; climb: goal height minus start height [m]).

        Raises:
            ValueError: timeout_per_climb is set and max_vertical_speed_m_s is not given.
        """
        timeout = self.timeout_base_s + self.timeout_per_speed * distance_m / max_speed_m_s
        if self.timeout_per_climb:
            if max_vertical_speed_m_s is None:
                raise ValueError("timeout_per_climb needs the vehicle's max_vertical_speed_m_s")
            timeout += self.timeout_per_climb * abs(climb_m) / max_vertical_speed_m_s
        return timeout


def boxes_only(city: BuildingMap) -> bool:
    """Whether every obstacle of `city` is a box (`Building`), as the vectorised sensor requires."""
    return all(isinstance(b, Building) for b in city.buildings)
