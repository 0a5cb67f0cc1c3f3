"""A synthetic run folder (no simulation) for tests of what reads run folders: report, animation, viewer.

Two pilots x two episodes x one seed over a four-building map; PPO's episode 1 ends in a collision.
Episode 0's files carry the per-step shaft power (`synthetic_power_W`); episode 1's are in the format saved
before it was recorded, and metrics.csv lacks the tracker columns (an older run's), so every reader is
checked on old files too.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from compare.flying.episode_loop import Trajectory
from compare.results.trajectory import EpisodeKey, EpisodeMeta, save_episode
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.generator import map_yaml_text

SCENARIO = "toy-quad"
LABELS = {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC"}
START, GOAL = (20.0, 20.0, 10.0), (170.0, 160.0, 20.0)
# rl.policies.folder.CURVE_COLUMNS (tests/compare/report/test_report.py checks they agree)
CURVE_COLUMNS = ["timesteps", "mean_episode_reward", "train_success_rate", "train_collision_rate",
                 "train_timeout_rate", "train_episodes", "difficulty", "success_rate", "collision_rate",
                 "eval_episodes", "wall_s"]
UPDATE_STEPS = 16_384  # timesteps per PPO update (256 vehicles x 64 steps)
METRIC_COLUMNS = ["scenario", "episode", "method", "seed", "map", "vehicle", "outcome", "success",
                  "collision", "failure_reason", "min_clearance_m", "time_below_2m_s", "time_below_5m_s",
                  "time_s", "path_length_m", "straight_line_m", "spl", "energy_kj", "compute_ms_mean",
                  "compute_ms_max", "plan_time_s"]


def toy_map() -> BuildingMap:
    parts = [Building(0, (60.0, 60.0), (20.0, 15.0), 30.0, 0.2),
             Building(1, (120.0, 70.0), (18.0, 18.0), 45.0),
             Building(2, (80.0, 140.0), (25.0, 12.0), 20.0, -0.3),
             Building(3, (190.0, 30.0), (16.0, 30.0), 25.0)]
    return BuildingMap(parts, (0.0, 0.0, 0.0), (200.0, 200.0, 80.0), name="toy")


def synthetic_power_W(t_s: np.ndarray) -> np.ndarray:
    """The shaft power [W] saved with episode 0's flights: a shape no formula of the rotor speeds gives."""
    return 180.0 + 40.0 * np.sin(0.5 * t_s) + 2.0 * t_s


def trajectory(n: int, duration_s: float, bend_m: float, stop_frac: float, outcome: str,
                seed: int, shaft_power: bool = False) -> Trajectory:
    """A smooth synthetic flight from START towards GOAL (bent sideways by `bend_m`), cut at `stop_frac`."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration_s, n)
    s = stop_frac * t / duration_s
    a, b = np.array(START), np.array(GOAL)
    side = np.array([-(b - a)[1], (b - a)[0], 0.0]) / np.linalg.norm((b - a)[:2])
    pos = a + s[:, None] * (b - a) + (bend_m * np.sin(np.pi * s))[:, None] * side
    vel = np.gradient(pos, t, axis=0)
    rotors = 620.0 + 15.0 * rng.standard_normal((n, 4))
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    states = np.hstack([pos, vel, quat, np.zeros((n, 3)), rotors])
    clearance = 8.0 + 6.0 * np.cos(3.0 * s) - (9.0 * s if outcome == "collision" else 0.0)
    decisions = t[::10]
    return Trajectory(t_s=t, states=states, rotor_commands=rotors,
                      wind_enu_m_s=np.tile([2.0, 1.0, 0.0], (n, 1)), clearance_m=clearance,
                      decision_t_s=decisions, compute_s=np.full(len(decisions), 2e-3),
                      energy_J=1000.0 * duration_s, outcome=outcome, plan_time_s=0.3,
                      detail=f"synthetic {outcome}", shaft_power_W=synthetic_power_W(t) if shaft_power else None)


def write_run(run_dir: Path, policy_dir: Path | None) -> None:
    """Two pilots x two episodes x one seed; PPO's episode 1 ends in a collision (see the module docstring)."""
    (run_dir / "maps").mkdir(parents=True)
    (run_dir / "maps" / f"{SCENARIO}.yaml").write_text(map_yaml_text(toy_map()), encoding="utf-8")
    # (episode, pilot): samples, duration [s], sideways bend [m], fraction of the way flown, outcome
    cells = {(0, "ppo"): (3000, 30.0, 25.0, 1.0, "success"),
             (0, "rrt_mpc"): (1500, 26.0, -10.0, 1.0, "success"),
             (1, "ppo"): (800, 12.0, 5.0, 0.45, "collision"),
             (1, "rrt_mpc"): (1200, 24.0, 15.0, 1.0, "success")}
    rows = []
    for (ep, pilot), (n, dur, bend, stop, outcome) in cells.items():
        key = EpisodeKey(SCENARIO, ep, pilot, 0)
        meta = EpisodeMeta(key, "toy", "small_quad", START, GOAL, 3.0, 60.0, 0.42, 4, 1000.0 * dur, outcome,
                           0.3 if pilot == "rrt_mpc" else 0.0, f"synthetic {outcome}")
        traj = trajectory(n, dur, bend, stop, outcome, ep, shaft_power=ep == 0)
        save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta, traj)
        ok = outcome == "success"
        rows.append([SCENARIO, ep, pilot, 0, "toy", "small_quad", outcome, int(ok), int(not ok),
                     "" if ok else "collision", 4.1, 0.0, 1.5, dur, 230.0, 206.2, 0.85 if ok else 0.0,
                     dur, 2.0, 3.5, 0.3 if pilot == "rrt_mpc" else "nan"])
    with (run_dir / "metrics.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(METRIC_COLUMNS)
        w.writerows(rows)
    stat = {"mean": 0.5, "ci_low": 0.0, "ci_high": 1.0, "n": 2}
    summary = {"bootstrap": {"resamples": 1000, "confidence": 0.95, "seed": 0, "method": "percentile"},
               "metrics": ["success", "collision", "min_clearance_m", "time_s", "energy_kj"],
               "methods": {"ppo": {"episodes": 2, "failure_reasons": {"collision": 1}, "success": stat,
                                   "collision": stat, "min_clearance_m": {**stat, "mean": 4.1},
                                   "time_s": {"mean": 21.0, "ci_low": None, "ci_high": None, "n": 2}},
                           "rrt_mpc": {"episodes": 2, "failure_reasons": {}, "success": {**stat, "mean": 1.0},
                                       "energy_kj": {**stat, "mean": 25.0}}},
               "paired": {"ppo - rrt_mpc": {"episodes": 2, "time_s": {"mean_diff": -4.0, "ci_low": -8.0,
                                                                      "ci_high": 1.0, "n": 2}}}}
    (run_dir / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    if policy_dir is not None:
        write_reward_curve(policy_dir)
    scenario = {"name": SCENARIO, "source": "/tmp/toy-quad.yaml", "description": "Synthetic test scenario.",
                "map_name": "toy", "vehicle": "small_quad",
                "vehicle_summary": "1.5 kg, 4 rotors, collision radius 0.42 m",
                "atmosphere": {"elevation_m": 1500.0, "isa_offset_k": 15.0, "density_kg_m3": 0.999},
                "wind": {"steady_enu_m_s": [2, 1, 0], "turbulence": "light"}, "episodes": 2, "seeds": [0],
                "methods": ["ppo", "rrt_mpc"], "physics_hz": 500, "control_hz": 50}
    run = {"format_version": 1, "created_utc": "2026-11-21T08:00:00Z", "command": "uam-compare run toy",
           "scenarios": [scenario],
           "methods": {"ppo": {"label": LABELS["ppo"], "description": "Learned pilot.",
                               "policies": [{"vehicle": "small_quad", "policy_dir": str(policy_dir),
                                             "decision_hz": 10.0}] if policy_dir else []},
                       "rrt_mpc": {"label": LABELS["rrt_mpc"], "description": "Classical pilot."}},
           "versions": {"uam-compare": "0.1.0", "python": "3.11.7", "numpy": np.__version__},
           "fairness": "Both pilots know the map, the start and the goal. Neither knows the wind. " * 4}
    (run_dir / "run.json").write_text(json.dumps(run), encoding="utf-8")


def write_reward_curve(policy_dir: Path, updates: int = 240, seed: int = 0, eval_every: int = 30,
                       kept_update: int | None = 210, rate: float = 1.0) -> dict:
    """A policy folder's `reward_curve.csv` as `rl.training.loop` writes it (one row per update) and provenance.json.

    The return rises from about -110 and levels off near 160 (`rate` scales how fast); the curriculum
    goes 0.25 -> 0.5 -> 0.75 -> 1 at 30 %, 38 % and 45 % of the run; validation runs every
    `eval_every` updates; the update 20 % into the run has no training episode (empty cells).

    Returns:
        {"validation_rows": row indices with a validation evaluation, "kept_timesteps": ...}.
    """
    rng = np.random.default_rng(seed)
    policy_dir.mkdir(parents=True, exist_ok=True)
    rows, val_rows = [], []
    for k in range(1, updates + 1):
        t = k * UPDATE_STEPS
        progress = 1.0 - np.exp(-rate * 5.0 * k / updates)
        frac = k / updates
        difficulty = 0.25 if frac < 0.3 else 0.5 if frac < 0.38 else 0.75 if frac < 0.45 else 1.0
        succ = float(np.clip(progress + 0.05 * rng.standard_normal(), 0, 1))
        coll = float(np.clip(0.8 * (1 - progress) + 0.02 * rng.standard_normal(), 0, 1 - succ))
        n_eps = int(rng.integers(50, 100))
        train = [f"{-110 + 270 * progress + 12 * rng.standard_normal():.4f}", f"{succ:.4f}", f"{coll:.4f}",
                 f"{1 - succ - coll:.4f}", n_eps]
        if k == max(1, updates // 5):
            train = ["", "", "", "", 0]
        val = ["", "", ""]
        if k % eval_every == 0 or k == updates:
            val = [f"{min(1.0, 0.97 * progress):.4f}", f"{0.3 * (1 - progress):.4f}", 200]
            val_rows.append(k - 1)
        rows.append([t, *train, f"{difficulty:.3f}", *val, f"{30 + t / 12_000:.1f}"])
    with (policy_dir / "reward_curve.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CURVE_COLUMNS)
        w.writerows(rows)
    kept = None if kept_update is None else kept_update * UPDATE_STEPS
    prov = {"command": "uam-compare train (synthetic)", "seed": seed, "method": "PPO from scratch",
            "timesteps": updates * UPDATE_STEPS, "wall_time_s": 40 + updates * UPDATE_STEPS / 12_000,
            "kept_timesteps": kept}
    (policy_dir / "provenance.json").write_text(json.dumps(prov), encoding="utf-8")
    return {"validation_rows": val_rows, "kept_timesteps": kept}


# ---- a synthetic benchmark-sized run: several vehicles, many scenarios, any pilots -----------------------
BENCH_VEHICLES = ("small_quad", "uam_multicopter")
TURBULENCE = ("none", "light", "moderate", "severe")


def bench_map(name: str, buildings: int, seed: int) -> BuildingMap:
    """A 400 m x 400 m city of `buildings` boxes on a 10 x 10 grid of 40 m lots (coverage grows with the count)."""
    rng = np.random.default_rng(seed)
    lots = rng.permutation(100)[:buildings]
    parts = [Building(k, (40.0 * (lot % 10) + 20.0, 40.0 * (lot // 10) + 20.0), (22.0, 22.0),
                      float(rng.uniform(15.0, 60.0))) for k, lot in enumerate(lots)]
    return BuildingMap(parts, (0.0, 0.0, 0.0), (400.0, 400.0, 120.0), name=name)


def write_benchmark_run(run_dir: Path, *, scenarios_per_vehicle: int, episodes: int, seeds: tuple[int, ...],
                        pilots: dict[str, str], vehicles: tuple[str, ...] = BENCH_VEHICLES, samples: int = 200,
                        episode_files: bool = True, seed: int = 0) -> list:
    """A run folder shaped like a benchmark run (no simulation): run.json, maps, episode files, metrics.csv.

    Scenario k of each vehicle has a city of 10 + 8k buildings (up to 90), turbulence level k mod 4 and an
    air density falling with k (hot and high); each task (episode, seed) a leg of 120-380 m. Success is
    drawn per cell with a probability that falls with leg, coverage, turbulence and thinner air, at a
    pace that differs per pilot, so the difficulty figures show where each "pilot" breaks. No summary.json
    (finalize's summary is what a test or benchmark computes from the rows returned).

    Args:
        pilots: pilot name -> label (run.json's "methods", in table order).
        samples: points per saved trajectory (small: the files are only drawn for a few tasks).
        episode_files: write an .npz per cell (False: metrics and run.json only).

    Returns:
        The metrics rows written (`EpisodeMetrics`).
    """
    from compare.results.metrics import EpisodeMetrics, write_metrics_csv

    rng = np.random.default_rng(seed)
    (run_dir / "maps").mkdir(parents=True)
    scenario_json, rows = [], []
    skill = {m: 1.0 - 0.15 * k for k, m in enumerate(pilots)}  # the first pilot is the most robust
    for v_index, vehicle in enumerate(vehicles):
        heavy = vehicle != "small_quad"
        for k in range(scenarios_per_vehicle):
            name = f"bench-{vehicle}-{k:02d}"
            bmap = bench_map(name, min(10 + 8 * k, 90), seed + 100 * v_index + k)
            (run_dir / "maps" / f"{name}.yaml").write_text(map_yaml_text(bmap), encoding="utf-8")
            turbulence = TURBULENCE[k % 4]
            density = 1.225 - 0.012 * k
            coverage = min(10 + 8 * k, 90) * 22.0 ** 2 / 400.0 ** 2
            scenario_json.append({
                "name": name, "source": f"benchmark/{name}.yaml", "description": "Synthetic benchmark scenario.",
                "map_name": name, "vehicle": vehicle,
                "vehicle_summary": "900 kg, 8 rotors" if heavy else "1.5 kg, 4 rotors",
                "atmosphere": {"elevation_m": 100.0 * k, "isa_offset_k": 0.0, "density_kg_m3": density},
                "wind": {"steady_enu_m_s": [2, 1, 0], "turbulence": turbulence}, "episodes": episodes,
                "seeds": list(seeds), "methods": list(pilots), "physics_hz": 500, "control_hz": 50})
            for ep in range(episodes):
                leg = 120.0 + 260.0 * ep / max(episodes - 1, 1)
                for s in seeds:
                    for m in pilots:
                        hard = (0.5 * leg / 380.0 + 1.5 * coverage + 0.15 * TURBULENCE.index(turbulence)
                                + 2.0 * (1.225 - density))  # 0.2 (easiest) to 1.5
                        ok = bool(rng.random() < 1.0 / (1.0 + np.exp(5.0 * (hard / skill[m] - 1.0))))
                        outcome = "success" if ok else ("collision" if rng.random() < 0.6 else "timeout")
                        duration = leg / (9.0 if heavy else 6.0) * (1.0 + 0.2 * rng.random())
                        energy = duration * (180.0 if heavy else 0.2) * (1.0 + 0.1 * rng.random())
                        rows.append(EpisodeMetrics(
                            scenario=name, episode=ep, method=m, seed=s, map=name, vehicle=vehicle, outcome=outcome,
                            success=ok, collision=outcome == "collision", failure_reason="" if ok else outcome,
                            min_clearance_m=float(rng.uniform(0.5, 8.0)) if ok else 0.0, time_below_2m_s=0.5,
                            time_below_5m_s=2.0, time_s=duration, path_length_m=1.2 * leg, straight_line_m=leg,
                            spl=0.83 if ok else 0.0, energy_kj=energy,
                            compute_ms_mean=float(rng.uniform(0.5, 3.0)) * (1 + k % 3), compute_ms_max=9.0,
                            plan_time_s=float("nan")))
                        if episode_files:
                            key = EpisodeKey(name, ep, m, s)
                            meta = EpisodeMeta(key, name, vehicle, START, GOAL, 3.0, 60.0, 0.42, 4, 1000.0 * energy,
                                               outcome, 0.0, f"synthetic {outcome}")
                            traj = trajectory(samples, duration, 20.0 * (rng.random() - 0.5), 1.0 if ok else 0.6,
                                              outcome, int(rng.integers(1 << 30)))
                            save_episode(run_dir / "episodes" / f"{key.stem}.npz", meta, traj)
    write_metrics_csv(rows, run_dir / "metrics.csv")
    run = {"format_version": 1, "created_utc": "2026-11-21T08:00:00Z", "command": "uam-compare run benchmark",
           "scenarios": scenario_json,
           "methods": {m: {"label": label, "description": f"{label} (synthetic)."} for m, label in pilots.items()},
           "versions": {"uam-compare": "0.1.0"}, "fairness": "Synthetic."}
    (run_dir / "run.json").write_text(json.dumps(run), encoding="utf-8")
    return rows


def to_store(run_dir: Path, compacted: bool = True) -> None:
    """Move a synthetic run folder's `.npz` episodes into the run store, as a run of today writes it: each
    episode scored and written as its cell's part (a control period of 10 samples: these flights decide every
    10 samples), then compacted unless `compacted` is False (an interrupted run's parts)."""
    from compare.results.metrics import episode_metrics
    from compare.results.store import compact, part_bytes, part_path, write_part
    from compare.results.tables import EpisodeConditions, episode_row, kept_rows, samples_table
    from compare.results.trajectory import episode_files, load_episode

    conditions = EpisodeConditions(0.999, 1800.0, "light", (2.0, 1.0, 0.0), 0.1)
    for path in episode_files(run_dir):
        saved = load_episode(path)
        traj, key = saved.trajectory, saved.meta.key
        period = 10
        row = episode_row(saved.meta, episode_metrics(saved), conditions, "control",
                          len(kept_rows(traj, "control", period)))
        write_part(part_path(run_dir, key),
                   part_bytes(row, samples_table(key, traj, saved.meta.n_rotors, "control", period)))
        path.unlink()
    (run_dir / "episodes").rmdir()
    if compacted:
        compact(run_dir)
