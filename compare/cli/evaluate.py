"""`evaluate-policy`: fly a policy, and the potential-field pilot on the same tasks, on held-out cities; the rates
with their Wilson intervals, per kind of city where the task mixes them, and last one JSON line."""
from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compare.cli.common import check_ranges, one_torch_thread, turbulence_levels
from compare.cli.printout import json_line
from compare.scenarios.scenario import MAX_SEED
from rl.task.air import AIR_LEVELS, AirDistribution
from uam_fdm.air.atmosphere import ELEVATION_RANGE_M, ISA_OFFSET_RANGE_K
from uam_fdm.air.wind import MAX_STEADY_WIND_M_S

if TYPE_CHECKING:
    from rl.task.config import NavConfig
    from rl.training.evaluation import EvalResult

AIR_FIELDS = 16
"""Fields drawn (and tabulated) for air given as ranges (--air): each episode flies one."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `evaluate-policy` to the command line."""
    ev = sub.add_parser("evaluate-policy", help="fly a policy (and the potential-field baseline) on held-out cities; "
                        "last line is JSON")
    ev.add_argument("policy", nargs="?", type=Path, default=None, help="policy folder (default: the shipped policy)")
    ev.add_argument("--episodes", type=int, default=1000, help="episodes, one held-out city each (default 1000)")
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
    ev.add_argument("--no-baseline", action="store_true", help="skip the potential-field pilot on the same tasks")
    ev.set_defaults(func=evaluate_policy)


def evaluate_policy(args: argparse.Namespace) -> int:
    """`evaluate-policy`: the options checked before anything is loaded, then the policy and (unless
    --no-baseline) the potential field on the same tasks; their rates, and last one JSON line."""
    from rl.env.world import NavWorld
    from rl.pilots.learned import load_policy
    from rl.task.vehicles import in_task_space, task_for
    from rl.training.evaluation import eval_config, evaluate, evaluate_potential_field, paired_counts

    if args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes}: must be >= 1")
    check_ranges({"--episodes": (args.episodes, 1, pool_cities(args.pool)), "--seed": (args.seed, 0, MAX_SEED)})
    one_torch_thread()
    air = air_from_options(args)  # before anything is loaded: a bad option is named at once
    policy = load_policy(args.policy)
    own = policy.nav if args.task == "own" else in_task_space(policy.nav, task_for(policy.nav.vehicle, envelope=True))
    nav = eval_config(own, args.episodes, pool=args.pool, air=air(own.air))
    world = NavWorld(nav)
    res = evaluate(lambda obs, _batch: policy.act_batch(obs), nav, args.episodes, seed=args.seed, pool=args.pool,
                   world=world)
    a = nav.air
    out: dict[str, Any] = {
        "pool": args.pool, "episodes": res.episodes, "seed": args.seed, "task": args.task,
        "turbulence": ",".join(a.turbulence), "steady_wind_max_m_s": a.steady_wind_max_m_s,
        "elevation_m": list(a.elevation_m), "isa_offset_k": list(a.isa_offset_k), "fields": len(world.atmospheres),
        "policy": str(policy.folder), "success_rate": res.success_rate, "success_ci95": res.success_ci95,
        "collision_rate": res.collision_rate, "collision_ci95": res.collision_ci95, "outcomes": res.outcomes}
    print(f"{res.episodes} {args.pool} episodes in the {'policy' if args.task == 'own' else 'envelope'}'s task "
          f"({'/'.join(a.turbulence)} turbulence, steady wind up to "
          f"{a.steady_wind_max_m_s:g} m/s, {describe_fields(a)}, {policy.nav.vehicle}), Wilson 95 % intervals:")
    print(_rates_line("ppo", res))
    results = {"ppo": res}
    if not args.no_baseline:
        # the same tasks (cities, legs, wind), the reactive pilot at the 50 Hz it was tuned for
        ex = evaluate_potential_field(nav, args.episodes, seed=args.seed, pool=args.pool, world=world)
        pairs = paired_counts(res, ex)
        print(_rates_line("potential field", ex))
        print(f"  paired: only ppo succeeded {pairs['only_a']}, only the potential field {pairs['only_b']}, "
              f"both {pairs['both']}, neither {pairs['neither']}")
        out.update(expert_success_rate=ex.success_rate, expert_success_ci95=ex.success_ci95,
                   expert_collision_rate=ex.collision_rate, expert_collision_ci95=ex.collision_ci95,
                   paired=pairs)
        results["potential field"] = ex
    out.update(_by_city_kind(results, nav))
    print(json_line(out))  # a kind of city that got no episodes has NaN rates: null here
    return 0


def _rates_line(name: str, res: EvalResult) -> str:
    """One pilot's success and collision rates with their intervals, and its outcomes."""
    return (f"  {name:<16} success {res.success_rate:6.1%} [{res.success_ci95[0]:.1%}, {res.success_ci95[1]:.1%}]"
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
            print(f"    {name:<15} {g.label}: {g.episodes} episodes, success {g.success_rate:.1%} "
                  f"[{g.success_ci95[0]:.1%}, {g.success_ci95[1]:.1%}], collisions {g.collision_rate:.1%} "
                  f"[{g.collision_ci95[0]:.1%}, {g.collision_ci95[1]:.1%}]  {g.outcomes}")
    return {"by_city_kind": {name: [asdict(g) for g in rows] for name, rows in groups.items()}}


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
