"""Held-out evaluation of a pilot on the navigation task: outcome counts with Wilson 95 % intervals.

Three disjoint city pools (seed ranges of `rl.task.cities`): training (0 on), validation (1,050,000
on: every choice made during training, e.g. which checkpoint ships) and test (1,000,000 on:
touched only to report). `eval_config(nav, n, pool)` gives the task on one of the held-out pools,
one city per episode; episode i of an evaluation seeded s is the same task (city, start, goal,
wind) for every pilot, whatever its decision rate, so pilots are compared on paired tasks.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np

from rl.env.held_out import BatchedPilot, FlownEpisodes, PolicyWeights, Progress, fly_episodes
from rl.env.split_vec_env import SplitVecEnv
from rl.env.world import NavBatch, NavWorld
from rl.pilots.potential_field import BatchedPotentialField, PotentialFieldConfig, gains_for
from rl.task.air import AirDistribution
from rl.task.cities import CityMixture
from rl.task.config import NavConfig
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.episode import Outcome
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS
from uam_fdm.stats import wilson_interval

VALIDATION_OFFSET = 50_000  # validation cities: eval seeds 1,050,000 on; test cities: 1,000,000 on
POOLS = ("test", "validation")



@dataclass(frozen=True)
class EvalResult:
    """Outcomes of an evaluation on held-out cities.

    Attributes:
        episodes: number of episodes; outcomes: count per outcome.
        success_rate, collision_rate: fractions; *_ci95: their Wilson 95 % intervals.
        mean_return: mean episode return; mean_time_s: mean flight time [s].
        per_episode: each episode's outcome, in episode order (for paired comparisons).
        pool: "test" or "validation"; seed: the evaluation seed.
        per_episode_levels: each episode's (sensing level, map-error level), in episode order.
    """

    episodes: int
    success_rate: float
    collision_rate: float
    success_ci95: tuple[float, float]
    collision_ci95: tuple[float, float]
    outcomes: dict[str, int]
    mean_return: float
    mean_time_s: float
    per_episode: tuple[str, ...]
    pool: str
    seed: int
    per_episode_levels: tuple[tuple[str, str], ...] = ()

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("per_episode")
        d.pop("per_episode_levels")
        return d


def eval_config(nav: NavConfig, episodes: int, pool: str = "test", turbulence: str | None = None,
                air: AirDistribution | None = None, sensing: str | None = None,
                map_error: str | None = None) -> NavConfig:
    """The task on a held-out pool ("test" or "validation"), one city per episode, and at most one
    turbulence stack per episode and level (each stack costs ~1 s of JSBSim at start-up; `NavWorld`).

    Args:
        air: the air to fly in (default: the task's); turbulence: one level replacing its levels.
        sensing: one sensing level (`uam_fdm.sensing.specs` preset) replacing the task's levels (None: the task's).
        map_error: one map-error level (`uam_fdm.city.map_error` preset) replacing the task's (None: the task's).

    Raises:
        ValueError: an unknown pool or level (`NavConfig` names the level).
    """
    if pool not in POOLS:
        raise ValueError(f"pool must be one of {POOLS}, got {pool!r}")
    air = air or nav.air
    if turbulence is not None:
        air = replace(air, turbulence=(turbulence,))
    return replace(nav, city_split="eval", city_pool_size=episodes, wind_pool_size=min(nav.wind_pool_size, episodes),
                   city_pool_offset=VALIDATION_OFFSET if pool == "validation" else 0, air=air,
                   sensing=nav.sensing if sensing is None else (sensing,),
                   map_error=nav.map_error if map_error is None else (map_error,))


def evaluate(pilot: BatchedPilot, nav: NavConfig, episodes: int, seed: int = 0, pool: str = "test",
             world: NavWorld | None = None, progress: Progress | None = None) -> EvalResult:
    """Fly `episodes` held-out episodes at once (episode i in pool city i), deterministically.

    Args:
        pilot: (observations, batch) -> actions.
        nav: the task definition; flown on `eval_config(nav, episodes, pool)` unless `world` is given.
        episodes: number of episodes.
        seed: slot i is seeded with seed + i.
        pool: "test" or "validation" (recorded in the result).
        world: a prebuilt world (its cities are used in order).
        progress: told (ended, episodes) after each decision in which episodes ended.

    Raises:
        ValueError: an episode's return or time is not finite (naming the metric; the task's `nav.reward`
            bounds its weights so that none is).
    """
    world = world or NavWorld(eval_config(nav, episodes, pool))
    return _result(fly_episodes(pilot, world, 0, episodes, seed, progress), pool, seed)


def evaluate_split(env: SplitVecEnv, weights: PolicyWeights, episodes: int, seed: int, pool: str,
                   world: NavWorld) -> EvalResult:
    """`evaluate` of the policy `weights` on `world`'s held-out tasks, the episodes shared by `env`'s processes
    (`SplitVecEnv.fly_held_out`): the same episodes and numbers as one process flying them all.

    Args:
        env: the training's environment, whose worker processes fly their shares.
        weights: the policy, as plain data.
        episodes, seed, pool: as `evaluate`'s.
        world: the evaluation world (`rl.env.split_vec_env.evaluation_world` of `env`'s world).

    Raises:
        ValueError: as `evaluate`; fewer episodes than processes.
    """
    return _result(env.fly_held_out(world, episodes, seed, weights), pool, seed)


def _result(flown: FlownEpisodes, pool: str, seed: int) -> EvalResult:
    """The outcomes as an `EvalResult` with Wilson intervals.

    Raises:
        ValueError: an episode's return or time is not finite (naming the metric).
    """
    outcomes, returns, times, episodes = list(flown.outcomes), flown.returns, flown.times_s, len(flown.outcomes)
    for key, values in (("mean_return", returns), ("mean_time_s", times)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:  # a mean of them would be inf or NaN, said by a NumPy warning at best
            raise ValueError(f"evaluation: {key} is not finite: episode(s) {bad[:5].tolist()} of {episodes} "
                             f"ended with {values[bad[0]]!r}")
    counts = {k: outcomes.count(k) for k in sorted(set(outcomes))}
    ns, nc = counts.get(Outcome.SUCCESS, 0), counts.get(Outcome.COLLISION, 0)
    return EvalResult(episodes, ns / episodes, nc / episodes, wilson_interval(ns, episodes),
                      wilson_interval(nc, episodes), counts, float(returns.mean()), float(times.mean()),
                      tuple(outcomes), pool, int(seed), flown.levels)


@dataclass(frozen=True)
class GroupRates:
    """Outcomes of the episodes of one group of an evaluation (e.g. the cities of one `CityMixture` component).

    Attributes:
        label: what the group is, in words; episodes: how many; outcomes: count per outcome.
        success_rate, collision_rate: fractions; *_ci95: their Wilson 95 % intervals.
    """

    label: str
    episodes: int
    success_rate: float
    success_ci95: tuple[float, float]
    collision_rate: float
    collision_ci95: tuple[float, float]
    outcomes: dict[str, int]


def rates_by_city_component(res: EvalResult, nav: NavConfig) -> tuple[GroupRates, ...]:
    """`res`'s outcomes per component of a `CityMixture` task (episode i flies the pool's city i, `evaluate`);
    empty for a task of one city distribution.

    Args:
        res: an evaluation of `nav` (its `eval_config`).
        nav: the task flown, whose city seeds and cities say each episode's component.
    """
    if not isinstance(nav.cities, CityMixture):
        return ()
    seeds = nav.city_seeds()
    kinds = [nav.cities.component(seeds[i % len(seeds)]) for i in range(res.episodes)]
    return tuple(_group(f"cities {dist.extent_m[0]:g}-{dist.extent_m[1]:g} m, streets {dist.street_width_m[0]:g}-"
                        f"{dist.street_width_m[1]:g} m",
                        [o for o, c in zip(res.per_episode, kinds, strict=True) if c == k])
                 for k, dist in enumerate(nav.cities.components))


def rates_by_level(res: EvalResult) -> tuple[GroupRates, ...]:
    """`res`'s outcomes per sensing level and per map-error level where it flew more than one of that axis, and per
    pair of them where it flew more than one of each (labels "sensing nominal", "map wrong", "nominal / wrong", in
    the presets' order); empty for an evaluation at one level of each."""
    levels = res.per_episode_levels
    order = {name: k for k, name in enumerate((*SENSING_LEVELS, *MAP_ERROR_LEVELS))}
    sensing, maps = {lv[0] for lv in levels}, {lv[1] for lv in levels}
    axes: list[tuple[str, Callable[[tuple[str, str]], tuple[str, ...]]]] = []
    if len(sensing) > 1:
        axes.append(("sensing {}", lambda lv: lv[:1]))
    if len(maps) > 1:
        axes.append(("map {}", lambda lv: lv[1:]))
    if len(sensing) > 1 and len(maps) > 1:
        axes.append(("{}", lambda lv: lv))
    out: list[GroupRates] = []
    for label, key in axes:
        for value in sorted({key(lv) for lv in levels}, key=lambda v: [order.get(x, len(order)) for x in v]):
            out.append(_group(label.format(" / ".join(value)),
                              [o for o, lv in zip(res.per_episode, levels, strict=True) if key(lv) == value]))
    return tuple(out)


def _group(label: str, outcomes: list[str]) -> GroupRates:
    """The rates of one group's outcomes (NaN and the whole unit interval for an empty group)."""
    n = len(outcomes)
    ns, nc = outcomes.count(Outcome.SUCCESS), outcomes.count(Outcome.COLLISION)
    return GroupRates(label, n, ns / n if n else float("nan"), wilson_interval(ns, n) if n else (0.0, 1.0),
                      nc / n if n else float("nan"), wilson_interval(nc, n) if n else (0.0, 1.0),
                      {o: outcomes.count(o) for o in sorted(set(outcomes))})


def paired_counts(a: EvalResult, b: EvalResult) -> dict[str, int]:
    """On the same episodes: how many only `a` succeeded, only `b`, both, neither."""
    if a.episodes != b.episodes or a.seed != b.seed or a.pool != b.pool:
        raise ValueError("paired counts need evaluations of the same episodes (count, seed and pool)")
    sa = np.array([o == Outcome.SUCCESS for o in a.per_episode])
    sb = np.array([o == Outcome.SUCCESS for o in b.per_episode])
    return {"only_a": int((sa & ~sb).sum()), "only_b": int((~sa & sb).sum()), "both": int((sa & sb).sum()),
            "neither": int((~sa & ~sb).sum())}


def evaluate_potential_field(nav: NavConfig, episodes: int, seed: int = 0, pool: str = "test",
                             world: NavWorld | None = None, gains: PotentialFieldConfig | None = None,
                             progress: Progress | None = None) -> EvalResult:
    """The reactive potential-field pilot (`rl.pilots.potential_field`) on the same tasks as
    `evaluate(..., nav, episodes, seed, pool)`, at the 50 Hz it was tuned for (decision_hz = control_hz: the
    tasks do not depend on it), with the gains the comparison flies it with (`gains_for`: tuned for the
    vehicle, or the small quad's scaled to the task).

    Args:
        world: the world whose tasks to fly, sharing its dynamics, fields, turbulence, cities and sensing (e.g. the
            policy's evaluation world).
        gains: other gains (e.g. a candidate while tuning).
        progress: as `evaluate`'s.
    """
    base_nav = replace(eval_config(nav, episodes, pool) if world is None else world.config,
                       decision_hz=nav.control_hz)
    base_world = NavWorld(base_nav, dynamics=world.dynamics if world else None,
                          atmosphere=world.atmospheres if world else None, wind_from=world, geometry_from=world)
    holder: dict[str, BatchedPotentialField] = {}

    flown = gains or gains_for(base_world.vehicle)

    def potential_field(obs: np.ndarray, batch: NavBatch) -> np.ndarray:
        if "pilot" not in holder:  # its sensor is built on the batch's cities
            holder["pilot"] = BatchedPotentialField(batch, flown)
        return holder["pilot"](obs, batch)

    return evaluate(potential_field, base_nav, episodes, seed=seed, pool=pool, world=base_world, progress=progress)
