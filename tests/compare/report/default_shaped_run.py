"""A run folder shaped like `uam-compare run`'s default one, without flying: the shipped `default` set's three
scenarios (their cities, vehicles, tasks and run.json entries, as the campaign records them), both pilots, the
shipped policies (so the training pages draw their real curves and recorded flights), the classical pilot's tracker
columns, and per episode a synthetic flight from the task's start to its goal, bent sideways through the city
(so that the 3D views have paths behind buildings). Twelve episodes, as the default run has."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from compare.flying import pilots
from compare.flying.episode_loop import Trajectory
from compare.results.metrics import EpisodeMetrics, write_metrics_csv
from compare.results.run_info import PilotInfo, PolicyRecord, RunInfo, write_run_info
from compare.results.summary import summarize_run, write_summary_json
from compare.results.trajectory import EpisodeKey, EpisodeMeta, save_episode
from compare.run.campaign import fairness, scenario_info, versions
from compare.run.cells import Cell
from compare.scenarios.sets import resolve_scenarios
from rl.policies.folder import SHIPPED_POLICIES
from uam_fdm.city.generator import map_yaml_text

PILOTS = ("ppo", "rrt_mpc")
SAMPLES = 400


def _flight(start: np.ndarray, goal: np.ndarray, bend_m: float, n_rotors: int, seed: int) -> Trajectory:
    """A smooth flight from `start` to `goal`, bent sideways by `bend_m` and climbing 5 m on the way."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 18.0, SAMPLES)
    s = t / t[-1]
    side = np.array([-(goal - start)[1], (goal - start)[0], 0.0]) / max(float(np.linalg.norm((goal - start)[:2])), 1e-9)
    pos = start + s[:, None] * (goal - start) + (bend_m * np.sin(np.pi * s))[:, None] * side
    pos[:, 2] += 5.0 * np.sin(np.pi * s)
    vel = np.gradient(pos, t, axis=0)
    rotors = 620.0 + 10.0 * rng.standard_normal((SAMPLES, n_rotors))
    states = np.hstack([pos, vel, np.tile([1.0, 0.0, 0.0, 0.0], (SAMPLES, 1)), np.zeros((SAMPLES, 3)), rotors])
    decisions = t[::10]
    return Trajectory(t_s=t, states=states, rotor_commands=rotors, wind_enu_m_s=np.tile([2.0, 1.0, 0.0], (SAMPLES, 1)),
                      clearance_m=6.0 + 3.0 * np.cos(3.0 * s), decision_t_s=decisions,
                      compute_s=np.full(len(decisions), 2e-3), energy_J=4500.0, outcome="success", plan_time_s=0.3,
                      detail="synthetic success", shaft_power_W=200.0 + 10.0 * np.sin(t))


def write_default_shaped_run(run_dir: Path) -> list[EpisodeMetrics]:
    """Write the run folder (see the module docstring); returns its metrics rows."""
    scenarios = resolve_scenarios("default")
    (run_dir / "maps").mkdir(parents=True)
    infos, rows = [], []
    for i, sc in enumerate(scenarios):
        (run_dir / "maps" / f"{sc.name}.yaml").write_text(map_yaml_text(sc.city), encoding="utf-8")
        cells = [Cell(i, ep.index, seed, m) for ep in sc.episodes for seed in sc.seeds for m in PILOTS]
        infos.append(scenario_info(sc, cells))
        p = sc.vehicle
        for c in cells:
            task = sc.episodes[c.episode].task
            start, goal = np.array(task.start_m, float), np.array(task.goal_m, float)
            bend = (25.0 if c.pilot == "ppo" else -15.0) * (1.0 + 0.3 * c.episode)
            key = EpisodeKey(sc.name, c.episode, c.pilot, c.seed)
            meta = EpisodeMeta(key, sc.city.name or sc.name, sc.vehicle_name, tuple(start), tuple(goal),
                               task.goal_radius_m, task.timeout_s, p.collision_radius_m, p.n_rotors, 4500.0, "success",
                               0.3, "synthetic success")
            save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta, _flight(start, goal, bend, p.n_rotors, i))
            classical = c.pilot == "rrt_mpc"
            tracker = dict(mpc_solve_ms_median=1.2, mpc_solve_ms_p95=1.5, mpc_failures=0.0, replans_tracking=0.0,
                           replans_clearance=0.0, tracking_rms_m=0.11, tracking_max_m=0.3, planner_margin_m=1.0,
                           mpc_margin_m=0.5, planner_margin_floor_m=1.0, planner_attempts=1.0,
                           clearance_over_margin_min=1.2) if classical else {}
            leg = float(np.linalg.norm(goal - start))
            rows.append(EpisodeMetrics(
                scenario=sc.name, episode=c.episode, method=c.pilot, seed=c.seed, map=meta.map_name,
                vehicle=sc.vehicle_name, outcome="success", success=True, collision=False, failure_reason="",
                min_clearance_m=1.0 + 0.5 * c.episode + (3.0 if classical else 0.0), time_below_2m_s=0.5,
                time_below_5m_s=2.0, time_s=18.0 + c.episode, path_length_m=1.1 * leg, straight_line_m=leg,
                spl=0.9, energy_kj=4.5 + 0.2 * c.episode, compute_ms_mean=2.4 if classical else 0.5,
                compute_ms_max=4.0, plan_time_s=0.3 if classical else 0.1, **tracker))
    policies = tuple(PolicyRecord(v, str(SHIPPED_POLICIES[v]), 10.0 if v == "small_quad" else 5.0)
                     for v in ("small_quad", "uam_multicopter"))
    info = RunInfo(
        created_utc="2026-11-27T18:16:44Z", command="uam-compare run", scenarios=tuple(infos),
        pilots={m: PilotInfo(pilots.PILOTS[m].label, f"{pilots.PILOTS[m].label} (description).",
                             policies if m == "ppo" else ()) for m in PILOTS},
        versions=versions(), fairness=fairness(list(PILOTS)))
    write_run_info(info, run_dir)
    write_metrics_csv(rows, run_dir / "metrics.csv")
    write_summary_json(summarize_run(rows, resamples=200), run_dir / "summary.json")
    return rows

