"""What the learned pilot's lidar-measured obstacle senses cost per decision (`rl.sensing.lidar_view.LidarView`),
against the exact senses they stand in for, same run.

N slots (default 256) fly across the first `--cities` (default 8) cities of the learned pilot's training pool at the
lidar benchmark's street poses (`perf/batch_lidar.py`: clearance >= 3 m, 5-60 m up, tilted up to 20 deg, any
heading), slot i in city i mod C, each scanning with the small quad's nominal lidar reduced to 8 channels x 36
columns (the scans are cast beforehand, untimed). Each slot's estimates fly on at the vehicle's top speed in a
direction of its own (the height memory's window follows them as in flight; the scans' points are placed on them,
which moves the points, not their count), 0.3 m off the truth (sigma 0.3 m); the goal frame's heading is drawn apart
from the yaw. Per decision it times, per slot:

* integrate: `LidarView.integrate` of every slot's one new scan (placing it on the estimate, the ground test, the
  kept points and the height memory);
* read: `LidarView.read` (rays, clearance and nearest vector from the kept points, the height map: the prior's
  raster through `Perception.roofs`, max'ed with the memory), of which the prior's `Perception.roofs` alone;
* exact: what the env computes today for the same slots, `Perception.observe` and `nearest_surface`;

the worst case of the memory's window, every slot's estimate jumping to the next street pose each decision
("teleport": every window moves by hundreds of metres and is cleared); and a decision of one slot (the runner's
pilot, M = 1): integrate and read. Each figure is the fastest of
`--repeats` timing blocks (on a shared machine other work only ever adds time).

    OMP_NUM_THREADS=1 python perf/lidar_view.py [--slots 256] [--cities 8] [--decisions 8] [--repeats 3]

Prints a table and, as its last line, one JSON object: us_per_slot_decision_8x36 (integrate + read at N slots),
integrate_us, read_us, prior_roofs_us, exact_us (per slot), ratio_vs_exact, us_per_slot_decision_teleport,
us_decision_one_slot, bytes_per_slot and the run's parameters.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from batch_lidar import _poses, _spec  # noqa: E402  (the lidar benchmark's street poses and reduced specs)

from rl.sensing.lidar_view import LidarView  # noqa: E402
from rl.sensing.perception import Perception  # noqa: E402
from rl.sensing.senses import clearance_sensor, nearest_surface  # noqa: E402
from rl.task.config import NavConfig  # noqa: E402
from uam_fdm.sensing.batch_lidar import BatchLidar  # noqa: E402
from uam_fdm.sensing.lidar import LidarScan  # noqa: E402
from uam_fdm.sensing.raycast import RayCaster  # noqa: E402
from uam_fdm.sensing.specs import sensing_preset  # noqa: E402
from uam_fdm.vehicle.params import load_vehicle  # noqa: E402

SPEC = "8x36"


def _best(block: Callable[[], None], repeats: int, setup: Callable[[], None] = lambda: None) -> float:
    """Fastest of `repeats` runs of `block` [s], each after an untimed `setup`, after one to warm up."""
    setup()
    block()
    best = math.inf
    for _ in range(repeats):
        setup()
        a = time.perf_counter()
        block()
        best = min(best, time.perf_counter() - a)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slots", type=int, default=256, help="slots N (default 256)")
    ap.add_argument("--cities", type=int, default=8, help="training cities the slots fly in (default 8)")
    ap.add_argument("--decisions", type=int, default=8, help="decisions (poses) per slot in a timing block (default 8)")
    ap.add_argument("--repeats", type=int, default=3, help="timing blocks per figure (default 3)")
    args = ap.parse_args()
    nav = NavConfig()
    n, d = args.slots, args.decisions
    cities = [nav.cities.city(s) for s in nav.city_seeds()[: args.cities]]
    vehicle = load_vehicle(nav.vehicle)
    radius = vehicle.collision_radius_m
    spec = _spec(SPEC, sensing_preset("nominal", 1.5).lidar)  # the small quad's VLP-16, reduced
    perception = Perception(cities, radius, nav.perception)  # exact level: the prior is the city
    sensor = clearance_sensor(cities, nav.scales, radius)
    pos, quat = _poses(cities, n, d, seed=0)
    city = np.arange(n) % len(cities)
    lidar = BatchLidar(spec, n, [RayCaster(c) for c in cities])
    for i in range(n):
        lidar.restart(i, np.random.default_rng(i), int(city[i]))
    slots = np.arange(n)
    scans: list[list[tuple[LidarScan, ...]]] = []
    for k in range(d):
        lidar.measure(slots, np.full(n, 0.1 * k), pos[k], quat[k])
        scans.append(lidar.hand_over(slots, np.full(n, math.inf)))
    rng = np.random.default_rng(1)
    course = rng.uniform(-math.pi, math.pi, n)
    step = vehicle.controller.max_speed_m_s / nav.decision_hz * np.column_stack([np.cos(course), np.sin(course)])
    teleport = np.zeros((d, n, 13))
    teleport[:, :, 0:3] = pos + rng.normal(0.0, 0.3, pos.shape)
    teleport[:, :, 6:10] = quat
    flight = teleport.copy()
    flight[:, :, 0:3] = teleport[0:1, :, 0:3]
    flight[:, :, 0:2] += np.arange(d)[:, None, None] * step
    sigma = np.full(n, 0.3)
    heading = rng.uniform(-math.pi, math.pi, (d, n))
    view = LidarView(perception, n, spec, nav.scales.clearance_m)

    def reset(m: int) -> Callable[[], None]:
        return lambda: view.reset(slots[:m], city[:m])  # once an episode: not a decision's cost

    def run(m: int, do_integrate: bool, do_read: bool, est: np.ndarray = flight) -> None:
        for k in range(d):
            if do_integrate:
                view.integrate(slots[:m], scans[k][:m], est[k, :m], sigma[:m])
            if do_read:
                view.read(slots[:m], est[k, :m], heading[k, :m])

    def prior_roofs() -> None:
        for k in range(d):
            perception.roofs(flight[k, :, 0:3], heading[k], city)

    def exact() -> None:
        for k in range(d):
            perception.observe(pos[k], heading[k], city)
            nearest_surface(sensor, pos[k], city)

    per = 1e6 / (n * d)
    t_int = _best(lambda: run(n, True, False), args.repeats, reset(n)) * per
    t_both = _best(lambda: run(n, True, True), args.repeats, reset(n)) * per
    t_read = t_both - t_int
    t_prior = _best(prior_roofs, args.repeats) * per
    t_exact = _best(exact, args.repeats) * per
    t_teleport = _best(lambda: run(n, True, True, teleport), args.repeats, reset(n)) * per
    t_one = _best(lambda: run(1, True, True), args.repeats, reset(1)) * 1e6 / d
    returns = np.mean([len(s[0].ranges_m) for row in scans for s in row])
    print(f"LidarView per slot per decision: N = {n} slots in {args.cities} training cities, {spec.part} reduced to "
          f"{SPEC} ({spec.rays_per_scan} beams, {returns:.0f} returns a scan on average), {d} decisions a block; "
          f"{platform.processor() or platform.machine()}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; "
          f"best of {args.repeats}")
    print(f"{'part':<57} {'µs/slot':>9}")
    for name, value in (("integrate (place, ground test, kept points, memory)", t_int),
                        ("read (rays, clearance, nearest, height map)", t_read),
                        ("  of which the prior's raster (Perception.roofs)", t_prior),
                        ("integrate + read", t_both),
                        ("integrate + read, teleporting (every window cleared)", t_teleport),
                        ("exact senses today (Perception.observe + nearest_surface)", t_exact)):
        print(f"{name:<57} {value:>9.1f}")
    print(f"one slot (the runner's pilot): {t_one:.0f} µs a decision; state {view.nbytes / n / 1e3:.1f} kB a slot "
          f"(memory window {view.window} x {view.window} cells of {view.sensed_cell_m:g} m)")
    out: dict[str, Any] = {"slots": n, "cities": args.cities, "decisions": d, "repeats": args.repeats,
                           f"us_per_slot_decision_{SPEC}": round(t_both, 2), "integrate_us": round(t_int, 2),
                           "read_us": round(t_read, 2), "prior_roofs_us": round(t_prior, 2),
                           "exact_us": round(t_exact, 2), "ratio_vs_exact": round(t_both / t_exact, 3),
                           "us_per_slot_decision_teleport": round(t_teleport, 2),
                           "us_decision_one_slot": round(t_one, 1), "bytes_per_slot": int(view.nbytes / n)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
