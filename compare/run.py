"""A comparison run: every (scenario, episode, seed, method) cell flown, saved, scored and reported.

`run_comparison(scenarios, options)` writes a run folder:

```
RUN_DIR/run.json        provenance: scenarios, methods, software versions, fairness statement, command
RUN_DIR/maps/*.yaml     the city of each scenario (reports never need the scenario files again)
RUN_DIR/episodes/*.npz  one per cell (`compare.trajectory`), written atomically as each finishes
RUN_DIR/metrics.csv     one row per cell (`compare.metrics`)
RUN_DIR/summary.json    per-method means with 95 % bootstrap intervals, paired differences
RUN_DIR/report.pdf      the report (`compare.report`); RUN_DIR/figures/*.png its pages
```

Cells are independent and seeded from the cell alone (`compare.seeding`), so they run in any order
in any number of processes (`jobs`) with the same results. An interrupted run keeps every episode
finished so far; `finalize(RUN_DIR)` (the `report` command) rescores and reports them, and
`resume=True` flies only the missing cells.
"""
from __future__ import annotations

import json
import logging
import os
import platform
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import numpy as np

from compare.metrics import (
    episode_metrics,
    read_metrics_csv,
    summarize,
    write_metrics_csv,
    write_summary_json,
)
from compare.runner import run_episode
from compare.scenario import Scenario
from compare.seeding import cell_seed
from compare.trajectory import EpisodeKey, EpisodeMeta, episode_files, load_episode, save_episode
from uam_fdm.atomic import write_text_atomic

log = logging.getLogger(__name__)

METHOD_LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC"}
METHOD_DESCRIPTIONS = {
    "ppo": "Learned pilot: policy network (2 x 128 tanh units, trained with PPO; the shipped policy starts from "
           "behaviour cloning of a reactive potential-field pilot and keeps a cloning term, see its provenance) "
           "-> 3D velocity command -> the vehicle's low-level velocity/attitude controller -> rotor speeds; "
           "sees only its local observation (30 m building sensing); acts deterministically.",
    "rrt_mpc": "Classical pilot: OMPL RRT* path (planned before take-off, timed) -> time-parameterised "
               "reference -> CasADi NMPC (ipopt) commanding rotor speeds, replanning on large tracking errors.",
}
FAIRNESS = (
    "Both pilots fly the same vehicle model (6-DOF, rotor dynamics, JSBSim atmosphere) at the same physics rate "
    "and decide at the same rate; each decision is timed with the same stopwatch. Both know the vehicle's "
    "parameters, the building map, the air density and the full vehicle state at each decision (perfect state "
    "estimation). Neither knows the wind: both fly the same seeded steady wind and turbulence realisation in "
    "each episode. The classical pilot plans on the whole map before take-off (its planning time is reported "
    "separately) and commands rotor speeds through its MPC; the learned pilot sees only its observation "
    "(position, goal vector, velocity, body rates, altitude and the nearest buildings within its sensing range) "
    "and commands a velocity that the vehicle's low-level controller turns into rotor speeds. Clearance is "
    "measured at every physics step from the vehicle's collision sphere to the buildings and the ground."
)
VIDEOS_DIR = "videos"  # the run's animations, one file per animated cell
SOLVER_FAILURE_SHARE = 0.25  # a failed classical episode with >= this share of failed MPC solves: "solver_failure"


@dataclass(frozen=True)
class Cell:
    """One episode to fly: scenario (index into the run's list), episode index, seed and method."""

    scenario: int
    episode: int
    seed: int
    method: str


@dataclass(frozen=True)
class RunOptions:
    """How to run.

    Attributes:
        out_dir: the run folder.
        methods: only these methods (None: each scenario's own list).
        seeds: override every scenario's seeds (None: the scenarios' own).
        policy: the learned pilot's policy folder (None: the shipped policy).
        jobs: parallel processes (1: in this process).
        resume: skip cells whose episode file already exists.
        progress: show a progress bar.
        command: the command line, for provenance.
        report: build the PDF report and the HTML viewer at the end.
        videos: which cells to animate into `videos/` at the end: "scenario" (the first cell of each
            scenario), "all" or "none" (see `compare.animate.render_videos`).
    """

    out_dir: Path
    methods: tuple[str, ...] | None = None
    seeds: tuple[int, ...] | None = None
    policy: Path | None = None
    jobs: int = 1
    resume: bool = False
    progress: bool = True
    command: str = ""
    report: bool = True
    videos: str = "scenario"


def plan_cells(scenarios: Sequence[Scenario], opts: RunOptions, policy_vehicle_fp: str | None) -> tuple[list[Cell], list[str]]:
    """The cells to fly, in a fixed order, and notes on cells left out (e.g. no policy for a vehicle)."""
    cells, notes = [], []
    for si, sc in enumerate(scenarios):
        methods = [m for m in sc.methods if opts.methods is None or m in opts.methods]
        if "ppo" in methods and policy_vehicle_fp is not None and sc.vehicle.fingerprint() != policy_vehicle_fp:
            methods.remove("ppo")
            notes.append(f"{sc.name}: no learned policy for vehicle {sc.vehicle_name!r}; ppo not flown")
        seeds = opts.seeds if opts.seeds is not None else sc.seeds
        for ep in sc.episodes:
            for seed in seeds:
                for m in methods:
                    cells.append(Cell(si, ep.index, int(seed), m))
    return cells, notes


def cell_key(scenarios: Sequence[Scenario], c: Cell) -> EpisodeKey:
    return EpisodeKey(scenarios[c.scenario].name, c.episode, c.method, c.seed)


class CellRunner:
    """Flies cells; holds per-process caches (worlds per scenario, one agent per method)."""

    def __init__(self, scenarios: Sequence[Scenario], out_dir: Path, policy: Path | None) -> None:
        self.scenarios, self.out_dir, self.policy = list(scenarios), Path(out_dir), policy
        self._worlds: dict[int, object] = {}
        self._dynamics: dict[tuple, object] = {}
        self._agents: dict[str, object] = {}

    def world(self, si: int):
        from uam_fdm.agent import World
        from uam_fdm.atmosphere import Atmosphere
        from uam_fdm.dynamics import VehicleDynamics

        if si not in self._worlds:
            sc = self.scenarios[si]
            key = (sc.vehicle.fingerprint(), sc.physics_hz, sc.control_hz)
            if key not in self._dynamics:
                self._dynamics[key] = VehicleDynamics(sc.vehicle, sc.physics_hz, sc.control_hz)
            top = float(sc.city.bounds_max_m[2]) + 100.0
            atm = Atmosphere.from_jsbsim(sc.atmosphere, z_max_m=top, z_min_m=-50.0)
            self._worlds[si] = World(sc.vehicle, self._dynamics[key], sc.city, atm)
        return self._worlds[si]

    def agent(self, method: str):
        if method not in self._agents:
            if method == "ppo":
                from rl.agent import PolicyAgent
                self._agents[method] = PolicyAgent(self.policy)
            elif method == "rrt_mpc":
                from planners.agent import ClassicalAgent
                self._agents[method] = ClassicalAgent()
            else:
                raise ValueError(f"unknown method {method!r}")
        return self._agents[method]

    def run(self, c: Cell) -> Path:
        from uam_fdm.wind import WindField

        sc = self.scenarios[c.scenario]
        spec = sc.episodes[c.episode]
        task = spec.task
        world = self.world(c.scenario)
        p = sc.vehicle
        wind_seed = cell_seed(sc.name, c.episode, c.seed, "wind")
        agent_seed = cell_seed(sc.name, c.episode, c.seed, "agent")
        height = float(np.clip(0.5 * (task.start_m[2] + task.goal_m[2]), 1.0, 5000.0))
        airspeed = float(np.clip(max(p.controller.max_speed_m_s, np.linalg.norm(sc.wind.steady_enu_m_s)), 1.0, 100.0))
        wind = WindField.from_conditions(sc.wind, wind_seed, task.timeout_s + 1.0, height, airspeed)
        agent = self.agent(c.method)
        traj = run_episode(world, agent, task, wind, agent_seed)
        extra: dict = {"wind_seed": wind_seed, "agent_seed": agent_seed,
                       "torque_coeff_Nm_s2": p.torque_coeff_Nm_s2,
                       "density_ratio": float(world.atmosphere.density_ratio(task.start_m[2])),
                       "mean_decision_ms": float(np.mean(traj.compute_s) * 1e3) if len(traj.compute_s) else None}
        stats = getattr(agent, "stats", None)
        if stats is not None and c.method == "rrt_mpc":
            extra.update(replans=stats.replans, mpc_solves=stats.mpc_solves, mpc_failures=stats.mpc_failures,
                         mpc_statuses=dict(stats.mpc_statuses),
                         mpc_solve_ms_median=float(np.median(stats.mpc_solve_times_s) * 1e3)
                         if stats.mpc_solve_times_s else None)
            if (traj.outcome not in ("success", "planner_failure") and stats.mpc_solves
                    and stats.mpc_failures >= SOLVER_FAILURE_SHARE * stats.mpc_solves):
                extra["failure_reason"] = "solver_failure"
        key = EpisodeKey(sc.name, c.episode, c.method, c.seed)
        meta = EpisodeMeta(key=key, map_name=sc.city.name or sc.name, vehicle=sc.vehicle_name,
                           start_m=tuple(task.start_m), goal_m=tuple(task.goal_m), goal_radius_m=task.goal_radius_m,
                           timeout_s=task.timeout_s, collision_radius_m=p.collision_radius_m, n_rotors=p.n_rotors,
                           energy_J=float(traj.energy_J), outcome=traj.outcome, plan_time_s=float(traj.plan_time_s),
                           detail=traj.detail, extra=extra)
        return save_episode(self.out_dir / "episodes" / f"{key.stem}.npz", meta, traj)


_WORKER: CellRunner | None = None


def _init_worker(scenarios: list[Scenario], out_dir: Path, policy: Path | None) -> None:
    global _WORKER
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _WORKER = CellRunner(scenarios, out_dir, policy)


def _run_in_worker(c: Cell) -> Path:
    assert _WORKER is not None
    return _WORKER.run(c)


def versions() -> dict[str, str]:
    """Versions of the software that produced a run."""
    out = {"python": platform.python_version()}
    for dist in ("uam-compare", "numpy", "casadi", "ompl", "jsbsim", "python-fcl", "torch", "stable-baselines3",
                 "gymnasium", "matplotlib"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def write_run_files(scenarios: Sequence[Scenario], opts: RunOptions, cells: Sequence[Cell], notes: Sequence[str]) -> None:
    """run.json and maps/*.yaml."""
    from rl.agent import DEFAULT_POLICY_DIR
    from uam_fdm.atmosphere import Atmosphere
    from uam_fdm.citygen import map_yaml_text

    out = opts.out_dir
    entries = []
    for si, sc in enumerate(scenarios):
        methods = sorted({c.method for c in cells if c.scenario == si})
        seeds = sorted({c.seed for c in cells if c.scenario == si})
        p = sc.vehicle
        rho = Atmosphere.from_jsbsim(sc.atmosphere, z_max_m=50.0, z_min_m=0.0).density_kg_m3(0.0)
        entries.append({
            "name": sc.name, "source": str(sc.source), "description": sc.description, "map_name": sc.city.name or sc.name,
            "vehicle": sc.vehicle_name,
            "vehicle_summary": f"{p.mass_kg:g} kg, {p.n_rotors} rotors, collision radius {p.collision_radius_m:g} m",
            "atmosphere": {"elevation_m": sc.atmosphere.elevation_m, "isa_offset_k": sc.atmosphere.isa_offset_k,
                           "density_kg_m3": round(float(rho), 4)},
            "wind": {"steady_enu_m_s": list(sc.wind.steady_enu_m_s), "turbulence": sc.wind.turbulence.value},
            "episodes": len(sc.episodes), "seeds": seeds, "methods": methods,
            "physics_hz": sc.physics_hz, "control_hz": sc.control_hz,
        })
        write_text_atomic(out / "maps" / f"{sc.name}.yaml", map_yaml_text(sc.city))
    policy_dir = opts.policy if opts.policy is not None else DEFAULT_POLICY_DIR
    methods = sorted({c.method for c in cells})
    run = {
        "format_version": 1, "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": opts.command, "scenarios": entries, "notes": list(notes),
        "methods": {m: {"label": METHOD_LABELS.get(m, m), "description": METHOD_DESCRIPTIONS.get(m, ""),
                        **({"policy_dir": str(Path(policy_dir).resolve())} if m == "ppo" else {})} for m in methods},
        "versions": versions(), "fairness": FAIRNESS,
    }
    write_text_atomic(out / "run.json", json.dumps(run, indent=2) + "\n")


def run_comparison(scenarios: Sequence[Scenario], opts: RunOptions) -> Path:
    """Fly every cell, then score and report (see the module docstring). Returns the run folder."""
    from tqdm import tqdm

    from compare.animate import VIDEO_CHOICES

    if opts.videos not in VIDEO_CHOICES:  # checked before flying, not when the videos are due
        raise ValueError(f"--videos {opts.videos!r}: choose from {', '.join(VIDEO_CHOICES)}")
    scenarios = list(scenarios)
    policy_fp = None
    if any("ppo" in sc.methods for sc in scenarios) and (opts.methods is None or "ppo" in opts.methods):
        policy_fp = _policy_vehicle_fingerprint(opts.policy)
    cells, notes = plan_cells(scenarios, opts, policy_fp)
    if not cells:
        raise ValueError("nothing to fly: no (scenario, method) left after --methods")
    out = Path(opts.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    write_run_files(scenarios, opts, cells, notes)
    todo = [c for c in cells
            if not (opts.resume and (out / "episodes" / f"{cell_key(scenarios, c).stem}.npz").exists())]
    t0 = time.perf_counter()
    bar = tqdm(total=len(todo), desc="episodes", unit="ep", disable=not opts.progress, file=sys.stderr)
    try:
        if opts.jobs <= 1:
            runner = CellRunner(scenarios, out, opts.policy)
            for c in todo:
                runner.run(c)
                bar.update(1)
        else:
            import multiprocessing as mp
            with ProcessPoolExecutor(max_workers=opts.jobs, mp_context=mp.get_context("spawn"),
                                     initializer=_init_worker, initargs=(scenarios, out, opts.policy)) as pool:
                futures = [pool.submit(_run_in_worker, c) for c in todo]
                for f in as_completed(futures):
                    f.result()
                    bar.update(1)
    finally:
        bar.close()
    log.info("flew %d episodes in %.1f s", len(todo), time.perf_counter() - t0)
    finalize(out, report=opts.report)
    if opts.videos != "none":
        from compare.animate import render_videos
        from compare.flights import flight_groups
        render_videos(flight_groups(out), out / VIDEOS_DIR, opts.videos, progress=opts.progress)
    return out


def _policy_vehicle_fingerprint(policy: Path | None) -> str:
    from rl.agent import DEFAULT_POLICY_DIR
    from uam_fdm.params import load_vehicle

    folder = Path(policy) if policy is not None else DEFAULT_POLICY_DIR
    cfg_path = folder / "config.json"
    if not cfg_path.is_file():
        raise ValueError(f"{folder}: not a policy folder (config.json is missing)")
    return load_vehicle(json.loads(cfg_path.read_text())["nav"]["vehicle"]).fingerprint()


def finalize(run_dir: Path, report: bool = True) -> Path:
    """Score the saved episodes (metrics.csv, summary.json), build the report and the viewer; never simulates."""
    run_dir = Path(run_dir)
    if not (run_dir / "run.json").is_file():
        raise ValueError(f"{run_dir}: not a run folder (run.json is missing)")
    files = episode_files(run_dir)
    if not files:
        raise ValueError(f"{run_dir}: no saved episodes to report")
    rows = [episode_metrics(load_episode(f)) for f in files]
    write_metrics_csv(rows, run_dir / "metrics.csv")
    rows = read_metrics_csv(run_dir / "metrics.csv")
    summary = summarize(rows)
    # Per scenario too: a run may mix vehicles (a quadrotor's and a multicopter's energies do not average).
    summary["by_scenario"] = {name: summarize([r for r in rows if r.scenario == name])
                              for name in sorted({r.scenario for r in rows})}
    write_summary_json(summary, run_dir / "summary.json")
    if report:
        from compare.report import build_report
        from compare.viewer import build_viewer
        build_report(run_dir)
        build_viewer(run_dir)
    return run_dir
