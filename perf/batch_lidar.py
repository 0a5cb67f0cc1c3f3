"""What the learned pilot's lidar costs in a training batch: `BatchLidar.measure` (the lidar of `BatchOnboard`, bit
for bit `Lidar.scan` per slot) per slot-scan, for reduced specs and the level's full one, same run.

N slots (default 64) fly across the first `--cities` (default 8) cities of the learned pilot's training pool
(`NavConfig().cities`, the generator's shipped-style districts), slot i in city i mod C, each at street positions
(clearance >= 3 m, 5-60 m up, tilted up to 20 deg, any heading; `--poses` per slot, cycled). Every slot scans at
once (the worst case: in the env a slot's scans fall due on its own clock). Per spec it times

* batched: `BatchLidar.measure` of all N slots (the slots in one city cast together, up to
  `uam_fdm.sensing.batch_lidar.CAST_RAYS` rays a call, then each slot's dropout and noise draws from its own
  stream), per slot-scan;
* per slot: `Lidar.scan` slot by slot (one cast per slot and its truth record, as `Onboard` calls it);
* cast: the batched path's `RayCaster.ranges_m` calls alone (the same calls), per slot-scan: batched minus cast is
  the work around the cast (beam directions, draws, the scans' arrays);

and the cost of one `RayCaster` call apart from its rays (a 1-ray cast): the per-call overhead that casting the
slots of a city together saves. Specs: "CxK" is C channels x K azimuth columns of the level's lidar (its field of
view, range, noise, dropout); "full" is the level's own (VLP-16: 16 x 1800). Each figure is the fastest of
`--repeats` timing blocks (on a shared machine other work only ever adds time); ratios are to the full spec in
the same run. "core share at 400 sim-s/s" is the share of one core the lidar takes at the env's throughput target
(400 simulated seconds per second, summed over slots) and the spec's scan rate.

    OMP_NUM_THREADS=1 python perf/batch_lidar.py [--slots 64] [--cities 8] [--specs 8x36,8x72,16x72,full]

Prints a table and, as its last line, one JSON object: slot_scan_us_<spec> (batched), per_slot_scan_us_<spec>,
cast_us_<spec>, ratio_<spec>_vs_full, call_overhead_us, and the run's parameters.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rl.task.config import NavConfig  # noqa: E402
from uam_fdm.city.buildings import BuildingMap  # noqa: E402
from uam_fdm.sensing.batch_lidar import CAST_RAYS, BatchLidar  # noqa: E402
from uam_fdm.sensing.lidar import Lidar  # noqa: E402
from uam_fdm.sensing.raycast import RayCaster  # noqa: E402
from uam_fdm.sensing.specs import LidarSpec, sensing_preset  # noqa: E402
from uam_fdm.vehicle.attitude import rotation_matrices  # noqa: E402

TARGET_SIM_S_PER_S = 400.0  # the env + PPO's throughput target, simulated seconds per wall second


def _spec(name: str, full: LidarSpec) -> LidarSpec:
    """`full`, or "CxK": C channels x K columns of it."""
    if name == "full":
        return full
    channels, columns = (int(v) for v in name.split("x"))
    return dataclasses.replace(full, channels=channels, horizontal_resolution_deg=360.0 / columns)


def _poses(cities: list[BuildingMap], n: int, per_slot: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Street poses of slot i in city i mod C: positions (P, N, 3) world ENU [m] and quaternions (P, N, 4)."""
    rng = np.random.default_rng(seed)
    pos, quat = np.zeros((per_slot, n, 3)), np.zeros((per_slot, n, 4))
    for i in range(n):
        city, found = cities[i % len(cities)], 0
        while found < per_slot:
            p = rng.uniform(city.bounds_min_m, city.bounds_max_m, (256, 3))
            p[:, 2] = rng.uniform(5.0, 60.0, 256)
            free = p[city.clearance(p).distance_m >= 3.0][: per_slot - found]
            pos[found:found + len(free), i] = free
            found += len(free)
        tilt = math.radians(20.0)
        roll, pitch = rng.uniform(-tilt, tilt, (2, per_slot))
        yaw = rng.uniform(-math.pi, math.pi, per_slot)
        cr, sr, cp, sp = np.cos(roll / 2), np.sin(roll / 2), np.cos(pitch / 2), np.sin(pitch / 2)
        cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
        quat[:, i] = np.column_stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                                      cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])
    return pos, quat


def _time_spec(spec: LidarSpec, casters: list[RayCaster], pos: np.ndarray, quat: np.ndarray,
               repeats: int) -> dict[str, float]:
    """Batched, per-slot and cast-only µs per slot-scan (best block of `repeats`; one block scans every pose)."""
    per_slot, n = pos.shape[0], pos.shape[1]
    slots = np.arange(n)
    world = slots % len(casters)
    batch = BatchLidar(spec, n, casters)
    singles = [Lidar(spec, casters[int(world[i])], np.random.default_rng(i)) for i in range(n)]
    rot = [rotation_matrices(quat[k]) for k in range(per_slot)]
    d_world = [[batch.directions_body @ r.T for r in rot[k]] for k in range(per_slot)]
    per_call = max(1, CAST_RAYS // spec.rays_per_scan)  # the batched path's calls: slots of a city, chunked
    calls = [(members[j:j + per_call].tolist(), w) for w in range(len(casters))
             for members in [np.flatnonzero(world == w)] for j in range(0, len(members), per_call)]
    best = {"batched": math.inf, "per_slot": math.inf, "cast": math.inf}
    for _ in range(repeats + 1):  # the first block warms up (caches, buffers)
        for i in range(n):
            batch.restart(i, np.random.default_rng(i), int(world[i]))
        spent = dict.fromkeys(best, 0.0)
        for k in range(per_slot):
            t = np.full(n, 0.1 * k)
            a = time.perf_counter()
            batch.measure(slots, t, pos[k], quat[k])
            b = time.perf_counter()
            for i in range(n):
                singles[i].scan(0.1 * k, pos[k, i], rot[k][i])
            c = time.perf_counter()
            for g, w in calls:
                origins = pos[k, g[0]] if len(g) == 1 else np.repeat(pos[k, g], spec.rays_per_scan, axis=0)
                directions = d_world[k][g[0]] if len(g) == 1 else np.concatenate([d_world[k][i] for i in g])
                casters[w].ranges_m(origins, directions, spec.max_range_m)
            d = time.perf_counter()
            batch.hand_over(slots, np.full(n, math.inf))  # untimed: the queues stay short
            spent["batched"] += b - a
            spent["per_slot"] += c - b
            spent["cast"] += d - c
        best = {key: min(best[key], spent[key]) for key in best}
    return {key: v * 1e6 / (per_slot * n) for key, v in best.items()}


def _call_overhead_us(caster: RayCaster, repeats: int = 2000) -> float:
    """One `RayCaster.ranges_m` call of a single ray [µs]: what a call costs apart from its rays."""
    o, d = np.zeros(3), np.array([[1.0, 0.0, 0.0]])
    best = math.inf
    for _ in range(3):
        a = time.perf_counter()
        for _ in range(repeats):
            caster.ranges_m(o, d, 100.0)
        best = min(best, time.perf_counter() - a)
    return best * 1e6 / repeats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slots", type=int, default=64, help="slots N (default 64)")
    ap.add_argument("--cities", type=int, default=8, help="training cities the slots fly in (default 8)")
    ap.add_argument("--specs", default="8x36,8x72,16x72,full", help="channels x columns, or full (default: "
                    "8x36,8x72,16x72,full)")
    ap.add_argument("--poses", type=int, default=4, help="poses per slot in a timing block (default 4)")
    ap.add_argument("--repeats", type=int, default=3, help="timing blocks per figure (default 3)")
    args = ap.parse_args()
    names = [s.strip() for s in args.specs.split(",") if s.strip()]
    if "full" not in names:
        names.append("full")  # the reference of the ratios
    nav = NavConfig()
    t0 = time.perf_counter()
    cities = [nav.cities.city(s) for s in nav.city_seeds()[: args.cities]]
    casters = [RayCaster(c) for c in cities]
    built_s = time.perf_counter() - t0
    full = sensing_preset("nominal", 1.5).lidar  # the small quad's (the learned pilot's vehicle class)
    pos, quat = _poses(cities, args.slots, args.poses, seed=0)
    figures = {name: _time_spec(_spec(name, full), casters, pos, quat, args.repeats) for name in names}
    overhead = _call_overhead_us(casters[0])
    ref = figures["full"]["batched"]
    print(f"lidar per slot-scan: N = {args.slots} slots in {args.cities} training cities "
          f"({sum(len(c.buildings) for c in cities)} parts, built with casters in {built_s:.1f} s), {full.part} "
          f"at {full.rate_hz:g} Hz; {platform.processor() or platform.machine()}, OMP_NUM_THREADS="
          f"{os.environ.get('OMP_NUM_THREADS')}; µs per slot-scan, best of {args.repeats}")
    print(f"{'spec':>7} {'rays':>6} {'batched':>9} {'cast':>9} {'around':>8} {'Lidar.scan':>11} {'µs/ray':>7} "
          f"{'vs full':>8} {'core share at 400 sim-s/s':>26}")
    for name in names:
        f, rays = figures[name], _spec(name, full).rays_per_scan
        share = TARGET_SIM_S_PER_S * full.rate_hz * f["batched"] * 1e-6
        print(f"{name:>7} {rays:>6} {f['batched']:>9.1f} {f['cast']:>9.1f} {f['batched'] - f['cast']:>8.1f} "
              f"{f['per_slot']:>11.1f} {f['cast'] / rays:>7.3f} {f['batched'] / ref:>8.4f} {share:>25.1%}")
    print(f"one RayCaster call of 1 ray: {overhead:.1f} µs (the per-call overhead a slot's own cast pays; the "
          f"batched path pays it once per {CAST_RAYS} rays of a city)")
    out: dict[str, Any] = {"slots": args.slots, "cities": args.cities, "poses": args.poses, "repeats": args.repeats,
                           "rate_hz": full.rate_hz}
    for name in names:
        f = figures[name]
        out[f"slot_scan_us_{name}"] = round(f["batched"], 2)
        out[f"per_slot_scan_us_{name}"] = round(f["per_slot"], 2)
        out[f"cast_us_{name}"] = round(f["cast"], 2)
        if name != "full":
            out[f"ratio_{name}_vs_full"] = round(f["batched"] / ref, 5)
    out["call_overhead_us"] = round(overhead, 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
