"""`run` (and `run --resume`): fly the pilots through scenarios and write the run folder; `sweep`: `run` on the
robustness sweep."""
from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime
from pathlib import Path

from compare.cli.common import CommandInterrupted, add_deprecated_alias, csv_list, one_torch_thread
from compare.cli.printout import print_run_results
from compare.flying.pilots import PILOT_NAMES, pilot
from compare.results.outputs import check_output_dir
from compare.results.run_info import RUN_INFO_NAME
from compare.run.backends import BACKENDS
from compare.run.campaign import RunConfig, RunInterrupted, check_empty_run_folder, estimate_run, run_comparison
from compare.scenarios.levels import MAP_ERROR_LEVELS, SENSING_LEVELS, with_levels
from compare.scenarios.scenario import Scenario, with_pilots
from compare.scenarios.sets import resolve_scenarios
from compare.scenarios.sweep import SWEEP_SETS, build_sweep


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `run` and `sweep` to the command line."""
    run_parser = sub.add_parser("run", help="fly both pilots through scenarios and write metrics and the PDF report")
    run_parser.add_argument("scenario", nargs="?", default="default",
                            help="a built-in set (default, full, benchmark, benchmark-quick, benchmark-validation, "
                                 "sweep, sweep-quick), a scenario YAML or a folder of them (default: default)")
    _add_run_options(run_parser)
    run_parser.set_defaults(func=run)
    sweep_parser = sub.add_parser("sweep", help="fly the robustness sweep (success and collision against density "
                                                "altitude and steady wind, every pilot on the same tasks): `run "
                                                "sweep` with a per-step table; the report draws it")
    sweep_parser.add_argument("--quick", action="store_true",
                              help="the sweep-quick set (the first city, two legs, every step: minutes) instead of "
                                   "sweep")
    sweep_parser.add_argument("--vehicle", action="append", default=None, metavar="VEHICLE",
                              help="only this vehicle's sweep (small_quad, uam_multicopter); repeat for more "
                                   "(default: both)")
    _add_run_options(sweep_parser)
    sweep_parser.set_defaults(func=sweep)


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    """The options of `run` (and `sweep`): pilots, policies, seeds, jobs, output, resume, backend, videos; their
    defaults are `RunConfig`'s."""
    _add_pilot_options(parser)
    parser.add_argument("--policy", type=Path, action="append", default=[],
                        help="policy folder for ppo, for the vehicle it was trained for; repeat for other vehicles "
                             "(default: the shipped policy of each vehicle)")
    parser.add_argument("--seeds", type=parse_seeds, default=RunConfig.seeds,
                        help="comma-separated seeds overriding the scenarios' own (distinct, 0 to 2**32 - 1)")
    parser.add_argument("--jobs", type=int, default=RunConfig.jobs,
                        help="parallel worker processes (default %(default)s; 1 flies in this process, where a "
                             "pilot's exception is recorded as a failed cell but a crash or a hang stops the run; "
                             "2 or more, or --cell-timeout, fly in worker processes, replaced when one dies or "
                             "hangs); with --backend ray the CPUs of the local Ray instance")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default: runs/<time>-<scenario>)")
    parser.add_argument("--resume", action="store_true",
                        help="complete an interrupted run in --out: fly only the cells without an episode file "
                             "(failed cells included); saved episodes are kept as they are")
    parser.add_argument("--cell-timeout", type=float, default=RunConfig.cell_timeout_s, metavar="SECONDS",
                        help="wall-time limit of every cell; a cell over it is recorded as failed (hang) and its "
                             "worker replaced (default: 300 s + 10 x the episode's simulated time limit x the "
                             "pilot's wall time per simulated second); with --jobs 1 giving it flies the cells in "
                             "one worker process (in this process nothing could stop a cell)")
    parser.add_argument("--backend", choices=BACKENDS, default=RunConfig.backend,
                        help="where cells fly (default %(default)s): local processes or Ray tasks (pip install -e "
                             "\".[ray]\"; see docs/scale_out.md)")
    parser.add_argument("--address", default=RunConfig.address, metavar="ADDR",
                        help="with --backend ray: the Ray cluster's head node, e.g. 10.0.0.5:6379 or "
                             "ray://host:10001 (default: start a local Ray instance with --jobs CPUs)")
    parser.add_argument("--videos", choices=("scenario", "all", "none"), default=None,
                        help="cells to animate into RUN_DIR/videos/: the first of each scenario (the default, but "
                             "none for a benchmark set: its product is numbers; `animate` draws any cell later), "
                             "all, none")
    parser.add_argument("--store", choices=("control", "full"), default=RunConfig.store,
                        help="samples kept per episode in RUN_DIR/store/ (default %(default)s): the control rate "
                             "(everything the report, viewer and animation draw) or every physics step; the "
                             "metrics are the same")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--sensing", choices=SENSING_LEVELS, default=None,
                        help="fly every scenario at this sensing level, in place of its own `sensing:` "
                             "(docs/sensing.md)")
    parser.add_argument("--map-error", choices=MAP_ERROR_LEVELS, default=None,
                        help="fly every scenario with this map error, in place of its own `map_error:` "
                             "(docs/sensing.md)")
    parser.add_argument("--tier", type=parse_tier, action="append", default=[], metavar="SENSING/MAP_ERROR",
                        help="fly only the scenarios at this sensing and map-error level, e.g. nominal/wrong (a "
                             "benchmark set's cell, after --sensing and --map-error); repeat for more (default: "
                             "every scenario)")


def _add_pilot_options(parser: argparse.ArgumentParser) -> None:
    """--pilot (repeated) and --pilots, and their old spellings --method and --methods (hidden, with a warning)."""
    one = parser.add_argument("--pilot", action="append", default=[], metavar="PILOT",
                              help="fly this pilot too, in every scenario: a registered pilot, a plug-in as "
                                   "module:Class or an installed plug-in's entry-point name; repeat for more")
    some = parser.add_argument("--pilots", type=csv_list, default=RunConfig.pilots,
                               help=f"comma-separated pilots to fly, of each scenario's own and --pilot's "
                                    f"({','.join(PILOT_NAMES)}, plug-ins)")
    add_deprecated_alias(parser, "--method", one)
    add_deprecated_alias(parser, "--methods", some)


def parse_tier(text: str) -> tuple[str, str]:
    """--tier's value "SENSING/MAP_ERROR" as (sensing level, map-error level), both known levels."""
    sensing, sep, map_error = text.partition("/")
    if not sep or sensing not in SENSING_LEVELS or map_error not in MAP_ERROR_LEVELS:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected SENSING/MAP_ERROR with SENSING one of {', '.join(SENSING_LEVELS)} and MAP_ERROR "
            f"one of {', '.join(MAP_ERROR_LEVELS)}, e.g. nominal/wrong")
    return sensing, map_error


def only_tiers(scenarios: Sequence[Scenario], tiers: Sequence[tuple[str, str]], spec: str) -> list[Scenario]:
    """The scenarios flown at one of `tiers` ((sensing, map-error) levels); all of them when `tiers` is empty.

    Raises:
        ValueError: no scenario of `spec` is at any of them (naming the levels it has).
    """
    if not tiers:
        return list(scenarios)
    kept = [sc for sc in scenarios if (sc.sensing.level, sc.map_error.level) in set(tiers)]
    if not kept:
        there = sorted({f"{sc.sensing.level}/{sc.map_error.level}" for sc in scenarios})
        raise ValueError(f"--tier {', '.join(f'{s}/{m}' for s, m in tiers)}: no scenario of {spec} is flown at it "
                         f"(its levels: {', '.join(there)})")
    return kept


def parse_seeds(text: str) -> tuple[int, ...]:
    """`--seeds`: comma-separated integers (their range and distinctness are checked with the scenarios' rule)."""
    try:
        return csv_list(text, int)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, e.g. 0,1,2, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    """`run`: check the options, read every scenario, fly, and print the results (their JSON line last)."""
    for flag, names in (("--pilot", args.pilot), ("--pilots", args.pilots or ())):
        for name in names:  # registered, or a plug-in (imported here, before anything flies)
            try:
                pilot(name)
            except ValueError as exc:
                raise ValueError(f"{flag}: {exc}") from None
    out = args.out if args.out is not None else _default_run_dir(args.scenario)
    opts = _run_config(args, out)
    opts.validate()  # e.g. Ray missing: before anything is read or flown
    if args.jobs > (os.cpu_count() or 1):
        print(f"uam-compare: warning: --jobs {args.jobs} is more than the {os.cpu_count()} CPUs here; the extra "
              f"processes only compete for them", file=sys.stderr)
    check_output_dir(out, "--out")
    if args.resume:
        check_resumable(args.out)
    else:
        check_empty_run_folder(out)
    scenarios = [with_levels(with_pilots(sc, tuple(args.pilot)), args.sensing, args.map_error)
                 for sc in _scenarios(args)]  # every file checked here
    scenarios = only_tiers(scenarios, args.tier, args.scenario)
    opts = replace(opts, videos=resolve_videos(args.videos, scenarios))  # its default depends on the scenarios
    one_torch_thread()
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
        raise CommandInterrupted(f"{stop.kept} of {stop.cells} episodes kept in {stop.out_dir}; to fly the rest: "
                                 f"{shlex.join(again)}") from None
    print_run_results(run_dir)
    return 0


def check_resumable(out: Path | None) -> None:
    """`--resume` completes a run: refuse an --out that is not a run folder (none given, no such folder, no
    run.json), rather than start a new run where a typo points (`check_resume` then compares its inputs)."""
    if out is None:
        raise ValueError("--resume: give --out, the run folder to complete")
    if not (out / RUN_INFO_NAME).is_file():
        what = "no such folder" if not out.exists() else f"no {RUN_INFO_NAME}"
        raise ValueError(f"{out}: cannot resume: not a run folder of uam-compare ({what}); nothing was written "
                         f"(to start a new run, leave out --resume)")


def _run_config(args: argparse.Namespace, out: Path) -> RunConfig:
    """The run's settings from the options (--videos' default is settled once the scenarios are read)."""
    videos = {} if args.videos is None else {"videos": args.videos}
    return RunConfig(out_dir=out, pilots=args.pilots, seeds=args.seeds, policies=tuple(args.policy), jobs=args.jobs,
                     resume=args.resume, progress=not args.no_progress, command="uam-compare " + " ".join(args.argv),
                     backend=args.backend, address=args.address, cell_timeout_s=args.cell_timeout, store=args.store,
                     **videos)


def _scenarios(args: argparse.Namespace) -> list[Scenario]:
    """The scenarios the command flies, every file validated (a sweep's only for its --vehicle's)."""
    if args.command == "sweep":
        only = tuple(args.vehicle) if args.vehicle else None
        return list(build_sweep(args.scenario, vehicles=only).scenarios)
    return resolve_scenarios(args.scenario)


def _default_run_dir(spec: str) -> Path:
    """runs/<time>-<scenario stem>, numbered on when that folder exists."""
    stem = Path(spec).stem if spec.endswith((".yaml", ".yml")) else Path(spec).name
    base = Path("runs") / f"{datetime.now().strftime('%Y%m%d-%H%M%S')}-{stem}"
    out, k = base, 1
    while out.exists():
        k += 1
        out = base.with_name(f"{base.name}-{k}")
    return out


def resolve_videos(chosen: str | None, scenarios: Sequence[Scenario]) -> str:
    """--videos, or its default: `RunConfig`'s (the first cell of each scenario), but none for a benchmark set
    (dozens of scenarios)."""
    if chosen is not None:
        return chosen
    return "none" if any(sc.task_set is not None for sc in scenarios) else RunConfig.videos


def sweep(args: argparse.Namespace) -> int:
    """`sweep`: `run` on the sweep set (or sweep-quick)."""
    args.scenario = SWEEP_SETS[1] if args.quick else SWEEP_SETS[0]
    return run(args)

