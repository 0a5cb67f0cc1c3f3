"""`evaluate-policy`: fly a policy, and the potential-field pilot (`apf`) on the same tasks, on held-out cities; the
rates with their Wilson intervals, per kind of city where the task mixes them, and last one JSON line. Progress goes
to stderr (`--no-progress`: none)."""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compare.cli.common import check_ranges, one_torch_thread, turbulence_levels
from compare.cli.printout import json_line
from compare.scenarios.levels import MAP_ERROR_LEVELS, SENSING_LEVELS
from compare.scenarios.scenario import MAX_SEED
from rl.task.air import AIR_LEVELS, AirDistribution
from uam_fdm.air.atmosphere import ELEVATION_RANGE_M, ISA_OFFSET_RANGE_K
from uam_fdm.air.wind import MAX_STEADY_WIND_M_S
from uam_fdm.stats import wilson_interval

if TYPE_CHECKING:
    from rl.task.config import NavConfig
    from rl.training.evaluation import EvalResult

AIR_FIELDS = 16
"""Fields drawn (and tabulated) for air given as ranges (--air): each episode flies one."""
DEFAULT_EPISODES = 300
"""Episodes by default: a few minutes on two cores, and a Wilson 95 % interval of about +/-5.6 points (`--help`)."""
BASELINE = "apf"
"""The potential-field pilot's one name: the comparison's pilot name, the rows and the JSON keys here."""
OLD_JSON_KEYS = {f"expert_{k}": f"{BASELINE}_{k}" for k in ("success_rate", "success_ci95", "collision_rate",
                                                             "collision_ci95")}
"""The JSON line's keys before the potential field was called `apf` everywhere (old -> new): still written, with
the same values, until the next release, for scripts that read them."""
PROGRESS_STEPS = 10
"""Progress lines per pilot: one each time another tenth of the episodes has ended."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `evaluate-policy` to the command line; `{name}` in its help is filled by `_shown_defaults`."""
    ev = sub.add_parser("evaluate-policy", help="fly a policy and the potential-field pilot (apf) on the same "
                        "held-out cities; last line is JSON", help_values=_shown_defaults,
                        description="Fly a policy and the potential-field pilot (apf) on the same held-out cities: "
                        "success and collision rates with Wilson 95 % intervals, and last one JSON line (its "
                        "apf_* keys were expert_* before; those are written too until the next release).")
    ev.add_argument("policy", nargs="?", type=Path, default=None, help="policy folder (default: the shipped policy)")
    ev.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                    help="episodes, one held-out city each (default {episodes}: a success rate's Wilson 95 %% "
                         "interval is then about +/-{half_50} points at 50 %% success, +/-{half_95} near 95 %%; "
                         "1000 episodes: +/-{half_50_1000} and +/-{half_95_1000})")
    ev.add_argument("--pool", choices=("test", "validation"), default="test",
                    help="held-out city pool (default test; validation is for choices made while developing)")
    ev.add_argument("--seed", type=int, default=0, help="seed of the episodes (default 0)")
    ev.add_argument("--task", choices=("own", "envelope"), default="own",
                    help="whose cities, legs and air: the policy's own (default), or its vehicle's envelope "
                         "(`train --envelope`: to compare policies trained on different tasks on the same legs)")
    ev.add_argument("--air", choices=tuple(AIR_LEVELS), default=None,
                    help="the benchmark's air levels: fields drawn in its elevation and temperature ranges "
                         "(default: the --task's air)")
    ev.add_argument("--elevation", type=float, default=None, metavar="M",
                    help="one field elevation above mean sea level [m] (instead of --air)")
    ev.add_argument("--isa-offset", type=float, default=None, metavar="K",
                    help="one ISA temperature offset [K] (instead of --air)")
    ev.add_argument("--wind-max", type=float, default=None, metavar="M/S",
                    help="steady wind speed uniform in [0, this] (default: the --task's air's)")
    ev.add_argument("--turbulence", default=None, metavar="LEVELS",
                    help="none|light|moderate|severe, or several comma-separated, one drawn per episode "
                         "(default: the --task's air's)")
    ev.add_argument("--sensing", choices=SENSING_LEVELS, default=None,
                    help="fly every episode at this sensing level (docs/sensing.md): below perfect the policy "
                         "observes its navigation estimate and its reduced lidar, as in training; the potential "
                         "field still reads its true position and the map (default: the policy's task's levels)")
    ev.add_argument("--map-error", choices=MAP_ERROR_LEVELS, default=None,
                    help="fly every episode with this map error (docs/sensing.md): the route is planned on the "
                         "prior map, collisions are with the city as it stands; not with --sensing perfect, whose "
                         "senses in the environment are the truth's (default: the policy's task's levels)")
    ev.add_argument("--no-baseline", action="store_true", help="skip the potential-field pilot (apf) on the same "
                                                               "tasks")
    ev.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    ev.set_defaults(func=evaluate_policy)


def interval_half_width(n: int, rate: float) -> float:
    """Half the width [percentage points] of the Wilson 95 % interval of a success rate `rate` measured on `n`
    episodes."""
    low, high = wilson_interval(round(rate * n), n)
    return 50.0 * (high - low)


def _shown_defaults() -> dict[str, str]:
    """`evaluate-policy --help`'s default and the interval it buys."""
    return {"episodes": str(DEFAULT_EPISODES),
            **{f"half_{round(100 * rate)}{'' if n == DEFAULT_EPISODES else f'_{n}'}":
               f"{interval_half_width(n, rate):.1f}" for n in (DEFAULT_EPISODES, 1000) for rate in (0.5, 0.95)}}


class ProgressLines:
    """Progress of one pilot's evaluation on stderr: a line each time another tenth of its episodes has ended.

    Args:
        pilot: the pilot's name; enabled: False prints nothing.
    """

    def __init__(self, pilot: str, enabled: bool = True) -> None:
        self.pilot, self.enabled = pilot, enabled
        self.t0 = time.perf_counter()
        self.shown = 0  # tenths already said

    def __call__(self, ended: int, episodes: int) -> None:
        tenths = ended * PROGRESS_STEPS // episodes
        if self.enabled and tenths > self.shown:
            self.shown = tenths
            print(f"evaluate-policy: {self.pilot}: {ended}/{episodes} episodes ended ({ended / episodes:.0%}, "
                  f"{time.perf_counter() - self.t0:.0f} s)", file=sys.stderr, flush=True)


def _say(text: str, enabled: bool) -> None:
    """One progress line on stderr (what is being built or flown), unless --no-progress."""
    if enabled:
        print(f"evaluate-policy: {text}", file=sys.stderr, flush=True)


def evaluate_policy(args: argparse.Namespace) -> int:
    """`evaluate-policy`: the options checked before anything is loaded, then the policy and (unless
    --no-baseline) the potential field on the same tasks; their rates, and last one JSON line."""
    from rl.env.world import NavWorld
    from rl.pilots.learned import load_policy
    from rl.task.vehicles import in_task_space, task_for
    from rl.training.evaluation import eval_config, evaluate, evaluate_potential_field, paired_counts

    if args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes}: must be >= 1")
    if args.sensing == "perfect" and args.map_error not in (None, "exact"):
        raise ValueError(f"--sensing perfect --map-error {args.map_error}: with nothing sensed, the comparison's "
                         f"pilots see only the prior map, while the environment's perfect senses are the truth's; "
                         f"fly it with `uam-compare run SCENARIO --sensing perfect --map-error {args.map_error}`, or "
                         f"evaluate at nominal or degraded sensing")
    check_ranges({"--episodes": (args.episodes, 1, pool_cities(args.pool)), "--seed": (args.seed, 0, MAX_SEED)})
    one_torch_thread()
    air = air_from_options(args)  # before anything is loaded: a bad option is named at once
    policy = load_policy(args.policy)
    own = policy.nav if args.task == "own" else in_task_space(policy.nav, task_for(policy.nav.vehicle, envelope=True))
    nav = eval_config(own, args.episodes, pool=args.pool, air=air(own.air), sensing=args.sensing,
                      map_error=args.map_error)
    show = not args.no_progress
    _say(f"building {args.episodes} {args.pool} cities, their sensing and air", show)
    world = NavWorld(nav)
    _say(f"flying ppo on {args.episodes} episodes at once", show)
    res = evaluate(lambda obs, _batch: policy.act_batch(obs), nav, args.episodes, seed=args.seed, pool=args.pool,
                   world=world, progress=ProgressLines("ppo", show))
    a = nav.air
    out: dict[str, Any] = {
        "pool": args.pool, "episodes": res.episodes, "seed": args.seed, "task": args.task,
        "turbulence": ",".join(a.turbulence), "steady_wind_max_m_s": a.steady_wind_max_m_s,
        "elevation_m": list(a.elevation_m), "isa_offset_k": list(a.isa_offset_k), "fields": len(world.atmospheres),
        "sensing": ",".join(nav.sensing), "map_error": ",".join(nav.map_error),
        "policy": str(policy.folder), "success_rate": res.success_rate, "success_ci95": res.success_ci95,
        "collision_rate": res.collision_rate, "collision_ci95": res.collision_ci95, "outcomes": res.outcomes}
    results = {"ppo": res}
    if not args.no_baseline:
        # the same tasks (cities, legs, wind), the reactive pilot at the 50 Hz it was tuned for
        _say(f"flying {BASELINE} (the potential field) on the same {args.episodes} episodes", show)
        results[BASELINE] = evaluate_potential_field(nav, args.episodes, seed=args.seed, pool=args.pool, world=world,
                                                     progress=ProgressLines(BASELINE, show))
    print(f"{res.episodes} {args.pool} episodes in the {'policy' if args.task == 'own' else 'envelope'}'s task "
          f"({'/'.join(a.turbulence)} turbulence, steady wind up to "
          f"{a.steady_wind_max_m_s:g} m/s, {describe_fields(a)}, {'/'.join(nav.sensing)} sensing, "
          f"{'/'.join(nav.map_error)} map, {policy.nav.vehicle}), Wilson 95 % intervals:")
    for name, r in results.items():
        print(_rates_line(name, r))
    if BASELINE in results:
        ex = results[BASELINE]
        pairs = paired_counts(res, ex)
        print(f"  paired: only ppo succeeded {pairs['only_a']}, only {BASELINE} {pairs['only_b']}, "
              f"both {pairs['both']}, neither {pairs['neither']}")
        out.update({f"{BASELINE}_success_rate": ex.success_rate, f"{BASELINE}_success_ci95": ex.success_ci95,
                    f"{BASELINE}_collision_rate": ex.collision_rate, f"{BASELINE}_collision_ci95": ex.collision_ci95,
                    "paired": pairs})
        out.update({old: out[new] for old, new in OLD_JSON_KEYS.items()})
    out.update(_by_city_kind(results, nav))
    out.update(_by_level(results))
    print(json_line(out))  # a kind of city that got no episodes has NaN rates: null here
    return 0


def _rates_line(name: str, res: EvalResult) -> str:
    """One pilot's success and collision rates with their intervals, and its outcomes."""
    return (f"  {name:<5} success {res.success_rate:6.1%} [{res.success_ci95[0]:.1%}, {res.success_ci95[1]:.1%}]"
            f"  collisions {res.collision_rate:5.1%} [{res.collision_ci95[0]:.1%}, {res.collision_ci95[1]:.1%}]"
            f"  {res.outcomes}")


def _by_city_kind(results: dict[str, EvalResult], nav: NavConfig) -> dict[str, Any]:
    """Where the task's cities mix several kinds: each pilot's rates per kind, printed; their JSON entry."""
    from rl.training.evaluation import rates_by_city_component

    groups = {name: rates_by_city_component(res, nav) for name, res in results.items()}
    if not groups["ppo"]:
        return {}
    print("  by kind of city:")
    for name, rows in groups.items():
        for g in rows:
            print(f"    {name:<5} {g.label}: {g.episodes} episodes, success {g.success_rate:.1%} "
                  f"[{g.success_ci95[0]:.1%}, {g.success_ci95[1]:.1%}], collisions {g.collision_rate:.1%} "
                  f"[{g.collision_ci95[0]:.1%}, {g.collision_ci95[1]:.1%}]  {g.outcomes}")
    by_kind = {name: [asdict(g) for g in rows] for name, rows in groups.items()}
    if BASELINE in by_kind:  # its old key, as OLD_JSON_KEYS, until the next release
        by_kind["potential field"] = by_kind[BASELINE]
    return {"by_city_kind": by_kind}


def _by_level(results: dict[str, EvalResult]) -> dict[str, Any]:
    """Where the episodes drew several sensing or map-error levels: each pilot's rates per level (and pair of
    levels), printed; their JSON entry."""
    from rl.training.evaluation import rates_by_level

    groups = {name: rates_by_level(res) for name, res in results.items()}
    if not groups["ppo"]:
        return {}
    print("  by sensing and map-error level:")
    for name, rows in groups.items():
        for g in rows:
            print(f"    {name:<5} {g.label:<20} {g.episodes:>4} episodes, success {g.success_rate:6.1%} "
                  f"[{g.success_ci95[0]:.1%}, {g.success_ci95[1]:.1%}], collisions {g.collision_rate:5.1%} "
                  f"[{g.collision_ci95[0]:.1%}, {g.collision_ci95[1]:.1%}]  {g.outcomes}")
    return {"by_level": {name: [asdict(g) for g in rows] for name, rows in groups.items()}}


def pool_cities(pool: str) -> int:
    """The held-out cities of `pool` ("test" or "validation"): the most episodes `evaluate-policy` flies, one city
    each (past them a test evaluation would fly the validation cities)."""
    from rl.task.cities import EVAL_SEEDS
    from rl.training.evaluation import VALIDATION_OFFSET

    return VALIDATION_OFFSET if pool == "test" else len(EVAL_SEEDS) - VALIDATION_OFFSET


def air_from_options(args: argparse.Namespace) -> Callable[[AirDistribution], AirDistribution]:
    """The air `evaluate-policy` flies, from --air or --elevation/--isa-offset, --wind-max and --turbulence, as a
    function of the task's air (what is not given stays the task's). Checked here, before any work.

    Raises:
        ValueError: conflicting or out-of-range options, naming them.
    """
    if args.air is not None and (args.elevation is not None or args.isa_offset is not None):
        raise ValueError("--air and --elevation/--isa-offset: give a level or an explicit field, not both")
    for name, value, valid in (("--elevation", args.elevation, ELEVATION_RANGE_M),
                               ("--isa-offset", args.isa_offset, ISA_OFFSET_RANGE_K)):
        if value is not None and not valid[0] <= value <= valid[1]:
            raise ValueError(f"{name} {value:g}: must be within [{valid[0]:g}, {valid[1]:g}]")
    # the steady-wind bound of the wind model, which scenario files obey too: well above any wind a multicopter
    # flies in (the trained air reaches 8 to 12 m/s), so past it a value is a unit or typing mistake, not a test
    if args.wind_max is not None and not 0.0 <= args.wind_max <= MAX_STEADY_WIND_M_S:
        raise ValueError(f"--wind-max {args.wind_max:g}: must be a steady wind speed in [0, {MAX_STEADY_WIND_M_S:g}] "
                         f"m/s")
    levels = turbulence_levels(args.turbulence) if args.turbulence is not None else None

    def air(trained: AirDistribution) -> AirDistribution:
        elevation, offset = trained.elevation_m, trained.isa_offset_k
        if args.air is not None:
            elevation, offset = AIR_LEVELS[args.air].elevation_m, AIR_LEVELS[args.air].isa_offset_k
        if args.elevation is not None:
            elevation = (args.elevation, args.elevation)
        if args.isa_offset is not None:
            offset = (args.isa_offset, args.isa_offset)
        return replace(trained, elevation_m=elevation, isa_offset_k=offset, turbulence=levels or trained.turbulence,
                       steady_wind_max_m_s=trained.steady_wind_max_m_s if args.wind_max is None else args.wind_max,
                       pool_size=max(trained.pool_size, AIR_FIELDS))

    return air


def describe_fields(air: AirDistribution) -> str:
    """The fields of `air` in words: "field 0 m, ISA +0 K" or "fields 1800-2600 m, ISA +20-30 K"."""
    def span(r: tuple[float, float], fmt: str) -> str:
        return fmt.format(r[0]) if r[0] == r[1] else f"{fmt.format(r[0])}-{fmt.format(r[1]).lstrip('+')}"

    many = air.elevation_m[0] != air.elevation_m[1] or air.isa_offset_k[0] != air.isa_offset_k[1]
    return f"field{'s' if many else ''} {span(air.elevation_m, '{:g}')} m, ISA {span(air.isa_offset_k, '{:+g}')} K"
