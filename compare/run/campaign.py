"""A comparison run: every (scenario, episode, seed, pilot) cell flown, saved, scored and reported.

`run_comparison(scenarios, options)` writes a run folder:

```
RUN_DIR/run.json        provenance: scenarios, pilots, software versions, fairness statement, command
RUN_DIR/maps/*.yaml     the city of each scenario (reports never need the scenario files again)
RUN_DIR/store/          the episodes (`compare.results.store`): each cell's part written atomically as it
                        finishes, compacted into an episode table and samples files when the run is scored
RUN_DIR/failed/*.json   one per cell that produced no episode, and why (`compare.results.failures`)
RUN_DIR/metrics.csv     one row per cell (`compare.results.metrics`)
RUN_DIR/summary.json    per vehicle and scenario: means with 95 % intervals, paired differences, their MDDs
RUN_DIR/report.pdf      the report (`compare.report.report`); RUN_DIR/figures/*.png its pages
```

Cells are independent and seeded from the cell alone (`compare.flying.seeding`), so they run in any order
in any number of processes (`jobs`) or on Ray (`compare.run.backends`) with the same results. One cell's
failure (its pilot raised; its worker process died; it gave no result within its wall-time limit,
`cell_limit_s`) is recorded as a failed cell and the run goes on. An interrupted run keeps every episode
finished so far; `finalize(RUN_DIR)` (the `report` command) compacts the store, gathers the metrics the cells
computed and reports them (an unreadable part is skipped with a warning and listed in the report), and
`resume=True` flies only the cells without an episode (failed and unreadable ones included), after checking
that the folder is a run saved from the same inputs (`compare.scenarios.fingerprint`). A run folder saved before the
store (one `.npz` per episode) reads and rescores as it did.
"""
from __future__ import annotations

import errno
import logging
import os
import platform
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

from tqdm import tqdm

from compare.flying import pilots
from compare.results.episodes import kept_keys, open_episodes, refuse_bad_rows
from compare.results.failures import (
    FAILED_DIR,
    FailedCell,
    FailureKind,
    describe_failures,
    read_failures,
    remove_failure,
    write_failure,
)
from compare.results.metrics import label_vehicles, read_metrics_csv, write_metrics_csv
from compare.results.run_folder import check_run_folder_links
from compare.results.run_info import (
    PRIOR_MAPS,
    RUN_INFO_NAME,
    AirEnvelope,
    AtmosphereInfo,
    PilotInfo,
    PolicyRecord,
    RunInfo,
    ScenarioInfo,
    TaskSetInfo,
    WindInfo,
    write_run_info,
)
from compare.results.sensing_facts import SensingEnvelope
from compare.results.store import compact, part_path
from compare.results.summary import summarize_run, write_summary_json
from compare.results.tables import STORE_MODES
from compare.run.backends import check_backend, open_backend
from compare.run.backends.base import Backend, CellFlown, CellJob, WorkerSetup
from compare.run.cells import Cell, cell_key
from compare.run.trained_air import air_envelope, outside_trained_air, sensed_facts, sensing_envelope
from compare.scenarios.fingerprint import check_resume, run_fingerprints
from compare.scenarios.scenario import Scenario, seeds_problem
from rl.policies.folder import shipped_policy_dir
from uam_fdm.city.generator import map_yaml_text
from uam_fdm.files.atomic import remove_stale_temporaries, write_text_atomic
from uam_fdm.files.lock import LOCK_NAME, folder_lock
from uam_fdm.vehicle.params import load_vehicle

log = logging.getLogger(__name__)

FAIRNESS_COMMON = (
    "{every} pilots fly the same vehicle model (6-DOF, rotor dynamics, JSBSim atmosphere) at the same physics "
    "rate, each at its own decision rate (the rates are in run.json), and each decision is timed with the same "
    "stopwatch. {every} know the vehicle's parameters and its sensors' specifications, the prior building map (the "
    "city as surveyed: the city as it stands where the map error is exact), the air density and the forecast "
    "turbulence level (none/light/moderate/severe). {none} knows the wind: {all} fly the same seeded steady wind "
    "and turbulence realisation, and meet the same sensor noise, in each episode.")
FAIRNESS_SENSING = {
    "perfect": "At perfect sensing each decision gets the full true vehicle state (perfect state estimation).",
    "sensed": "At {levels} sensing each decision gets the navigation filter's estimate (an error-state EKF fusing "
              "the IMU, barometer, GNSS receiver and heading aid) with its covariance, as old as the sensing "
              "latency, and the readings since the previous decision (lidar scans, GNSS fixes, barometer and heading); "
              "the velocity controller flies on the current estimate.",
}
FAIRNESS_TRUTH = ("The true city (with what the prior map lacks) and the true state stay with the simulator, which "
                  "scores every metric on them.")
FAIRNESS_CLEARANCE = ("Clearance is measured at every physics step from the vehicle's collision sphere to the "
                      "buildings and the ground.")
VIDEOS_DIR = "videos"  # the run's animations, one file per animated cell
WARN_RUN_HOURS = 3.0  # the CLI warns above these estimates before flying
WARN_RUN_GB = 3.0
# A cell's default wall-time limit: CELL_LIMIT_BASE_S + CELL_LIMIT_FACTOR x its simulated time limit x its pilot's
# wall_s_per_flight_s. Generous: a slow cell wrongly killed costs more than a hung one found late; the base
# covers a worker's first cell (imports, building the flight model and the pilot) on a busy machine.
CELL_LIMIT_BASE_S = 300.0
CELL_LIMIT_FACTOR = 10.0


@dataclass(frozen=True)
class RunConfig:
    """How to run.

    Attributes:
        out_dir: the run folder.
        pilots: only these pilots (None: each scenario's own list).
        seeds: override every scenario's seeds (None: the scenarios' own).
        policies: the learned pilot's policy folders, at most one per vehicle (each records the
            vehicle it was trained for); a vehicle without one flies its shipped policy, if any.
        jobs: parallel processes (1: in this process, unless `cell_timeout_s` is given); with the Ray backend
            the CPUs of the local Ray instance it starts (with `address`: at most this many cells in flight
            when > 1, else one per CPU of the cluster).
        resume: skip cells whose episode file already exists (failed cells are flown again); refuse a folder
            that is not a run of this tool or was saved from other inputs
            (`compare.scenarios.fingerprint.check_resume`).
        progress: show a progress bar.
        command: the command line, for provenance.
        report: build the PDF report and the HTML viewer at the end.
        videos: which cells to animate into `videos/` at the end: "scenario" (the first cell of each
            scenario), "all" or "none" (see `compare.playback.animate.render_videos`).
        backend: where cells fly: "local" (this process or worker processes) or "ray" (`compare.run.backends`).
        address: the Ray cluster to run on (None: a local Ray instance of `jobs` CPUs); only with "ray".
        cell_timeout_s: every cell's wall-time limit [s] (None: `cell_limit_s`'s default per cell). A cell over
            it is a failed cell ("hang") and its worker is replaced; in this process (one job, no limit given)
            cells have no limit.
        store: the samples each episode keeps: "control" (the control rate, rounded) or "full" (every physics
            step); the metrics are the same either way (`compare.results.tables`).
    """

    out_dir: Path
    pilots: tuple[str, ...] | None = None
    seeds: tuple[int, ...] | None = None
    policies: tuple[Path, ...] = ()
    jobs: int = 1
    resume: bool = False
    progress: bool = True
    command: str = ""
    report: bool = True
    videos: str = "scenario"
    backend: str = "local"
    address: str | None = None
    cell_timeout_s: float | None = None
    store: str = "control"

    @property
    def in_process(self) -> bool:
        """Cells fly in this process (no worker to survive a crash or enforce a time limit)."""
        return self.backend == "local" and self.jobs <= 1 and self.cell_timeout_s is None

    def validate(self) -> None:
        """Raise ValueError for an option no run can take, naming it as the command line does: the one check of
        each option, made by `run_comparison` and, before it reads any scenario, by the CLI.

        Raises:
            ValueError: seeds that a scenario's `seeds` would refuse, jobs < 1, a cell timeout <= 0, an unknown
                backend, an address without Ray or Ray missing (`check_backend`), an unknown `videos`.
        """
        from compare.playback.animate import VIDEO_CHOICES  # matplotlib, which the run's figures import anyway

        if self.seeds is not None and (problem := seeds_problem(list(self.seeds))) is not None:
            index, reason = problem  # the same limits as a scenario's `seeds`
            where = "" if index is None else f" (index {index})"
            raise ValueError(f"--seeds {','.join(map(str, self.seeds))}{where}: {reason}")
        if self.jobs < 1:
            raise ValueError(f"--jobs {self.jobs}: must be >= 1")
        if self.cell_timeout_s is not None and not self.cell_timeout_s > 0.0:
            raise ValueError(f"--cell-timeout {self.cell_timeout_s:g}: must be > 0 s")
        check_backend(self.backend, self.address)
        if self.videos not in VIDEO_CHOICES:  # checked before flying, not when the videos are due
            raise ValueError(f"--videos {self.videos!r}: choose from {', '.join(VIDEO_CHOICES)}")
        if self.store not in STORE_MODES:
            raise ValueError(f"--store {self.store!r}: choose from {', '.join(STORE_MODES)}")


@dataclass(frozen=True)
class PolicyFacts:
    """What a run needs to know of the learned pilot's policy before flying.

    Attributes:
        folder: the policy folder.
        vehicle: the name of the vehicle it was trained for (its config.json's nav.vehicle).
        vehicle_fingerprint: `VehicleParams.fingerprint()` of the vehicle it was trained for.
        control_hz: the low-level controller rate it was trained with [Hz].
        decision_hz: the rate at which it chooses a command [Hz] (held for the control periods between).
        envelope: the air it was trained in (None: not known).
        sensing: the sensing and map error it was trained across (None: not known).
    """

    folder: Path
    vehicle: str
    vehicle_fingerprint: str
    control_hz: float
    decision_hz: float
    envelope: AirEnvelope | None = None
    sensing: SensingEnvelope | None = None


def plan_cells(scenarios: Sequence[Scenario], opts: RunConfig,
               policies: Mapping[str, PolicyFacts] | None) -> tuple[list[Cell], list[str]]:
    """The cells to fly, in a fixed order, and notes on cells left out (e.g. no policy for a vehicle).

    `policies`: the policies of the pilots that need one (`compare.flying.pilots.PilotEntry.needs_policy`), by
    vehicle fingerprint (`select_policies`); None: not known yet (an estimate), every cell is kept.

    Raises:
        ValueError: a scenario that flies a policy runs its controller at another rate than the policy
            was trained with (the policy's decisions would be held for the wrong time).
    """
    cells, notes = [], []
    for si, sc in enumerate(scenarios):
        flown = [m for m in sc.pilots if opts.pilots is None or m in opts.pilots]
        policy = policies.get(sc.vehicle.fingerprint()) if policies is not None else None
        for m in [name for name in flown if pilots.pilot(name).needs_policy]:
            if policies is not None and policy is None:
                flown.remove(m)
                notes.append(f"{sc.name}: no learned policy for vehicle {sc.vehicle_name!r} "
                             f"({_why_no_policy(sc, opts, policies)}); {m} not flown")
            elif policy is not None and abs(sc.control_hz - policy.control_hz) > 1e-9:
                others = ",".join(o for o in flown if o != m)
                raise ValueError(
                    f"{sc.source}: control_hz {sc.control_hz:g}: the policy {policy.folder} was trained with a "
                    f"{policy.control_hz:g} Hz controller (its config.json, nav.control_hz); fly this scenario at "
                    f"{policy.control_hz:g} Hz, without {m}{f' (--pilots {others})' if others else ''}, or with "
                    f"a policy trained for it")
        seeds = opts.seeds if opts.seeds is not None else sc.seeds
        for ep in sc.episodes:
            for seed in seeds:
                for m in flown:
                    cells.append(Cell(si, ep.index, int(seed), m))
    return cells, notes


@dataclass(frozen=True)
class RunEstimate:
    """Upper bounds of what a run costs, every episode flown to its timeout.

    Attributes:
        cells: episodes to fly (scenario x episode x seed x pilot).
        flight_s: simulated flight time of all cells [s].
        wall_h: wall time with `jobs` processes [h] (each pilot's `wall_s_per_flight_s` per simulated second).
        disk_gb: the run store, uncompressed [GB] (float64 time and position, float32 rest of the state, rotor
            commands, wind, clearance and shaft power, per control period or, `--store full`, per physics step).
    """

    cells: int
    flight_s: float
    wall_h: float
    disk_gb: float

    @property
    def large(self) -> bool:
        """More than WARN_RUN_HOURS or WARN_RUN_GB."""
        return self.wall_h > WARN_RUN_HOURS or self.disk_gb > WARN_RUN_GB


def estimate_run(scenarios: Sequence[Scenario], opts: RunConfig) -> RunEstimate:
    """Estimate a run's time and disk from its scenarios and options, without flying or loading a policy."""
    cells, _ = plan_cells(scenarios, opts, None)
    flight_s = wall_s = n_bytes = 0.0
    for c in cells:
        sc = scenarios[c.scenario]
        t = sc.episodes[c.episode].task.timeout_s
        flight_s += t
        wall_s += t * pilots.pilot(c.pilot).wall_s_per_flight_s
        n = sc.vehicle.n_rotors
        rate_hz = sc.physics_hz if opts.store == "full" else sc.control_hz
        n_bytes += t * rate_hz * (8 * 4 + 4 * ((10 + n) + n + 3 + 1 + 1))  # t and position, state, commands, ...
    workers = max(1, min(opts.jobs, os.cpu_count() or 1))
    return RunEstimate(len(cells), flight_s, wall_s / workers / 3600.0, n_bytes / 1e9)


def cell_limit_s(scenarios: Sequence[Scenario], c: Cell, opts: RunConfig) -> float | None:
    """The wall-time limit of cell `c` [s]: `opts.cell_timeout_s` when given, else CELL_LIMIT_BASE_S +
    CELL_LIMIT_FACTOR x the episode's simulated time limit x its pilot's `wall_s_per_flight_s`; None in this
    process (nothing could stop the cell)."""
    if opts.in_process:
        return None
    if opts.cell_timeout_s is not None:
        return float(opts.cell_timeout_s)
    timeout_s = scenarios[c.scenario].episodes[c.episode].task.timeout_s
    return CELL_LIMIT_BASE_S + CELL_LIMIT_FACTOR * timeout_s * pilots.pilot(c.pilot).wall_s_per_flight_s


class RunInterrupted(Exception):
    """Ctrl-C or SIGTERM stopped a run; the episodes finished so far are kept.

    Attributes:
        out_dir: the run folder.
        kept: episode files in it.
        cells: episodes the run asked for.
    """

    def __init__(self, out_dir: Path, kept: int, cells: int) -> None:
        super().__init__(f"{out_dir}: interrupted with {kept} of {cells} episodes kept")
        self.out_dir, self.kept, self.cells = out_dir, kept, cells


def _remove_stale_temporaries(run_dir: Path) -> None:
    stale = remove_stale_temporaries(run_dir)
    if stale:
        log.info("removed %d temporary files left by an interrupted write: %s", len(stale),
                 ", ".join(str(p.relative_to(run_dir)) for p in stale))


def versions() -> dict[str, str]:
    """Versions of the software that produced a run."""
    out = {"python": platform.python_version()}
    for dist in ("uam-compare", "numpy", "casadi", "ompl", "jsbsim", "python-fcl", "shapely", "torch",
                 "stable-baselines3", "gymnasium", "matplotlib"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def write_run_files(scenarios: Sequence[Scenario], opts: RunConfig, cells: Sequence[Cell], notes: Sequence[str],
                    fingerprints: dict, policies: Sequence[PolicyFacts] = ()) -> None:
    """run.json (with the inputs' `fingerprints`, see `compare.scenarios.fingerprint`, the policy folders of the pilots
    that fly one, their vehicles and decision rates, the pilots in table order) and maps/*.yaml."""
    out = opts.out_dir
    for sc in scenarios:
        write_text_atomic(out / "maps" / f"{sc.name}.yaml", map_yaml_text(sc.city), root=out)
        if sc.prior_map is not sc.city:  # the pilots' map, where it differs from the city as it stands
            write_text_atomic(out / "maps" / PRIOR_MAPS / f"{sc.name}.yaml", map_yaml_text(sc.prior_map), root=out)
    flown = pilots.ordered(c.pilot for c in cells)
    entries = [pilots.pilot(m) for m in flown]
    at_control_rate = [s.name for s in entries if not s.needs_policy]
    if policies:
        rates = "; ".join(f"for {p.vehicle} at {p.decision_hz:g} Hz (each command held for "
                          f"{p.control_hz / p.decision_hz:g} control periods)" for p in policies)
        rest = f"; {', '.join(at_control_rate)} at each scenario's control rate" if at_control_rate else ""
        notes = [*notes, *(f"{s.name} decides at its policy's rate: {rates}{rest}" for s in entries if s.needs_policy)]
    records = tuple(PolicyRecord(p.vehicle, str(p.folder), p.decision_hz, p.envelope, p.sensing) for p in policies)
    info = RunInfo(
        created_utc=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), command=opts.command,
        scenarios=tuple(scenario_info(sc, [c for c in cells if c.scenario == si]) for si, sc in enumerate(scenarios)),
        notes=tuple(notes),
        pilots={s.name: PilotInfo(s.label, s.description, records if s.needs_policy else (),
                                 "" if s.name in pilots.PILOTS else s.color) for s in entries},
        versions=versions(), fairness=fairness(flown, [sc.sensing.label for sc in scenarios]),
        fingerprints=fingerprints, task_set=run_task_set(scenarios))
    write_run_info(info, out)


def run_task_set(scenarios: Sequence[Scenario]) -> TaskSetInfo | None:
    """The published task set (benchmark) the run's scenarios all come from, else None."""
    task_sets = {sc.task_set for sc in scenarios}
    return task_sets.pop() if len(task_sets) == 1 else None


def scenario_info(sc: Scenario, cells: Sequence[Cell]) -> ScenarioInfo:
    """What run.json records of a scenario flown as `cells` (its own cells)."""
    p = sc.vehicle
    rho = sc.air.density_kg_m3(0.0)
    return ScenarioInfo(
        name=sc.name, source=str(sc.source), description=sc.description, map_name=sc.city.name or sc.name,
        vehicle=sc.vehicle_name,
        vehicle_summary=f"{p.mass_kg:g} kg, {p.n_rotors} rotors, collision radius {p.collision_radius_m:g} m",
        atmosphere=AtmosphereInfo(sc.atmosphere.elevation_m, sc.atmosphere.isa_offset_k, round(float(rho), 4)),
        wind=WindInfo(sc.wind.steady_enu_m_s, sc.wind.turbulence.value, sc.wind.shear),
        episodes=len(sc.episodes), seeds=tuple(sorted({c.seed for c in cells})),
        pilots=tuple(pilots.ordered(c.pilot for c in cells)), physics_hz=sc.physics_hz, control_hz=sc.control_hz,
        sensing=sc.sensing.label, map_error=sc.map_error.label, sensed=sensed_facts(sc.sensing),
        missing_fraction=sc.map_error.missing_fraction)


def fairness(flown: Sequence[str], sensing_levels: Sequence[str] = ("perfect",)) -> str:
    """The run's fairness statement for the pilots flown at the sensing levels flown: what every pilot shares, what
    each decision gets at each level, then what each pilot is given."""
    every, none, all_ = ("Both", "Neither", "both") if len(flown) <= 2 else ("All", "None", "all")
    common = FAIRNESS_COMMON.format(every=every, none=none, all=all_)
    levels = sorted(set(sensing_levels))
    sensed = [lv for lv in levels if lv.rstrip("+") != "perfect"]
    by_level = ([FAIRNESS_SENSING["perfect"]] if len(sensed) < len(levels) else []) + (
        [FAIRNESS_SENSING["sensed"].format(levels=" and ".join(sensed))] if sensed else [])
    return " ".join([common, *by_level, FAIRNESS_TRUTH, *(pilots.pilot(m).given for m in pilots.ordered(flown)),
                     FAIRNESS_CLEARANCE])


def run_comparison(scenarios: Sequence[Scenario], opts: RunConfig) -> Path:
    """Fly every cell, then score and report (see the module docstring). Returns the run folder.

    Raises:
        ValueError: a bad option (`RunConfig.validate`), a bad policy, nothing to fly, a refused resume, or a
            backend that cannot start; before the run folder is written.
    """
    opts.validate()
    scenarios = list(scenarios)
    policies = select_policies(scenarios, opts)
    cells, notes = plan_cells(scenarios, opts, policies)
    if not cells:
        raise ValueError("nothing to fly: no (scenario, pilot) left after --pilots")
    out = Path(opts.out_dir)
    flown = {scenarios[c.scenario].vehicle.fingerprint() for c in cells if pilots.pilot(c.pilot).needs_policy}
    used = [f for fp, f in policies.items() if fp in flown]
    # air outside a policy's training is flown all the same (where it breaks is the finding), warned and noted
    notes += outside_trained_air(scenarios, cells, {f.vehicle_fingerprint: f.envelope for f in used
                                                    if f.envelope is not None},
                                 {f.vehicle_fingerprint: f.sensing for f in used if f.sensing is not None})
    fingerprints = run_fingerprints(scenarios, {f.vehicle: f.folder for f in used})
    if opts.resume:  # before anything is written: a refused folder stays as it was
        # the seeds and pilots of each scenario as run.json records them (`scenario_info`)
        asked = {sc.name: (tuple(sorted({c.seed for c in cells if c.scenario == i})),
                           tuple(pilots.ordered(c.pilot for c in cells if c.scenario == i)))
                 for i, sc in enumerate(scenarios)}
        fingerprints = check_resume(out, fingerprints, asked)
    setup = WorkerSetup(tuple(scenarios), out, {f.vehicle_fingerprint: f.folder for f in used}, opts.store)
    t0 = time.perf_counter()
    # the backend starts before anything is written: a Ray cluster that cannot be reached leaves no folder
    jobs = min(opts.jobs, len(cells))  # a worker per cell at most: --jobs 64 for one cell starts one interpreter
    with (open_backend(opts.backend, setup, jobs, opts.address, isolate=not opts.in_process) as backend,
          folder_lock(out, opts.command or "uam-compare run")):
        check_run_folder_links(out)  # a link planted in a run folder being resumed leads no write out of it
        if not opts.resume:  # checked again under the lock: two runs started together into one --out
            check_empty_run_folder(out)
        else:  # the store's rows are of the cells run.json plans, each once, before anything is written
            refuse_bad_rows(out)
        _remove_stale_temporaries(out)
        for n in notes:  # cells left out (also in run.json and the report)
            log.warning("%s", n)
        write_run_files(scenarios, opts, cells, notes, fingerprints, used)
        kept = kept_keys(out) if opts.resume else set()  # an unreadable episode is flown again (and replaced)
        todo = [c for c in cells if cell_key(scenarios, c) not in kept]
        tasks = [CellJob(c, cell_key(scenarios, c), cell_limit_s(scenarios, c, opts)) for c in todo]
        bar = tqdm(total=len(todo), desc="episodes", unit="ep", disable=not opts.progress, file=sys.stderr)
        try:
            failed = _fly(backend, tasks, out, bar)
        except KeyboardInterrupt:  # Ctrl-C, or SIGTERM through the CLI: every finished episode is on disk
            backend.close()  # first: a worker must not write another episode after they are counted
            raise RunInterrupted(out, len(open_episodes(out).entries), len(cells)) from None
        finally:
            bar.close()
        log.info("flew %d cells (%d failed) in %.1f s", len(todo), len(failed), time.perf_counter() - t0)
        _finalize(out, report=opts.report)  # still under the lock: a `report` started now waits for none of it
        if opts.videos != "none":  # matplotlib, and ffmpeg's writer, only for a run that animates
            from compare.playback.animate import render_videos
            from compare.playback.flights import flight_groups
            # finalize has named any unreadable file, and its viewer every flight that does not draw
            groups = flight_groups(out, warn_unreadable=False, warn_undrawable=not opts.report)
            render_videos(groups, out / VIDEOS_DIR, opts.videos, progress=opts.progress, root=out)
    return out


def check_empty_run_folder(out: Path) -> None:
    """Refuse a new run's --out `out` if it holds anything but the lock (a run never writes into other files)."""
    if not out.exists():
        return
    if any(p.name != LOCK_NAME for p in out.iterdir()):
        raise ValueError(f"--out {out}: folder exists and is not empty (use --resume to complete it)")


def _fly(backend: Backend, tasks: Sequence[CellJob], out: Path, bar) -> list[FailedCell]:
    """Fly `tasks` on `backend`, keeping the run folder's record of failed cells: a failure is written as it
    happens, and a cell that flies removes the record of an earlier failure (a resumed run). Returns the
    failures of this run."""
    failed: list[FailedCell] = []
    for outcome in backend.fly(tasks):
        if isinstance(outcome, CellFlown):
            remove_failure(out, outcome.key)
        elif outcome.kind == FailureKind.DISK_FULL:  # every cell after it would fail the same: stop, name the file
            path = part_path(out, outcome.key)
            raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} while saving an episode ({len(failed)} cells "
                                        f"failed before it; `run --resume` flies the rest once there is room)",
                          str(path))
        else:
            write_failure(out, outcome)
            failed.append(outcome)
            log.warning("cell %s failed (%s): %s", outcome.key.stem, outcome.kind, outcome.reason)
            bar.set_postfix(failed=len(failed))
        bar.update(1)
    return failed


def policy_facts(policy: Path | None) -> PolicyFacts:
    """Load the whole policy folder (network, statistics, config) as plain data and return what a run
    needs of it: a broken or foreign policy is an error before the run folder exists."""
    from rl.pilots.learned import load_policy  # PyTorch: imported only by a run that flies a policy

    loaded = load_policy(policy)  # None: the shipped default
    nav = loaded.nav
    return PolicyFacts(loaded.folder.resolve(), nav.vehicle, load_vehicle(nav.vehicle).fingerprint(),
                       float(nav.control_hz), float(nav.decision_hz), air_envelope(nav.air), sensing_envelope(nav))


def _why_no_policy(sc: Scenario, opts: RunConfig, policies: Mapping[str, PolicyFacts]) -> str:
    """Why no policy flies `sc`'s vehicle (`policies`: those chosen, by vehicle fingerprint), for its note."""
    same_name = next((p.folder for p in policies.values() if p.vehicle == sc.vehicle_name),
                     shipped_policy_dir(sc.vehicle_name))
    if same_name is not None:  # a vehicle file that reuses a preset's name with other parameters
        return f"{same_name} was trained for the preset {sc.vehicle_name!r}, not for this vehicle's other parameters"
    given = {Path(f).resolve() for f in opts.policies}
    for_others = sorted({p.vehicle for p in policies.values() if p.folder in given})
    if for_others:
        return f"none shipped; --policy gives one for {', '.join(map(repr, for_others))} only"
    return "none shipped, none given with --policy"


def select_policies(scenarios: Sequence[Scenario], opts: RunConfig) -> dict[str, PolicyFacts]:
    """The policy for each vehicle that flies a pilot that needs one (`PilotEntry.needs_policy`), by vehicle
    fingerprint: the one given with --policy for that vehicle, else the shipped one trained for it (none:
    that pilot is not flown there).

    Raises:
        ValueError: two --policy folders for the same vehicle, or a broken policy folder (naming it).
    """
    def flies_policy(names: Sequence[str]) -> bool:
        return any(pilots.pilot(m).needs_policy for m in names)

    if opts.pilots is not None and not flies_policy(opts.pilots):
        return {}
    chosen: dict[str, PolicyFacts] = {}
    for folder in opts.policies:
        facts = policy_facts(folder)
        first = chosen.get(facts.vehicle_fingerprint)
        if first is not None:
            raise ValueError(f"--policy {folder}: a second policy for vehicle {facts.vehicle!r} "
                             f"(the first: {first.folder}); give one per vehicle")
        chosen[facts.vehicle_fingerprint] = facts
    for sc in scenarios:
        fp = sc.vehicle.fingerprint()
        if not flies_policy(sc.pilots) or fp in chosen:
            continue
        shipped = shipped_policy_dir(sc.vehicle.name)
        if shipped is not None:
            facts = policy_facts(shipped)
            if facts.vehicle_fingerprint == fp:  # a vehicle file that reuses a preset's name is not that preset
                chosen[fp] = facts
    return chosen


def finalize(run_dir: Path, report: bool = True) -> Path:
    """Compact the store, gather the episodes' metrics (metrics.csv, summary.json), build the report and the
    viewer; never simulates.

    Raises:
        ValueError: not a run folder, nothing readable to report, or (`FolderBusy`) a run or report is
            writing the folder now.
    """
    run_dir = Path(run_dir)
    if not (run_dir / RUN_INFO_NAME).is_file():
        raise ValueError(f"{run_dir}: not a run folder ({RUN_INFO_NAME} is missing)")
    with folder_lock(run_dir, "uam-compare report"):
        check_run_folder_links(run_dir)  # before any work: a store linked to another run is not this one's
        return _finalize(run_dir, report)


def _finalize(run_dir: Path, report: bool) -> Path:
    """`finalize` for a caller that holds the folder's lock."""
    _remove_stale_temporaries(run_dir)
    # an unreadable part stays where it is, is warned about by `compact`, left out here and flown again by --resume
    bad_parts = {b.path for b in compact(run_dir)}
    episodes = open_episodes(run_dir)
    failed = read_failures(run_dir)  # cells without an episode: no metrics row, listed in failed/
    listed = f"{describe_failures(failed)}, listed in {run_dir / FAILED_DIR}" if failed else ""
    if not episodes.entries and not episodes.unreadable:
        raise ValueError(f"{run_dir}: no saved episodes to report" + (f" ({listed})" if failed else ""))
    if failed:
        log.warning("%s; `run --resume` flies them again", listed)
    unreadable = sorted({b.path.name for b in episodes.unreadable} | {p.name for p in bad_parts})
    for b in episodes.unreadable:
        if b.path not in bad_parts:
            log.warning("skipping unreadable episode file %s", b.reason)  # the reason names the file
    rows = []
    for e in (e for e in episodes.entries if e.path not in bad_parts):
        try:  # an .npz is read and scored here; a stored episode's row holds what its cell computed
            rows.append(episodes.metrics(e))
        except ValueError as exc:  # one corrupt or truncated file must not cost the report of the rest
            log.warning("skipping unreadable episode file %s", exc)  # the message names the file
            unreadable.append(e.path.name)
    rows = label_vehicles(rows)  # by fingerprint: a vehicle file that keeps a preset's name is not the preset
    if not rows:
        raise ValueError(f"{run_dir}: no readable saved episodes to report (unreadable: {', '.join(unreadable)})")
    write_metrics_csv(rows, run_dir / "metrics.csv")
    rows = read_metrics_csv(run_dir / "metrics.csv")
    # per scenario too: a run may mix vehicles (a quadrotor's and a multicopter's energies do not average)
    write_summary_json(summarize_run(rows), run_dir / "summary.json")
    if report:  # matplotlib and plotly, only when the report is built: scoring alone needs neither
        from compare.pages.viewer import build_viewer
        from compare.report.report import build_report
        # the skipped files were named above; the viewer, which reads every flight, names each that does not draw
        # (one warning each): the report lists them all on its failures page without a second warning
        build_viewer(run_dir, warn_unreadable=False, warned=unreadable)
        build_report(run_dir, warn_unreadable=False)
    return run_dir
