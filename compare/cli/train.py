"""`train`: train the learned pilot with PPO. The options' defaults are `TrainConfig`'s (rl/training/config.py),
read from it, never restated; the vehicle's task (`rl.task.vehicles`) gives the cities, air and observation, or
`--scenario` a scenario file's map and air (`rl.env.ground`). It ends with the kept model's validation and what to
do next with the policy."""
from __future__ import annotations

import argparse
import shlex
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compare.cli.common import check_ranges, option, turbulence_levels
from compare.results.outputs import check_output_dir
from compare.scenarios.scenario import MAX_SEED, load_scenario
from rl.policies.folder import PROVENANCE, TENSORBOARD, PolicyFolder
from rl.sensing.observation import ObservedContext

if TYPE_CHECKING:
    from rl.env.ground import TrainingGround
    from rl.sensing.route import RouteConfig
    from rl.task.config import NavConfig
    from rl.training.config import TrainConfig

MAX_TIMESTEPS = 10**12
MAX_ENVS = 65_536  # vehicles stepped in one call: far beyond one machine's memory already
MAX_EVAL_EPISODES = 1_000_000
MAX_CITY_POOL = 1_000_000

CONFIG_FIELDS = {"preset": "preset", "timesteps": "total_timesteps", "envs": "n_envs", "seed": "seed",
                 "eval_every": "eval_every", "eval_episodes": "eval_episodes", "checkpoint_every": "checkpoint_every",
                 "record_flights": "record_flights", "env_processes": "env_processes"}
"""The options (by their `argparse` name) that set a `TrainConfig` field of their own (their default: the field's)."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `train` to the command line; `{name}` in its help is filled by `_shown_defaults`."""
    tr = sub.add_parser("train", help="train the learned pilot with PPO from scratch on the batched environment",
                        help_values=_shown_defaults)
    tr.add_argument("--preset", default=None, help="PPO preset (default {preset}; {presets})")
    tr.add_argument("--timesteps", type=int, default=None, help="decisions, all vehicles (default {timesteps})")
    tr.add_argument("--envs", type=int, default=None, help="vehicles stepped together (default {envs})")
    tr.add_argument("--seed", type=int, default=None, help="the one seed of the run (default {seed})")
    tr.add_argument("--env-processes", type=int, default=None, metavar="N",
                    help="processes stepping the vehicles, each its share (the same transitions for any N; about "
                         "N times the environment's speed on N free cores; generated cities only; default "
                         "{env_processes})")
    _add_task_options(tr)
    tr.add_argument("--no-curriculum", dest="curriculum", action="store_false",
                    help="full-length legs from the start (default: success-gated curriculum)")
    tr.add_argument("--curriculum-level-steps", type=int, default=None, metavar="N",
                    help="a curriculum level lasts at most N timesteps, then the legs lengthen even if training "
                         "success is under the gate (0: until the gate is met; default {level_steps})")
    tr.add_argument("--eval-every", type=int, default=None,
                    help="timesteps between validation evaluations (default {eval_every})")
    tr.add_argument("--eval-episodes", type=int, default=None,
                    help="validation episodes per evaluation (default {eval_episodes})")
    tr.add_argument("--checkpoint-every", type=int, default=None,
                    help="timesteps between checkpoints (0: none; default {checkpoint_every})")
    tr.add_argument("--record-flights", type=int, default=None, metavar="N",
                    help="fixed validation tasks flown and recorded at step 0 and every evaluation, for "
                         "view-training, the report and export (default {record_flights}; 0: none)")
    tr.add_argument("--resume", type=Path, default=None, help="resume from a checkpoint or policy folder")
    tr.add_argument("--out", type=Path, default=Path("runs/policy"),
                    help="policy folder to write (default runs/policy); an existing non-empty one is refused "
                         "unless --resume or --overwrite")
    tr.add_argument("--overwrite", action="store_true", help="replace the policy in a non-empty --out")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.set_defaults(func=train)


def _add_task_options(tr: argparse.ArgumentParser) -> None:
    """The options that change the vehicle's task: vehicle, cities, air, observation."""
    tr.add_argument("--vehicle", default=None, help="the vehicle and its task (rl/task/vehicles.py): {vehicles}")
    tr.add_argument("--scenario", type=Path, default=None, metavar="FILE",
                    help="train in a scenario file's map and air instead of generated cities: legs drawn in its map "
                         "by the vehicle's task, validated on other legs there, full length from the start (no "
                         "curriculum); its own episodes are left for `run FILE --policy OUT`. Its vehicle is the "
                         "task's; not with --envelope, --city-pool or --turbulence")
    tr.add_argument("--city-pool", type=int, default=None, help="training cities (default: the task's, {city_pools})")
    tr.add_argument("--turbulence", default=None, metavar="LEVELS",
                    help="none|light|moderate|severe, or several comma-separated, one drawn per episode "
                         "(default: the vehicle's task's)")
    tr.add_argument("--sensing", default=None, metavar="LEVELS",
                    help="perfect|nominal|degraded, or several comma-separated, one drawn per episode "
                         "(docs/sensing.md): below perfect the policy flies on its navigation estimate and its "
                         "lidar (default: the task's, perfect)")
    tr.add_argument("--map-error", default=None, metavar="LEVELS",
                    help="exact|outdated|wrong, or several comma-separated, one drawn per episode (docs/sensing.md): "
                         "the route and the height map come from the erroneous prior, the truth scores the flight "
                         "(default: the task's, exact)")
    tr.add_argument("--envelope", action="store_true",
                    help="train in the air and space the vehicle will meet: fields from density altitude -0.6 to "
                         "4.0 km, no to moderate turbulence, steady wind to 8 m/s (small quad) or 12 m/s (UAM), drawn "
                         "per episode; the UAM also in cities at the shipped maps' scale (15-30 m streets), with goals "
                         "down to 15 m from the flight volume's side, observing that side (geofence)")
    tr.add_argument("--exact-maps-at-perfect", action="store_true",
                    help="an episode drawing perfect sensing flies its city's exact map (at perfect the env hands the "
                         "policy the truth's senses, the comparison a sensorless pilot the prior map's: over a wrong "
                         "map no comparison pilot meets the env's case); needs exact among --map-error")
    tr.add_argument("--route-refresh", type=float, default=None, metavar="SECONDS",
                    help="below perfect sensing, redraw the route the policy observes around the obstacles its "
                         "lidar sensed, checking every SECONDS of flight (a whole number of decisions; 0: the prior "
                         "map's route all episode; default: the task's, 0)")
    tr.add_argument("--observe", default=None, metavar="WHAT",
                    help="what the policy observes beyond the base observation, comma-separated: air (density "
                         "ratio and forecast turbulence), geofence (the flight volume's edge), history=N (N past "
                         "decisions), uncertainty (the navigation estimate's position sigma), or none; replaces "
                         "the task's own (default: the task's; the UAM's --envelope task observes geofence)")


def _shown_defaults() -> dict[str, str]:
    """`train --help`'s defaults, read from `TrainConfig` and the vehicles' tasks."""
    from rl.task.vehicles import TASKS
    from rl.training.config import TrainConfig  # the tasks and presets: only when help is printed
    from rl.training.presets import PRESETS

    c = TrainConfig()
    arch = {name: p.net_arch for name, p in PRESETS.items()}
    layers = {name: f"{len(a)} x {a[0]}" if len(set(a)) == 1 else " x ".join(map(str, a)) for name, a in arch.items()}
    others = [v for v in TASKS if v != c.nav.vehicle]
    return {"preset": c.preset, "timesteps": _count(c.total_timesteps), "envs": str(c.n_envs), "seed": str(c.seed),
            "presets": "; ".join(f"{n}: {layers[n]} units, clip {p.clip_range:g}" for n, p in PRESETS.items()),
            "vehicles": f"{c.nav.vehicle} (default)" + "".join(f" or {v}" for v in others),
            "city_pools": ", ".join(f"{task.city_pool_size} for {v}" for v, task in TASKS.items()),
            "level_steps": str(c.curriculum.level_steps), "eval_every": _count(c.eval_every),
            "eval_episodes": str(c.eval_episodes), "checkpoint_every": _count(c.checkpoint_every),
            "record_flights": str(c.record_flights), "env_processes": str(c.env_processes)}


def _count(n: int) -> str:
    """A count of timesteps as the help says it: 10M, 500k, 64."""
    for unit, size in (("M", 10**6), ("k", 10**3)):
        if n >= size and n % size == 0:
            return f"{n // size}{unit}"
    return str(n)


def train(args: argparse.Namespace) -> int:
    """`train`: every option (and --scenario's file) checked by its own name before anything is built, then PPO; at
    the end the kept model's validation, once, and the next steps (`next_steps`)."""
    from rl.training.config import MAX_ENV_PROCESSES, MAX_RECORDED_FLIGHTS, TrainConfig
    from rl.training.loop import train as train_policy
    from rl.training.presets import PRESETS

    defaults = TrainConfig()
    given = {field: getattr(defaults, field) if getattr(args, dest) is None else getattr(args, dest)
             for dest, field in CONFIG_FIELDS.items()}
    # TrainConfig would name its fields, not the options
    check_ranges({"--timesteps": (given["total_timesteps"], 1, MAX_TIMESTEPS), "--envs": (given["n_envs"], 1, MAX_ENVS),
                  "--eval-every": (given["eval_every"], 1, MAX_TIMESTEPS),
                  "--eval-episodes": (given["eval_episodes"], 1, MAX_EVAL_EPISODES),
                  "--checkpoint-every": (given["checkpoint_every"], 0, MAX_TIMESTEPS),
                  "--seed": (given["seed"], 0, MAX_SEED),
                  "--record-flights": (given["record_flights"], 0, MAX_RECORDED_FLIGHTS),
                  "--env-processes": (given["env_processes"], 1, min(given["n_envs"], MAX_ENV_PROCESSES)),
                  **({} if args.city_pool is None else {"--city-pool": (args.city_pool, 1, MAX_CITY_POOL)})})
    if given["preset"] in PRESETS:  # an unknown preset is named below; a known one fits the vehicles, or --envs says
        n = given["n_envs"]
        try:
            PRESETS[given["preset"]].minibatch_size(n)
        except ValueError as exc:
            raise ValueError(f"--envs {n}: {str(exc).removeprefix(f'n_envs {n}: ')}") from None
    ground = _ground(args)
    nav = _task(args, defaults, ground)
    level_steps = (defaults.curriculum.level_steps if args.curriculum_level_steps is None
                   else args.curriculum_level_steps)
    check_ranges({"--curriculum-level-steps": (level_steps, 0, MAX_TIMESTEPS)})
    full_length = not args.curriculum or ground is not None  # a scenario's legs are drawn once, at full length
    curriculum = replace(defaults.curriculum, **({"start": 1.0} if full_length else {"level_steps": level_steps}))

    def config(preset: str) -> TrainConfig:  # the other fields are checked above: a refusal here is the preset's
        return TrainConfig(**{**given, "preset": preset}, nav=nav, curriculum=curriculum,
                           scenario=None if ground is None else ground.source)

    cfg = option("--preset", config, given["preset"])
    res = train_policy(cfg, args.out, resume=args.resume, progress=not args.no_progress,
                       command="uam-compare " + " ".join(args.argv), ground=ground)
    prov = PolicyFolder(args.out).provenance() if (args.out / PROVENANCE).is_file() else None
    at = f" (the model at {prov.kept_timesteps:,d} timesteps)" if prov and prov.kept_timesteps is not None else ""
    print(f"policy written to {args.out}{at}: validation success {res.success_rate:.1%}, collisions "
          f"{res.collision_rate:.1%} over {res.episodes} episodes")
    for line in next_steps(args.out, cfg):
        print(line)
    return 0


def next_steps(out: Path, cfg: TrainConfig) -> list[str]:
    """What to do with a freshly trained policy folder `out`, as command lines: its training page (when flights
    were recorded), its TensorBoard logs, and flying it in the comparison (on its scenario, if it has one)."""
    folder = shlex.quote(str(out))
    fly = f"uam-compare run {shlex.quote(cfg.scenario)} --policy {folder}" if cfg.scenario else \
        f"uam-compare run --policy {folder}"
    steps = [f"uam-compare view-training {folder}   # its learning curves and recorded flights, one HTML page"] \
        if cfg.record_flights else []
    steps += [f"tensorboard --logdir {shlex.quote(str(out / TENSORBOARD))}   # PPO's own curves",
              f"{fly}   # fly it beside the other pilots"]
    return ["next:"] + [f"  {step}" for step in steps]


def _ground(args: argparse.Namespace) -> TrainingGround | None:
    """--scenario's map and air, read and checked before anything is built (None: generated cities).

    Raises:
        ValueError: an option that the scenario states otherwise, or a bad scenario file (its file, key and reason).
    """
    from rl.env.ground import TrainingGround

    if args.scenario is None:
        return None
    if args.env_processes not in (None, 1):
        raise ValueError(f"--env-processes {args.env_processes} and --scenario: a scenario's legs are dealt to the "
                         f"vehicles of one batch; leave --env-processes out")
    given = [name for name, value in (("--envelope", args.envelope), ("--city-pool", args.city_pool),
                                      ("--turbulence", args.turbulence)) if value]
    if given:
        raise ValueError(f"--scenario and {', '.join(given)}: the scenario states the map and the air; give one or "
                         f"the other")
    if not args.scenario.is_file():
        raise ValueError(f"--scenario {args.scenario}: no such file")
    ground = TrainingGround.from_scenario(load_scenario(args.scenario))
    if args.vehicle is not None and args.vehicle != ground.vehicle:
        raise ValueError(f"--vehicle {args.vehicle}: {args.scenario} flies {ground.vehicle!r}; give that vehicle or "
                         f"leave --vehicle out")
    return ground


def _task(args: argparse.Namespace, defaults: TrainConfig, ground: TrainingGround | None = None) -> NavConfig:
    """The vehicle's task with --city-pool, --turbulence and --observe applied, or in `ground`'s air and rates; --out
    checked on the way (a policy there is never replaced unasked)."""
    from rl.task.vehicles import task_for

    vehicle = ground.vehicle if ground is not None else defaults.nav.vehicle if args.vehicle is None else args.vehicle
    task = option("--vehicle", lambda v: task_for(v, envelope=args.envelope), vehicle)
    air = task.air if args.turbulence is None else replace(task.air, turbulence=turbulence_levels(args.turbulence))
    observe = task.observe if args.observe is None else parse_observed(args.observe)
    sensing = task.sensing if args.sensing is None else _levels("--sensing", args.sensing, "sensing", task)
    map_error = task.map_error if args.map_error is None else _levels("--map-error", args.map_error, "map_error", task)
    route = task.route if args.route_refresh is None else option(
        "--route-refresh", lambda v: _refresh_every(task, float(v)), str(args.route_refresh))
    if args.exact_maps_at_perfect and "exact" not in map_error:
        raise ValueError(f"--exact-maps-at-perfect with --map-error {','.join(map_error)}: the exact map must be "
                         f"one of the levels (add exact)")
    check_output_dir(args.out, "--out")
    if args.out.is_dir() and any(args.out.iterdir()) and args.resume is None and not args.overwrite:
        raise ValueError(f"--out {args.out}: folder exists and is not empty (a policy there would be replaced; "
                         f"give another --out, --resume to continue its training, or --overwrite to replace it)")
    task = replace(task, city_pool_size=args.city_pool or task.city_pool_size, air=air, observe=observe,
                   sensing=sensing, map_error=map_error, route=route,
                   exact_maps_at_perfect=task.exact_maps_at_perfect or args.exact_maps_at_perfect)
    return task if ground is None else ground.task(task)


def _refresh_every(task: NavConfig, seconds: float) -> RouteConfig:
    """The task's route settings checking for sensed obstacles every `seconds` (`rl.sensing.route_refresh`).

    Raises:
        ValueError: a negative or non-finite period, or one that is not a whole number of the task's decisions.
    """
    from rl.sensing.route_refresh import refresh_decisions

    route = replace(task.route, refresh_s=seconds)
    refresh_decisions(route, task.decision_hz)
    return route


def _levels(name: str, text: str, key: str, task: NavConfig) -> tuple[str, ...]:
    """--sensing's or --map-error's levels ("nominal", or "perfect,nominal,degraded"), checked by the task's own
    rules (`NavConfig`, field `key`).

    Raises:
        ValueError: an unknown or repeated level, naming the option.
    """
    levels = tuple(t.strip() for t in text.split(","))
    changes: dict[str, Any] = {key: levels}
    try:
        replace(task, **changes)
    except ValueError as exc:
        raise ValueError(f"{name} {text}: {str(exc).removeprefix(f'{key} ')}") from None
    return levels


def parse_observed(text: str) -> ObservedContext:
    """--observe's items: "air", "geofence", "history=N" (comma-separated), or "none".

    Raises:
        ValueError: an unknown item or a bad count, naming the option.
    """
    air = geofence = uncertainty = False
    history = 0
    for item in (t.strip() for t in text.split(",")):
        name, _, value = item.partition("=")
        if item == "air":
            air = True
        elif item == "geofence":
            geofence = True
        elif item == "uncertainty":
            uncertainty = True
        elif name == "history" and value.isdigit() and 1 <= int(value) <= 50:
            history = int(value)
        elif item != "none":
            raise ValueError(f"--observe {text}: {item!r} is not air, geofence, history=N (N 1 to 50), uncertainty "
                             f"or none")
    return ObservedContext(air=air, geofence=geofence, history=history, uncertainty=uncertainty)
