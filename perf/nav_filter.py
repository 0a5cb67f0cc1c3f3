"""Navigation filter cost: one IMU prediction (state and 16x16 covariance) per vehicle, single and batched, and
one GNSS update.

The prediction of N vehicles is one call into the compiled filter (`uam_fdm.sensing.nav_filter.BatchNavFilter`);
the figure is that call's time divided by N. The baseline is N = 1 in the same run (ratio = its per-vehicle time
over each batch's). Each figure is the fastest of `--repeats` timing blocks (on a shared machine other work only
ever adds time).

    OMP_NUM_THREADS=1 python perf/nav_filter.py [--batches 1,64,256] [--seconds 0.3] [--repeats 3]

Prints a table and, as its last line, one JSON object: ekf_step_us (per vehicle at N = 256), ekf_step_us_single
(N = 1), ekf_update_gnss_us (one fix into one vehicle), and the per-batch figures.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from uam_fdm.sensing.nav_filter import BatchNavFilter, NavEstimate  # noqa: E402
from uam_fdm.sensing.specs import BMI088, IST8310, MS5611  # noqa: E402


@dataclass(frozen=True)
class Fix:
    t_s: float
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    sigma_h_m: float = 1.0
    sigma_v_m: float = 1.5
    sigma_vel_m_s: float = 0.1


def _filters(n: int, compiled: bool | None) -> BatchNavFilter:
    start = NavEstimate.initial(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), BMI088)
    return BatchNavFilter(BMI088, MS5611, IST8310, [start] * n, compiled=compiled)


def _best_us(step: Callable[[], None], seconds: float, repeats: int) -> float:
    """Fastest mean time of one call [µs] over `repeats` blocks of about `seconds` each."""
    step()
    t0, calls = time.perf_counter(), 0
    while time.perf_counter() - t0 < 0.05:
        step()
        calls += 1
    per_block = max(1, int(calls * seconds / 0.05))
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(per_block):
            step()
        best = min(best, (time.perf_counter() - t0) / per_block)
    return best * 1e6


def _predict_us(n: int, seconds: float, repeats: int, compiled: bool | None) -> float:
    nav = _filters(n, compiled)
    rng = np.random.default_rng(0)
    accel = np.array([0.0, 0.0, 9.80665]) + 0.05 * rng.standard_normal((n, 3))
    gyro = 0.01 * rng.standard_normal((n, 3))
    clock = [0.0]

    def step() -> None:
        clock[0] += 0.004
        nav.predict(clock[0], accel, gyro)
    return _best_us(step, seconds, repeats) / n


def _update_gnss_us(n: int, seconds: float, repeats: int) -> float:
    nav = _filters(n, None)
    fixes = [Fix(0.0, np.zeros(3), np.zeros(3))] * n
    snapshot = nav.x.copy(), nav.P.copy()

    def step() -> None:
        nav.x[:], nav.P[:] = snapshot  # the same update each time (a converged P would make every call equal)
        nav.update_gnss(fixes)
    return _best_us(step, seconds, repeats) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", default="1,64,256", help="batch sizes (default 1,64,256; 1 is the baseline)")
    ap.add_argument("--seconds", type=float, default=0.3, help="length of one timing block [s] (default 0.3)")
    ap.add_argument("--repeats", type=int, default=3, help="timing blocks per figure (default 3)")
    args = ap.parse_args()
    batches = sorted({1, *(int(b) for b in args.batches.split(","))})
    backend = _filters(1, None).backend
    print(f"navigation filter (error-state EKF: 16 navigation states + the heading aid's disturbance), "
          f"{backend} backend; {platform.processor() or 'cpu'}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")
    print(f"{'N':>6} {'predict µs/vehicle':>20} {'ratio to N=1':>14} {'GNSS update µs/vehicle':>24}")
    predict, update = {}, {}
    for n in batches:
        predict[n] = _predict_us(n, args.seconds, args.repeats, None)
        update[n] = _update_gnss_us(n, args.seconds, args.repeats)
        print(f"{n:>6} {predict[n]:>20.2f} {predict[1] / predict[n]:>14.1f} {update[n]:>24.2f}")
    vm = _predict_us(1, args.seconds, args.repeats, False)
    print(f"{'1 (VM)':>6} {vm:>20.2f} {predict[1] / vm:>14.2f}   (CasADi virtual machine, no compiler)")
    largest = max(batches)
    print(json.dumps({"backend": backend, "ekf_step_us": round(predict[largest], 3), "ekf_step_batch": largest,
                      "ekf_step_us_single": round(predict[1], 3), "ekf_step_us_vm_single": round(vm, 3),
                      "ekf_update_gnss_us": round(update[1], 3),
                      "ekf_update_gnss_us_batched": round(update[largest], 3),
                      "ekf_step_us_by_batch": {str(n): round(v, 3) for n, v in predict.items()}}))


if __name__ == "__main__":
    main()
