"""Batched onboard estimation cost: `BatchOnboard` (IMU, barometer, heading aid, GNSS and the navigation filter of N
vehicles, no lidar) per control period, against the batched physics and the learned pilot's env step, same run.

Each batch size N flies the learned pilot's world (`NavConfig()`'s task in a pool of `--cities` training cities;
each slot its own task, city, atmosphere and sensing seed, set by `NavBatch.reset_slots`) under velocity commands
toward each slot's goal. Per control period (20 ms: 10 physics steps, 5 IMU samples, one barometer and heading
reading, a GNSS epoch every 5th period) it times

* physics: `BatchSimulator.step_velocity_batch` of the N slots (controller and RK4 substeps, compiled);
* estimation: `BatchOnboard.advance` of that period's substep states plus `BatchOnboard.estimates` (conservative:
  a pilot deciding at 10 Hz asks for the estimate every 5th period);
* env: `NavBatch.step` (one decision: 5 control periods with collision checks, route, observation and reward),
  divided by its periods: what PPO's data collection steps, without the policy's forward pass.

Figures are per slot per control period [µs], each the fastest of `--repeats` timing blocks (on a shared machine
other work only ever adds time); the N = 1 figure is the baseline of the speed-up ratio. Also the cost of a slot's
reset (a new episode: sensors re-seeded, first barometer reading, the filter's start), once per episode.

    OMP_NUM_THREADS=1 python perf/batch_onboard.py [--batches 1,64,256] [--levels nominal,degraded] [--periods 100]

Prints a table per level and, as its last line, one JSON object: onboard_step_us (nominal, N = 256),
onboard_step_us_degraded, onboard_vs_physics_ratio and onboard_vs_env_ratio (N = 256, nominal), and per level and N
the figures.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rl.env.world import NavBatch, NavWorld  # noqa: E402
from rl.task.config import NavConfig  # noqa: E402
from uam_fdm.sensing.batch_onboard import BatchOnboard  # noqa: E402
from uam_fdm.sensing.raycast import RayCaster  # noqa: E402
from uam_fdm.sensing.specs import sensing_preset  # noqa: E402


def _placed(world: NavWorld, n: int) -> NavBatch:
    batch = NavBatch(world, n)
    batch.seed(range(n))
    batch.reset_slots(np.arange(n))
    return batch


def _onboard(world: NavWorld, batch: NavBatch, level: str, casters: list[RayCaster]) -> BatchOnboard:
    cfg = sensing_preset(level, world.vehicle.mass_kg)
    canyon = cfg.gnss.urban_canyon
    onboard = BatchOnboard(cfg, world.dynamics.dt_s, batch.n, world.atmospheres,
                           cities=world.cities if canyon else (), casters=casters if canyon else ())
    onboard.reset(np.arange(batch.n), np.arange(batch.n), batch.x, city=batch.city if canyon else None,
                  field=batch.air)
    return onboard


def _fly_us(world: NavWorld, n: int, level: str, casters: list[RayCaster], periods: int,
            repeats: int) -> tuple[float, float, float]:
    """(physics, estimation, reset) per slot [µs]: the first two per control period, best block of `repeats`."""
    vmax = 0.5 * world.vehicle.controller.max_speed_m_s
    best_phys = best_est = best_reset = np.inf
    for _ in range(repeats + 1):  # the first block warms up (caches, buffers)
        batch = _placed(world, n)
        t0 = time.perf_counter()
        onboard = _onboard(world, batch, level, casters)
        reset_s = time.perf_counter() - t0
        x, xi, t = batch.x.copy(), batch.xi.copy(), batch.t.copy()
        cmd = np.zeros((n, 4))
        phys = est = 0.0
        for _ in range(periods):
            cmd[:, 0:3] = np.clip(0.5 * (batch.goal - x[:, 0:3]), -vmax, vmax)
            cmd[:, 3] = batch.yaw
            a = time.perf_counter()
            r = batch.sim.step_velocity_batch(x, xi, cmd, t)
            b = time.perf_counter()
            onboard.advance(x, r.states, t)
            onboard.estimates()
            c = time.perf_counter()
            phys, est = phys + b - a, est + c - b
            x, xi, t = r.final_state, r.ctrl_state, t + 1.0 / world.config.control_hz
        best_phys, best_est = min(best_phys, phys), min(best_est, est)
        best_reset = min(best_reset, reset_s)
    scale = 1e6 / (periods * n)
    return best_phys * scale, best_est * scale, best_reset * 1e6 / n


def _env_us(world: NavWorld, n: int, decisions: int, repeats: int) -> float:
    """`NavBatch.step` per slot per control period [µs] (random actions; ended episodes restarted, untimed)."""
    batch = _placed(world, n)
    acts = np.random.default_rng(0).uniform(-0.5, 0.5, (decisions, n, 3))
    best = np.inf
    for _ in range(repeats + 1):
        spent = 0.0
        for k in range(decisions):
            t0 = time.perf_counter()
            _, _, term, trunc, _ = batch.step(acts[k])
            spent += time.perf_counter() - t0
            done = np.flatnonzero(term | trunc)
            if len(done):
                batch.reset_slots(done)
        best = min(best, spent)
    return best * 1e6 / (decisions * n * world.config.action_repeat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", default="1,64,256", help="batch sizes (default 1,64,256; 1 is the baseline)")
    ap.add_argument("--levels", default="nominal,degraded", help="sensing levels (default nominal,degraded)")
    ap.add_argument("--periods", type=int, default=100, help="control periods per timing block (default 100)")
    ap.add_argument("--repeats", type=int, default=3, help="timing blocks per figure (default 3)")
    ap.add_argument("--cities", type=int, default=8, help="training cities in the pool (default 8)")
    args = ap.parse_args()
    batches = sorted({1, *(int(b) for b in args.batches.split(","))})
    levels = [s.strip() for s in args.levels.split(",") if s.strip()]
    world = NavWorld(replace(NavConfig(), city_pool_size=args.cities))
    casters = [RayCaster(c) for c in world.cities] if any(
        sensing_preset(lv, world.vehicle.mass_kg).gnss.urban_canyon for lv in levels) else []
    cfg = world.config
    env = {n: _env_us(world, n, max(4, args.periods // cfg.action_repeat), args.repeats) for n in batches}
    print(f"batched onboard estimation: {cfg.vehicle}, {cfg.physics_hz:g} Hz physics, {cfg.control_hz:g} Hz control, "
          f"{cfg.decision_hz:g} Hz decisions, {args.cities} training cities; {platform.processor() or 'cpu'}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; µs per slot per control period, best of "
          f"{args.repeats}")
    figures: dict[str, dict[str, dict[str, float]]] = {}
    for level in levels:
        print(f"\n{level}:")
        print(f"{'N':>5} {'physics':>9} {'estimation':>11} {'est/physics':>12} {'speed-up vs N=1':>16} "
              f"{'env step':>9} {'est/env':>8} {'reset µs/slot':>14}")
        figures[level] = {}
        for n in batches:
            phys, est, reset = _fly_us(world, n, level, casters, args.periods, args.repeats)
            base = figures[level]["1"]["onboard_us"] if n != 1 else est
            row = {"physics_us": phys, "onboard_us": est, "onboard_vs_physics_ratio": est / phys,
                   "speedup_vs_n1": base / est, "env_step_us": env[n], "onboard_vs_env_ratio": est / env[n],
                   "reset_us": reset}
            figures[level][str(n)] = row
            print(f"{n:>5} {phys:>9.2f} {est:>11.2f} {est / phys:>12.2f} {base / est:>16.1f} {env[n]:>9.2f} "
                  f"{est / env[n]:>8.2f} {reset:>14.0f}")
    largest = str(max(batches))
    nominal = figures.get("nominal", figures[levels[0]])[largest]
    out: dict[str, Any] = {"onboard_step_us": round(nominal["onboard_us"], 3), "onboard_step_batch": int(largest),
           "onboard_vs_physics_ratio": round(nominal["onboard_vs_physics_ratio"], 3),
           "onboard_vs_env_ratio": round(nominal["onboard_vs_env_ratio"], 3)}
    if "degraded" in figures:
        out["onboard_step_us_degraded"] = round(figures["degraded"][largest]["onboard_us"], 3)
    out["by_level"] = {lv: {n: {k: round(v, 3) for k, v in row.items()} for n, row in rows.items()}
                       for lv, rows in figures.items()}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
