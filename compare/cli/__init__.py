"""The `uam-compare` command line."""
from __future__ import annotations

import argparse
import errno
import json
import logging
import math
import os
import shlex
import signal
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from datetime import datetime
from pathlib import Path
from typing import TypeVar

from compare.flying.demo import demo_flight
from compare.flying.pilots import METHODS, pilot
from compare.results.failures import FAILED_DIR, describe_failures, read_failures
from compare.results.level_rates import level_json, level_rates, level_table_lines
from compare.results.metrics import read_metrics_csv
from compare.results.outputs import check_not_replacing, check_output_dir, check_output_file
from compare.results.run_info import RUN_INFO_NAME, read_run_info
from compare.results.summary import PairedSummary, PowerSettings, Stat, Summary, methods_table, read_summary_json
from compare.results.sweep_rates import sweep_json, sweep_rates, sweep_table_lines
from compare.run.backends import BACKENDS
from compare.run.campaign import (
    VIDEOS_DIR,
    RunInterrupted,
    RunOptions,
    check_empty_run_folder,
    estimate_run,
    finalize,
    run_comparison,
)
from compare.scenarios.benchmark import BENCHMARK_SETS
from compare.scenarios.scenario import MAX_SEED, Scenario, with_methods
from compare.scenarios.sets import resolve_scenarios
from compare.scenarios.sweep import SWEEP_SETS, build_sweep
from rl.policies.flights import TrainingFlights
from rl.policies.folder import CONFIG
from rl.sensing.observation import ObservedContext
from rl.task.air import AIR_LEVELS, AirDistribution
from uam_fdm.air.atmosphere import ELEVATION_RANGE_M, ISA_OFFSET_RANGE_K
from uam_fdm.files.atomic import TEMP_MARK
from uam_fdm.vehicle.params import preset_names

AIR_FIELDS = 16
"""Fields drawn (and tabulated) for air given as ranges (--air): each episode flies one."""

# Imported inside the commands that use them: matplotlib and plotly (figures, viewer, maps) and PyTorch (the
# learned pilot's training and evaluation), each slow to import, so that the other commands start without them.

INTERRUPTED_EXIT = 130  # the shell's code for a command stopped by Ctrl-C (128 + SIGINT)


def _cmd_demo(args: argparse.Namespace) -> int:
    for preset in args.vehicles:
        r = demo_flight(preset, seed=args.seed)
        print(f"{r.vehicle}: {r.mass_kg:g} kg, {r.n_rotors} rotors, hover at {r.hover_rotor_speed_rad_s:.1f} rad/s "
              f"({r.backend} dynamics)")
        print(f"  reached {r.waypoints_reached}/{r.waypoints} waypoints (climb, square, return, descend) in "
              f"{r.flight_time_s:.1f} s through light turbulence: flew {r.path_length_m:.0f} m, "
              f"max speed {r.max_speed_m_s:.1f} m/s, max tilt {r.max_tilt_deg:.1f} deg")
        print(f"  largest distance from the square {r.max_cross_track_m:.2f} m, ended at "
              f"({r.final_position_m[0]:.1f}, {r.final_position_m[1]:.1f}, {r.final_position_m[2]:.1f}) m")
        print(f"  rotor shaft energy {r.energy_kj:.1f} kJ (mean {r.mean_shaft_power_kw:.2f} kW); "
              f"simulated {r.flight_time_s / r.wall_time_s:.0f}x faster than real time")
    return 0


def _cmd_maps(args: argparse.Namespace) -> int:
    from uam_fdm.city.plot import render_named_maps  # matplotlib

    check_output_dir(Path(args.out_dir), "OUT_DIR")
    for path in render_named_maps(args.out_dir):
        print(path)
    return 0


def _csv_list(text: str, kind=str) -> tuple:
    items = tuple(kind(v.strip()) for v in text.split(",") if v.strip())
    if not items:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    return items


def _seed_list(text: str) -> tuple[int, ...]:
    """`--seeds`: comma-separated integers (their range and distinctness are checked with the scenarios' rule)."""
    try:
        return _csv_list(text, int)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, e.g. 0,1,2, got {text!r}") from None


def _default_run_dir(spec: str) -> Path:
    stem = Path(spec).stem if spec.endswith((".yaml", ".yml")) else Path(spec).name
    base = Path("runs") / f"{datetime.now().strftime('%Y%m%d-%H%M%S')}-{stem}"
    out, k = base, 1
    while out.exists():
        k += 1
        out = base.with_name(f"{base.name}-{k}")
    return out


def _one_torch_thread() -> None:
    """This process flies small networks one observation at a time: one torch thread is fastest."""
    import torch  # PyTorch: seconds to import, only for the commands that fly

    torch.set_num_threads(1)


def _cmd_run(args: argparse.Namespace) -> int:
    for flag, names in (("--method", args.method), ("--methods", args.methods or ())):
        for m in names:  # registered, or a plug-in (imported here, before anything flies)
            try:
                pilot(m)
            except ValueError as exc:
                raise ValueError(f"{flag}: {exc}") from None
    out = args.out if args.out is not None else _default_run_dir(args.scenario)
    # --videos' default is settled once the scenarios are read (`_videos`)
    opts = RunOptions(out_dir=out, methods=args.methods, seeds=args.seeds, policies=tuple(args.policy), jobs=args.jobs,
                      resume=args.resume, progress=not args.no_progress, videos=args.videos or "scenario",
                      command="uam-compare " + " ".join(args.argv), backend=args.backend, address=args.address,
                      cell_timeout_s=args.cell_timeout, store=args.store)
    opts.validate()  # e.g. Ray missing: before anything is read or flown
    if args.jobs > (os.cpu_count() or 1):
        print(f"uam-compare: warning: --jobs {args.jobs} is more than the {os.cpu_count()} CPUs here; the extra "
              f"processes only compete for them", file=sys.stderr)
    check_output_dir(out, "--out")
    if not args.resume:
        check_empty_run_folder(out)
    # validates every file before anything flies
    if args.command == "sweep":
        only = tuple(args.vehicle) if args.vehicle else None
        scenarios = list(build_sweep(args.scenario, vehicles=only).scenarios)
    else:
        scenarios = resolve_scenarios(args.scenario)
    scenarios = [with_methods(sc, tuple(args.method)) for sc in scenarios]
    opts = replace(opts, videos=_videos(args.videos, scenarios))  # its default depends on the scenarios
    _one_torch_thread()
    est = estimate_run(scenarios, opts)
    if est.large:
        print(f"uam-compare: warning: {est.cells} episodes may take up to {est.wall_h:.1f} h with --jobs {opts.jobs} "
              f"and {est.disk_gb:.1f} GB of episode files in {out} (every episode flown to its timeout)",
              file=sys.stderr)
    try:
        run_dir = run_comparison(scenarios, opts)
    except RunInterrupted as stop:
        again = ["uam-compare", *args.argv] + (["--out", str(out)] if args.out is None else [])
        again += [] if args.resume else ["--resume"]
        print(f"uam-compare: interrupted: {stop.kept} of {stop.cells} episodes kept in {stop.out_dir}; "
              f"to fly the rest: {shlex.join(again)}", file=sys.stderr)
        return INTERRUPTED_EXIT
    _print_summary(run_dir)
    _print_suite(run_dir)
    _print_headline_json(run_dir)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    args.scenario = SWEEP_SETS[1] if args.quick else SWEEP_SETS[0]
    return _cmd_run(args)


def _videos(chosen: str | None, scenarios: Sequence[Scenario]) -> str:
    """--videos, or its default: the first cell of each scenario, none for a benchmark set (dozens of scenarios)."""
    if chosen is not None:
        return chosen
    return "none" if any(sc.suite is not None for sc in scenarios) else "scenario"


def _print_headline_json(run_dir: Path) -> None:
    """The run's headline figures as the last line, one JSON object (for scripts): per vehicle and method the
    episodes, success and collision rates with their 95 % Wilson intervals; the task set and its version; the
    failed cells."""

    def rate(st: Stat | None) -> dict:
        return {"rate": st.mean, "ci95": [st.ci_low, st.ci_high]} if st is not None else {}

    per_vehicle = read_summary_json(run_dir / "summary.json").per_vehicle() or {}
    info = read_run_info(run_dir)
    suite = info.suite
    out: dict[str, object] = {
        "run_dir": str(run_dir),
        "suite": None if suite is None else {"name": suite.name, "version": suite.version},
        "vehicles": {v: {m: {"episodes": ms.episodes, "success": rate(ms.stats.get("success")),
                             "collision": rate(ms.stats.get("collision"))} for m, ms in part.methods.items()}
                     for v, part in per_vehicle.items()},
        "failed_cells": len(read_failures(run_dir))}
    if suite is not None and suite.name in SWEEP_SETS:  # per vehicle, axis, step and pilot (printed above)
        out["sweep"] = sweep_json(sweep_rates(info, read_metrics_csv(run_dir / "metrics.csv")))
    if suite is not None and suite.name in BENCHMARK_SETS and (run_dir / "metrics.csv").exists():
        # per vehicle, air and turbulence level (printed above)
        out["by_level"] = level_json(level_rates(info, read_metrics_csv(run_dir / "metrics.csv")))
    print(json.dumps(out))


def _print_suite(run_dir: Path) -> None:
    """The benchmark set a run flew, with its version (nothing for scenario files); a sweep's rates per step, a
    benchmark's per air and turbulence level."""
    info = read_run_info(run_dir)
    suite = info.suite
    if suite is not None and suite.name in SWEEP_SETS:
        for line in sweep_table_lines(sweep_rates(info, read_metrics_csv(run_dir / "metrics.csv"))):
            print(line)
    if suite is not None and suite.name in BENCHMARK_SETS and (run_dir / "metrics.csv").exists():
        for line in level_table_lines(level_rates(info, read_metrics_csv(run_dir / "metrics.csv"))):
            print(line)
    if suite is not None:
        print(f"task set {suite.name}, version {suite.version}: {suite.description}")


SCENARIOS_PRINTED = 4
"""A vehicle's scenarios printed one by one at the end of a run when it has at most this many (else its table only)."""


def _print_summary(run_dir: Path) -> None:
    """Per vehicle (never pooled: a quadrotor's and a multicopter's numbers do not average) one row per method,
    then its scenarios when there are few, then its paired success differences with their MDD."""
    summary = read_summary_json(run_dir / "summary.json")
    wanted = ("method", "episodes", "success", "collision", "min clearance", "time", "SPL", "energy", "compute mean")

    def table(blocks: list[tuple[str, Summary]]) -> list[str]:
        lines = []
        for name, part in blocks:
            full = methods_table(part)
            keep = [i for i, h in enumerate(full[0]) if h.split(" [")[0].split(" (")[0] in wanted]
            lines.append([name] + [""] * (len(keep) - 1))
            lines += [[row[i] for i in keep] for row in full]
        widths = [max(len(str(r[i])) for r in lines) for i in range(len(lines[0]))]
        return ["  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip() for row in lines]

    scenarios = summary.by_scenario or {}
    per_vehicle = summary.per_vehicle()
    if per_vehicle is None:  # a summary.json from before per-vehicle summaries: its scenarios, as then
        for line in table(list((scenarios or {"all": summary}).items())):
            print(line)
    for vehicle, part in (per_vehicle or {}).items():
        mine = [(name, s) for name, s in scenarios.items() if s.vehicle == vehicle]
        few = 1 < len(mine) <= SCENARIOS_PRINTED
        where = (f"scenario {mine[0][0]}" if len(mine) == 1 else
                 f"{len(mine)} scenarios" + ("" if few else f" (more than {SCENARIOS_PRINTED}: see report.pdf)"))
        for line in table([(f"{vehicle}: {where}", part)] + [(f"{vehicle} / {name}", s) for name, s in mine
                                                            if few]):
            print(line)
        for pair in part.paired:
            print("  " + _paired_success_line(pair, part.power))
    for name in ("report.pdf", "viewer.html", "metrics.csv", "summary.json"):
        if (run_dir / name).exists():
            print(run_dir / name)
    for video in sorted((run_dir / "videos").glob("[!.]*.*")):
        print(video)
    failed = read_failures(run_dir)
    if failed:
        print(f"{run_dir / FAILED_DIR}{os.sep}  {describe_failures(failed)}: no episode, no metrics row; one record "
              f"each, with the reason; `run --resume` flies them again")


def _paired_success_line(pair: PairedSummary, power: PowerSettings) -> str:
    """One pair's success difference with its 95 % interval, and the smallest difference this many pairs detect."""
    st = pair.stats.get("success")
    head = f"{pair.first} - {pair.second}: success difference"
    if st is None or st.mean is None:
        return f"{head} n/a (no paired episodes)"

    def pct(v: float | None, sign: str = "+") -> str:
        return "n/a" if v is None else f"{100.0 * v:{sign}.0f}%"

    def detectable(v: float | None) -> str:  # no difference of rates exceeds 100 %
        return "over 100%, too few pairs" if v is not None and v > 1.0 else pct(v, "")

    both = 100.0 * (power.design_rate or 0.5)
    design = "" if st.mdd_design is None else f"; before any run (both at {both:.0f} %): {detectable(st.mdd_design)}"
    seen = "n/a from the spread, every pair agreed" if st.sd == 0.0 else detectable(st.mdd)
    test = "" if power.alpha is None else f" (alpha {power.alpha:g}, power {power.power:g})"
    return (f"{head} {pct(st.mean)} [{pct(st.ci_low)}, {pct(st.ci_high)}] over {st.n} paired episodes; "
            f"smallest difference detectable{test}: {seen}{design}")


def _cmd_report(args: argparse.Namespace) -> int:
    run_dir = finalize(args.run_dir)
    _print_summary(run_dir)
    _print_suite(run_dir)
    _print_headline_json(run_dir)
    return 0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 1280x720, got {text!r}") from None
    return w, h


def _cmd_animate(args: argparse.Namespace) -> int:
    from compare.playback.animate import AnimationOptions, render_animation, render_videos  # matplotlib
    from compare.playback.flights import flight_groups, select_group

    w, h = args.size
    opts = AnimationOptions(fps=args.fps, duration_s=args.duration, width_px=w, height_px=h, orbit_deg=args.orbit)
    opts.validate()  # before loading anything
    if args.all and args.episode is not None:
        raise ValueError("--all and --episode: give one or the other")
    groups = flight_groups(args.run_dir)
    if args.all:
        out_dir = args.out if args.out is not None else args.run_dir / VIDEOS_DIR
        check_output_dir(out_dir, "--out")
        results = render_videos(groups, out_dir, "all", opts, progress=not args.no_progress, fmt=args.format)
    else:
        group = select_group(groups, args.episode) if args.episode is not None else groups[0]
        out = args.out if args.out is not None else args.run_dir / VIDEOS_DIR / f"{group.stem}.{args.format}"
        check_output_file(out, "--out")
        check_not_replacing(args.out, "--out", args.overwrite)
        results = [render_animation(group, out, opts, progress=not args.no_progress)]
    for r in results:
        print(f"{r.path}  ({r.format}, {r.frames} frames {r.width_px}x{r.height_px} at {r.fps:g} fps, "
              f"x{r.speedup:.2f} real time, rendered in {r.seconds:.1f} s)")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from compare.pages.viewer import VIEWER_NAME, build_viewer  # plotly and matplotlib

    check_output_file(args.out if args.out is not None else args.run_dir / VIEWER_NAME, "--out")
    check_not_replacing(args.out, "--out", args.overwrite)
    print(build_viewer(args.run_dir, args.out))
    return 0


def _cmd_view_training(args: argparse.Namespace) -> int:
    from compare.pages.training_view import build_training_view, default_out  # plotly and matplotlib

    if not args.policy_dir.is_dir():
        raise ValueError(f"{args.policy_dir}: not a policy folder (no such folder)")
    TrainingFlights.open(args.policy_dir)  # no flights: one line naming the folder and how to record them
    out = args.out if args.out is not None else default_out(args.policy_dir)
    check_output_file(out, "--out")
    check_not_replacing(out, "--out", args.overwrite)  # the default file too: it is in the user's folder
    print(build_training_view(args.policy_dir, out))
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    if not args.rerun:
        raise ValueError("export: give --rerun (a Rerun .rrd recording is the one export format)")
    from compare.playback.rerun_export import require_rerun, run_recording, training_recording  # matplotlib

    require_rerun()  # a missing extra is said before anything is read
    folder = args.folder
    write: Callable[[Path, Path], Path]
    if (folder / RUN_INFO_NAME).is_file():
        out = args.out if args.out is not None else folder / "flights.rrd"  # the run folder's own file
        write = run_recording
    elif folder.is_dir() and (folder / CONFIG).is_file():
        TrainingFlights.open(folder)  # no flights: one line naming the folder and how to record them
        out = args.out if args.out is not None else Path(f"{folder.resolve().name}-training.rrd")
        write = training_recording
    else:
        raise ValueError(f"{folder}: neither a run folder ({RUN_INFO_NAME}) nor a policy folder ({CONFIG})")
    check_output_file(out, "--out")
    # a file the user named, or the policy's default file in their folder, is never replaced unasked
    check_not_replacing(out if args.out is not None or write is training_recording else None, "--out",
                        args.overwrite)
    print(write(folder, out))
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    for sc in resolve_scenarios(args.scenario):
        print(f"{sc.source}: ok ({sc.name}: map {sc.city.name or '-'} with {len(sc.city.buildings)} buildings, "
              f"vehicle {sc.vehicle_name}, {len(sc.episodes)} episodes x {len(sc.seeds)} seeds, "
              f"methods {', '.join(sc.methods)}, turbulence {sc.wind.turbulence.value})")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from rl.task.vehicles import task_for
    from rl.training.config import MAX_RECORDED_FLIGHTS, Curriculum, TrainConfig
    from rl.training.loop import train
    from rl.training.ppo import PRESETS

    # every option by its own name, before anything is built (TrainConfig would name its fields, not options)
    _check_ranges({"--timesteps": (args.timesteps, 1, MAX_TIMESTEPS), "--envs": (args.envs, 1, MAX_ENVS),
                   "--eval-every": (args.eval_every, 1, MAX_TIMESTEPS),
                   "--eval-episodes": (args.eval_episodes, 1, MAX_EVAL_EPISODES),
                   "--checkpoint-every": (args.checkpoint_every, 0, MAX_TIMESTEPS), "--seed": (args.seed, 0, MAX_SEED),
                   "--record-flights": (args.record_flights, 0, MAX_RECORDED_FLIGHTS),
                   **({} if args.city_pool is None else {"--city-pool": (args.city_pool, 1, MAX_CITY_POOL)})})
    task = _option("--vehicle", lambda v: task_for(v, envelope=args.envelope), args.vehicle)
    air = task.air if args.turbulence is None else replace(task.air, turbulence=_turbulence_levels(args.turbulence))
    observe = task.observe if args.observe is None else _observed(args.observe)
    check_output_dir(args.out, "--out")
    if args.out.is_dir() and any(args.out.iterdir()) and args.resume is None and not args.overwrite:
        raise ValueError(f"--out {args.out}: folder exists and is not empty (a policy there would be replaced; "
                         f"give another --out, --resume to continue its training, or --overwrite to replace it)")
    nav = replace(task, city_pool_size=args.city_pool or task.city_pool_size, air=air, observe=observe)
    _check_ranges({"--curriculum-level-steps": (args.curriculum_level_steps, 0, MAX_TIMESTEPS)})
    cur = Curriculum(level_steps=args.curriculum_level_steps) if args.curriculum else Curriculum(start=1.0)
    if args.preset not in PRESETS:
        raise ValueError(f"--preset {args.preset}: unknown; choose from {', '.join(sorted(PRESETS))}")
    cfg = TrainConfig(preset=args.preset, total_timesteps=args.timesteps, n_envs=args.envs, seed=args.seed, nav=nav,
                      curriculum=cur, eval_every=args.eval_every, eval_episodes=args.eval_episodes,
                      checkpoint_every=args.checkpoint_every, record_flights=args.record_flights)
    res = train(cfg, args.out, resume=args.resume, progress=not args.no_progress,
                command="uam-compare " + " ".join(args.argv))
    print(f"policy written to {args.out}: validation success {res.success_rate:.1%}, collisions "
          f"{res.collision_rate:.1%} over {res.episodes} episodes")
    return 0


MAX_TIMESTEPS = 10**12
MAX_ENVS = 65_536  # vehicles stepped in one call: far beyond one machine's memory already
MAX_EVAL_EPISODES = 1_000_000
MAX_CITY_POOL = 1_000_000


def _check_ranges(values: dict[str, tuple[int, int, int]]) -> None:
    """Raise ValueError naming the first option whose value is outside [low, high] (option -> value, low, high)."""
    for option, (value, low, high) in values.items():
        if not low <= value <= high:
            raise ValueError(f"{option} {value}: must be between {low} and {high}")


T = TypeVar("T")


def _option(option: str, check: Callable[[str], T], value: str) -> T:
    """`check(value)`, its ValueError said as the option's: "--option value: reason"."""
    try:
        return check(value)
    except ValueError as exc:
        raise ValueError(f"{option} {value}: {exc}") from None


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from rl.env.world import NavWorld
    from rl.pilots.learned import load_policy
    from rl.task.vehicles import in_task_space, task_for
    from rl.training.evaluation import (
        eval_config,
        evaluate,
        evaluate_potential_field,
        paired_counts,
        rates_by_city_component,
    )

    if args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes}: must be >= 1")
    _check_ranges({"--seed": (args.seed, 0, MAX_SEED)})
    _one_torch_thread()
    air = _air_from_options(args)  # before anything is loaded: a bad option is named at once
    policy = load_policy(args.policy)
    own = policy.nav if args.task == "own" else in_task_space(policy.nav, task_for(policy.nav.vehicle, envelope=True))
    nav = eval_config(own, args.episodes, pool=args.pool, air=air(own.air))
    world = NavWorld(nav)
    res = evaluate(lambda obs, _batch: policy.act_batch(obs), nav, args.episodes, seed=args.seed, pool=args.pool,
                   world=world)
    a = nav.air
    out = {"pool": args.pool, "episodes": res.episodes, "seed": args.seed, "task": args.task,
           "turbulence": ",".join(a.turbulence),
           "steady_wind_max_m_s": a.steady_wind_max_m_s, "elevation_m": list(a.elevation_m),
           "isa_offset_k": list(a.isa_offset_k), "fields": len(world.atmospheres), "policy": str(policy.folder),
           "success_rate": res.success_rate, "success_ci95": res.success_ci95,
           "collision_rate": res.collision_rate, "collision_ci95": res.collision_ci95, "outcomes": res.outcomes}
    print(f"{res.episodes} {args.pool} episodes in the {'policy' if args.task == 'own' else 'envelope'}'s task "
          f"({'/'.join(a.turbulence)} turbulence, steady wind up to "
          f"{a.steady_wind_max_m_s:g} m/s, {_describe_fields(a)}, {policy.nav.vehicle}), Wilson 95 % intervals:")
    print(f"  ppo              success {res.success_rate:6.1%} [{res.success_ci95[0]:.1%}, {res.success_ci95[1]:.1%}]"
          f"  collisions {res.collision_rate:5.1%} [{res.collision_ci95[0]:.1%}, {res.collision_ci95[1]:.1%}]"
          f"  {res.outcomes}")
    groups = {"ppo": rates_by_city_component(res, nav)}
    if not args.no_baseline:
        # the same tasks (cities, legs, wind), the reactive pilot at the 50 Hz it was tuned for
        ex = evaluate_potential_field(nav, args.episodes, seed=args.seed, pool=args.pool, world=world)
        pairs = paired_counts(res, ex)
        print(f"  potential field  success {ex.success_rate:6.1%} [{ex.success_ci95[0]:.1%}, {ex.success_ci95[1]:.1%}]"
              f"  collisions {ex.collision_rate:5.1%} [{ex.collision_ci95[0]:.1%}, {ex.collision_ci95[1]:.1%}]"
              f"  {ex.outcomes}")
        print(f"  paired: only ppo succeeded {pairs['only_a']}, only the potential field {pairs['only_b']}, "
              f"both {pairs['both']}, neither {pairs['neither']}")
        out.update(expert_success_rate=ex.success_rate, expert_success_ci95=ex.success_ci95,
                   expert_collision_rate=ex.collision_rate, expert_collision_ci95=ex.collision_ci95,
                   paired=pairs)
        groups["potential field"] = rates_by_city_component(ex, nav)
    if groups["ppo"]:  # a task whose cities mix several kinds: the rates per kind
        print("  by kind of city:")
        for pilot, rows in groups.items():
            for g in rows:
                print(f"    {pilot:<15} {g.label}: {g.episodes} episodes, success {g.success_rate:.1%} "
                      f"[{g.success_ci95[0]:.1%}, {g.success_ci95[1]:.1%}], collisions {g.collision_rate:.1%} "
                      f"[{g.collision_ci95[0]:.1%}, {g.collision_ci95[1]:.1%}]  {g.outcomes}")
        out["by_city_kind"] = {pilot: [asdict(g) for g in rows] for pilot, rows in groups.items()}
    print(json.dumps(out))
    return 0


def _turbulence_levels(text: str) -> tuple[str, ...]:
    """--turbulence's levels ("moderate", or "none,light,moderate").

    Raises:
        ValueError: an unknown or repeated level, naming the option.
    """
    levels = tuple(t.strip() for t in text.split(","))
    try:
        AirDistribution(turbulence=levels)
    except ValueError as exc:
        raise ValueError(f"--turbulence {text}: {str(exc).removeprefix('air.turbulence ')}") from None
    return levels


def _observed(text: str) -> ObservedContext:
    """--observe's items: "air", "geofence", "history=N" (comma-separated), or "none".

    Raises:
        ValueError: an unknown item or a bad count, naming the option.
    """
    air = geofence = False
    history = 0
    for item in (t.strip() for t in text.split(",")):
        name, _, value = item.partition("=")
        if item == "air":
            air = True
        elif item == "geofence":
            geofence = True
        elif name == "history" and value.isdigit() and 1 <= int(value) <= 50:
            history = int(value)
        elif item != "none":
            raise ValueError(f"--observe {text}: {item!r} is not air, geofence, history=N (N 1 to 50) or none")
    return ObservedContext(air=air, geofence=geofence, history=history)


def _air_from_options(args: argparse.Namespace) -> Callable[[AirDistribution], AirDistribution]:
    """The air `evaluate-policy` flies, from --air or --elevation/--isa-offset, --wind-max and --turbulence, as a
    function of the task's air (what is not given stays the task's). Checked here, before any work.

    Raises:
        ValueError: conflicting or out-of-range options, naming them.
    """
    if args.air is not None and (args.elevation is not None or args.isa_offset is not None):
        raise ValueError("--air and --elevation/--isa-offset: give a level or an explicit field, not both")
    for option, value, valid in (("--elevation", args.elevation, ELEVATION_RANGE_M),
                                 ("--isa-offset", args.isa_offset, ISA_OFFSET_RANGE_K)):
        if value is not None and not valid[0] <= value <= valid[1]:
            raise ValueError(f"{option} {value:g}: must be within [{valid[0]:g}, {valid[1]:g}]")
    if args.wind_max is not None and not (math.isfinite(args.wind_max) and args.wind_max >= 0.0):
        raise ValueError(f"--wind-max {args.wind_max:g}: must be a finite speed >= 0 m/s")
    levels = _turbulence_levels(args.turbulence) if args.turbulence is not None else None

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


def _describe_fields(air: AirDistribution) -> str:
    """The fields of `air` in words: "field 0 m, ISA +0 K" or "fields 1800-2600 m, ISA +20-30 K"."""
    def span(r: tuple[float, float], fmt: str) -> str:
        return fmt.format(r[0]) if r[0] == r[1] else f"{fmt.format(r[0])}-{fmt.format(r[1]).lstrip('+')}"

    many = air.elevation_m[0] != air.elevation_m[1] or air.isa_offset_k[0] != air.isa_offset_k[1]
    return f"field{'s' if many else ''} {span(air.elevation_m, '{:g}')} m, ISA {span(air.isa_offset_k, '{:+g}')} K"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uam-compare", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo_command(sub)
    _add_maps_command(sub)
    _add_run_command(sub)
    _add_sweep_command(sub)
    _add_report_command(sub)
    _add_animate_command(sub)
    _add_view_command(sub)
    _add_view_training_command(sub)
    _add_export_command(sub)
    _add_validate_command(sub)
    _add_train_command(sub)
    _add_evaluate_command(sub)
    return parser


def _add_demo_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    demo = sub.add_parser("demo", help="fly the vehicle presets through a demo pattern and report what happened")
    demo.add_argument("vehicles", nargs="*", default=preset_names(),
                      help=f"preset names or vehicle YAML paths (default: {' '.join(preset_names())})")
    demo.add_argument("--seed", type=int, default=0, help="turbulence seed")
    demo.set_defaults(func=_cmd_demo)


def _add_maps_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    maps = sub.add_parser("maps", help="render the shipped maps (top-down and 3D) to PNG")
    maps.add_argument("out_dir", nargs="?", default="maps_png", help="output folder (default: maps_png)")
    maps.set_defaults(func=_cmd_maps)


def _add_run_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    run = sub.add_parser("run", help="fly both pilots through scenarios and write metrics and the PDF report")
    run.add_argument("scenario", nargs="?", default="default",
                     help="a built-in set (default, full, benchmark, benchmark-quick, benchmark-validation, sweep, "
                          "sweep-quick), a scenario YAML or a folder of them (default: default)")
    _add_run_options(run)
    run.set_defaults(func=_cmd_run)


def _add_sweep_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    sweep = sub.add_parser("sweep", help="fly the robustness sweep (success and collision against density altitude "
                                         "and steady wind, every pilot on the same tasks): `run sweep` with a "
                                         "per-step table; the report draws it")
    sweep.add_argument("--quick", action="store_true",
                       help="the sweep-quick set (the first city, two legs, every step: minutes) instead of sweep")
    sweep.add_argument("--vehicle", action="append", default=None, metavar="VEHICLE",
                       help="only this vehicle's sweep (small_quad, uam_multicopter); repeat for more (default: both)")
    _add_run_options(sweep)
    sweep.set_defaults(func=_cmd_sweep)


def _add_run_options(run: argparse.ArgumentParser) -> None:
    """The options of `run` (and `sweep`): pilots, policies, seeds, jobs, output, resume, backend, videos."""
    run.add_argument("--method", action="append", default=[], metavar="METHOD",
                     help="fly this pilot too, in every scenario: a registered method, a plug-in as module:Class "
                          "or an installed plug-in's entry-point name; repeat for more")
    run.add_argument("--methods", type=_csv_list, default=None,
                     help=f"comma-separated methods to fly, of each scenario's own and --method's "
                          f"({','.join(METHODS)}, plug-ins)")
    run.add_argument("--policy", type=Path, action="append", default=[],
                     help="policy folder for ppo, for the vehicle it was trained for; repeat for other vehicles "
                          "(default: the shipped policy of each vehicle)")
    run.add_argument("--seeds", type=_seed_list, default=None,
                     help="comma-separated seeds overriding the scenarios' own (distinct, 0 to 2**32 - 1)")
    run.add_argument("--jobs", type=int, default=1,
                     help="parallel worker processes (default 1: in this process, where a pilot's exception is "
                          "recorded as a failed cell but a crash or a hang stops the run; 2 or more, or "
                          "--cell-timeout, fly in worker processes, replaced when one dies or hangs); with "
                          "--backend ray the CPUs of the local Ray instance")
    run.add_argument("--out", type=Path, default=None, help="run folder (default: runs/<time>-<scenario>)")
    run.add_argument("--resume", action="store_true",
                     help="complete an interrupted run in --out: fly only the cells without an episode file "
                          "(failed cells included); saved episodes are kept as they are")
    run.add_argument("--cell-timeout", type=float, default=None, metavar="SECONDS",
                     help="wall-time limit of every cell; a cell over it is recorded as failed (hang) and its "
                          "worker replaced (default: 300 s + 10 x the episode's simulated time limit x the "
                          "pilot's wall time per simulated second); with --jobs 1 giving it flies the cells in "
                          "one worker process (in this process nothing could stop a cell)")
    run.add_argument("--backend", choices=BACKENDS, default="local",
                     help="where cells fly: local processes (default) or Ray tasks (pip install -e \".[ray]\"; "
                          "see docs/scale_out.md)")
    run.add_argument("--address", default=None, metavar="ADDR",
                     help="with --backend ray: the Ray cluster's head node, e.g. 10.0.0.5:6379 or ray://host:10001 "
                          "(default: start a local Ray instance with --jobs CPUs)")
    run.add_argument("--videos", choices=("scenario", "all", "none"), default=None,
                     help="cells to animate into RUN_DIR/videos/: the first of each scenario (the default, but none "
                          "for a benchmark set: its product is numbers; `animate` draws any cell later), all, none")
    run.add_argument("--store", choices=("control", "full"), default="control",
                     help="samples kept per episode in RUN_DIR/store/: the control rate (default: everything the "
                          "report, viewer and animation draw) or every physics step; the metrics are the same")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_report_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    rep = sub.add_parser("report",
                         help="rescore a run folder's saved episodes, rebuild its report and viewer (no simulation)")
    rep.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    rep.set_defaults(func=_cmd_report)


def _add_animate_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    anim = sub.add_parser("animate", help="render both pilots flying one cell of a run to MP4 (GIF without ffmpeg)")
    anim.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    anim.add_argument("--episode", default=None, metavar="SCENARIO:EPISODE[:SEED]",
                      help="the cell to show, e.g. suburb-quad:0 (default: the run's first)")
    anim.add_argument("--all", action="store_true", help="every cell of the run, one file each")
    anim.add_argument("--out", type=Path, default=None,
                      help="output file (.mp4 or .gif); with --all a folder (default: RUN_DIR/videos/)")
    anim.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    anim.add_argument("--format", choices=("mp4", "gif"), default="mp4", help="format of default file names")
    anim.add_argument("--fps", type=float, default=20.0, help="frames per second (default 20)")
    anim.add_argument("--duration", type=float, default=None,
                      help="video length [s] (default: real time, sped up to fit 30 s)")
    anim.add_argument("--size", type=_size, default=(1280, 720), help="WIDTHxHEIGHT in pixels (default 1280x720)")
    anim.add_argument("--orbit", type=float, default=0.0, help="camera turn over the clip [deg] (default 0)")
    anim.add_argument("--no-progress", action="store_true", help="no progress bar")
    anim.set_defaults(func=_cmd_animate)


def _add_view_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    view = sub.add_parser("view", help="write a run folder's interactive 3D viewer (one self-contained HTML file)")
    view.add_argument("run_dir", type=Path, help="a folder written by `uam-compare run`")
    view.add_argument("--out", type=Path, default=None, help="HTML file to write (default: RUN_DIR/viewer.html)")
    view.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    view.set_defaults(func=_cmd_view)


def _add_view_training_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    vt = sub.add_parser("view-training", help="write one offline HTML page of a policy's training: the curves, and "
                        "the recorded flights of every checkpoint in 3D, scrubbable")
    vt.add_argument("policy_dir", type=Path, help="a policy folder trained with recorded flights (uam-compare train)")
    vt.add_argument("--out", type=Path, default=None,
                    help="HTML file to write (default: <policy folder name>-training.html here)")
    vt.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    vt.set_defaults(func=_cmd_view_training)


def _add_export_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    ex = sub.add_parser("export", help="write a run's flights, or a policy's recorded training flights, as a Rerun "
                        "recording (.rrd; needs the rerun extra)")
    ex.add_argument("folder", type=Path, help="a run folder (uam-compare run) or a policy folder with training flights")
    ex.add_argument("--rerun", action="store_true", help="write a Rerun .rrd recording (the one format)")
    ex.add_argument("--out", type=Path, default=None,
                    help="file to write (default: RUN_DIR/flights.rrd, or <policy folder name>-training.rrd here)")
    ex.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ex.set_defaults(func=_cmd_export)


def _add_validate_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    val = sub.add_parser("validate", help="check scenario files strictly without flying anything")
    val.add_argument("scenario", help="a built-in set, a scenario YAML or a folder of them")
    val.set_defaults(func=_cmd_validate)


def _add_train_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    tr = sub.add_parser("train", help="train the learned pilot with PPO from scratch on the batched environment")
    tr.add_argument("--preset", default="paper", help="PPO preset (paper: 2 x 128 units, clip 0.2)")
    tr.add_argument("--timesteps", type=int, default=10_000_000, help="decisions, all vehicles (default 10M)")
    tr.add_argument("--envs", type=int, default=256, help="vehicles stepped together (default 256)")
    tr.add_argument("--seed", type=int, default=0, help="the one seed of the run (default 0)")
    tr.add_argument("--vehicle", default="small_quad",
                    help="the vehicle and its task (rl/task/vehicles.py): small_quad (default) or uam_multicopter")
    tr.add_argument("--city-pool", type=int, default=None,
                    help="training cities (default: the task's, 1024 for small_quad, 256 for uam_multicopter)")
    tr.add_argument("--turbulence", default=None, metavar="LEVELS",
                    help="none|light|moderate|severe, or several comma-separated, one drawn per episode "
                         "(default: the vehicle's task's)")
    tr.add_argument("--envelope", action="store_true",
                    help="train in the air and space the vehicle will meet: fields from density altitude -0.6 to "
                         "4.0 km, no to moderate turbulence, steady wind to 8 m/s (small quad) or 12 m/s (UAM), drawn "
                         "per episode; the UAM also in cities at the shipped maps' scale (15-30 m streets), with goals "
                         "down to 15 m from the flight volume's side, observing that side (geofence)")
    tr.add_argument("--observe", default=None, metavar="WHAT",
                    help="what the policy observes beyond the base observation, comma-separated: air (density "
                         "ratio and forecast turbulence), geofence (the flight volume's edge), history=N (N past "
                         "decisions), or none; replaces the task's own (default: the task's; the UAM's --envelope "
                         "task observes geofence)")
    tr.add_argument("--no-curriculum", dest="curriculum", action="store_false",
                    help="full-length legs from the start (default: success-gated curriculum)")
    tr.add_argument("--curriculum-level-steps", type=int, default=0, metavar="N",
                    help="a curriculum level lasts at most N timesteps, then the legs lengthen even if training "
                         "success is under the gate (default 0: until the gate is met)")
    tr.add_argument("--eval-every", type=int, default=1_000_000, help="timesteps between validation evaluations")
    tr.add_argument("--eval-episodes", type=int, default=500, help="validation episodes per evaluation (default 500)")
    tr.add_argument("--checkpoint-every", type=int, default=2_000_000, help="timesteps between checkpoints (0: none)")
    tr.add_argument("--record-flights", type=int, default=8, metavar="N",
                    help="fixed validation tasks flown and recorded at step 0 and every evaluation, for "
                         "view-training, the report and export (default 8; 0: none)")
    tr.add_argument("--resume", type=Path, default=None, help="resume from a checkpoint or policy folder")
    tr.add_argument("--out", type=Path, default=Path("runs/policy"),
                    help="policy folder to write (default runs/policy); an existing non-empty one is refused "
                         "unless --resume or --overwrite")
    tr.add_argument("--overwrite", action="store_true", help="replace the policy in a non-empty --out")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.set_defaults(func=_cmd_train)


def _add_evaluate_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    ev.set_defaults(func=_cmd_evaluate)


class _CliFormatter(logging.Formatter):
    """Log records as the CLI's own lines: "uam-compare: warning: <message>"."""

    def format(self, record: logging.LogRecord) -> str:
        return f"uam-compare: {record.levelname.lower()}: {record.getMessage()}"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv
    handler = logging.StreamHandler()  # a no-op where the caller configured logging already (basicConfig)
    # without -v a user sees the same "uam-compare: warning: ..." lines as the CLI's own warnings
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s") if args.verbose else _CliFormatter())
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, handlers=[handler])
    if args.command is None:
        parser.print_help()
        return 0
    # SIGTERM stops a command the way Ctrl-C does (a run keeps its finished episodes and says how to resume);
    # only the main thread may set handlers, and the previous one comes back for library callers.
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler) if in_main else None
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print(f"uam-compare: interrupted ({args.command}); its outputs are written whole or not at all",
              file=sys.stderr)
        return INTERRUPTED_EXIT
    except ValueError as exc:   # bad user input (ConfigError is a ValueError): one clear line, non-zero exit
        print(f"uam-compare: error: {exc}", file=sys.stderr)
        return BAD_INPUT_EXIT
    except OSError as exc:      # the file system said no (disk full, permissions): which file, and why
        print(f"uam-compare: error: {_os_error_message(exc)}", file=sys.stderr)
        return BAD_INPUT_EXIT
    except (Exception, SystemExit) as exc:  # the last resort: one line, the traceback in a file
        if isinstance(exc, SystemExit) and exc.code in (None, 0):
            return 0
        print(f"uam-compare: error: {args.command}: internal error {_last_resort(exc, args.command)}",
              file=sys.stderr)
        return INTERNAL_ERROR_EXIT
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)


BAD_INPUT_EXIT = 2  # bad input (a file, a key, an option): the one error line says which and why
INTERNAL_ERROR_EXIT = 1  # anything else: a bug or a broken installation; the traceback is in a log file
LOG_DIR_ENV = "UAM_COMPARE_LOG_DIR"
"""Where the last-resort handler writes tracebacks (default: <temporary folder>/uam-compare-logs)."""


def _last_resort(exc: BaseException, command: str) -> str:
    """Log `exc`'s full traceback to a new file in the log folder; returns the rest of the one error line: the
    exception, and where its traceback is (or why it could not be written)."""
    what = f"({type(exc).__name__}: {_one_line(str(exc))})"
    folder = Path(os.environ.get(LOG_DIR_ENV) or Path(tempfile.gettempdir()) / "uam-compare-logs")
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f"{datetime.now().strftime('%Y%m%d-%H%M%S')}-{command}-",
                                    suffix=".log", dir=folder)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(f"uam-compare {' '.join(sys.argv[1:])}\n{text}")
    except OSError as log_exc:
        return f"{what}; the traceback could not be logged in {folder} ({log_exc.strerror or log_exc})"
    return f"{what}; full traceback in {name}"


MAX_MESSAGE_CHARS = 300


def _one_line(text: str) -> str:
    """`text` on one line, at most `MAX_MESSAGE_CHARS` characters."""
    flat = " ".join(text.split())
    return flat if len(flat) <= MAX_MESSAGE_CHARS else flat[:MAX_MESSAGE_CHARS] + "..."


def _os_error_message(exc: OSError) -> str:
    """One line for a failed read or write: the file, the system's reason, and for a full disk what was kept.

    A temporary of an atomic write (".<name>.partial-...") is named by the file it was to become: the user never
    made it and will not find it.
    """
    filename = exc.filename
    if filename is not None and TEMP_MARK in Path(str(filename)).name:
        temp = Path(str(filename))
        filename = temp.with_name(temp.name[1:].split(TEMP_MARK)[0])
    text = f"{filename}: {exc.strerror or exc}" if filename is not None else str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        text += ": the disk is full; the file was not written (no partial file is left)"
    return text


if __name__ == "__main__":
    sys.exit(main())
