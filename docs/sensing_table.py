"""The table of docs/sensing.md: both pilots at each sensing and map-error level, from run folders.

Fly the levels (the same tasks and seeds at every level; the map error is drawn from each scenario's first seed):

    for lv in "perfect exact" "nominal exact" "degraded exact" "nominal outdated" "nominal wrong" \
              "degraded wrong"; do
      set -- $lv
      uam-compare run default --seeds 0,1,2 --sensing $1 --map-error $2 --videos none --out runs/levels/$1-$2
    done
    python docs/sensing_table.py runs/levels/*

Prints a markdown table per vehicle (rates with Wilson 95 % intervals; below 10 episodes the counts alone), the
paired difference ppo - rrt_mpc (Newcombe 95 %), and last one JSON line of the figures.
"""
from __future__ import annotations

import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from compare.results.stats import PairedCounts, newcombe_paired_interval
from uam_fdm.stats import wilson_interval

FEW = 10  # below this many episodes a rate is given as counts, not with an interval
PILOTS = ("ppo", "rrt_mpc")


def _rate(k: int, n: int) -> str:
    if n < FEW:
        return f"{k}/{n} (too few for an interval)"
    lo, hi = wilson_interval(k, n)
    return f"{100 * k / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] (n {n})"


def _rows(run: Path) -> list[dict[str, str]]:
    with open(run / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def main(runs: list[Path]) -> None:
    figures: dict[str, dict] = {}
    by_vehicle: dict[str, list[list[str]]] = defaultdict(list)
    for run in runs:
        rows = _rows(run)
        for vehicle in sorted({r["vehicle"] for r in rows}):
            mine = [r for r in rows if r["vehicle"] == vehicle]
            level = f"{mine[0]['sensing']} / {mine[0]['map_error']}"
            cells: dict[str, dict[tuple, bool]] = {p: {} for p in PILOTS}
            for p in PILOTS:
                rs = [r for r in mine if r["method"] == p]
                n, ok = len(rs), sum(r["success"] == "1" for r in rs)
                hit = sum(r["collision"] == "1" for r in rs)
                h = np.array([float(r["est_error_h_rms_m"]) for r in rs])
                v = np.array([float(r["est_error_v_rms_m"]) for r in rs])
                gnss = np.array([float(r["gnss_availability"]) for r in rs])
                near = np.array([float(r["min_clearance_unmapped_m"]) for r in rs])
                nees = np.array([float(r.get("est_nees_in_bounds", "nan")) for r in rs])
                cells[p] = {(r["scenario"], r["episode"], r["seed"]): r["success"] == "1" for r in rs}
                by_vehicle[vehicle].append([
                    level, p, _rate(ok, n), _rate(hit, n), f"{np.mean(h):.2f} (max {np.max(h):.2f})",
                    f"{np.mean(v):.2f}", "—" if np.all(np.isnan(gnss)) else f"{100 * np.nanmean(gnss):.0f} %",
                    "—" if np.all(np.isnan(near)) else f"{np.nanmin(near):.2f}",
                    "—" if np.all(np.isnan(nees)) else
                    f"{100 * np.nanmean(nees):.0f} % (least {100 * np.nanmin(nees):.0f} %)"])
                figures.setdefault(vehicle, {}).setdefault(level, {})[p] = {
                    "episodes": n, "success": ok / n if n else None, "collisions": hit / n if n else None,
                    "est_error_h_rms_m_mean": float(np.mean(h)) if n else None,
                    "est_nees_in_bounds_mean": None if np.all(np.isnan(nees)) else float(np.nanmean(nees))}
            keys = sorted(set(cells["ppo"]) & set(cells["rrt_mpc"]))
            if len(keys) >= FEW:
                a = np.array([cells["ppo"][k] for k in keys])
                b = np.array([cells["rrt_mpc"][k] for k in keys])
                lo, hi = newcombe_paired_interval(PairedCounts.of(a, b))
                diff = (f"{100 * (a.mean() - b.mean()):+.0f} points [{100 * lo:+.0f}, {100 * hi:+.0f}] "
                        f"over {len(keys)} pairs")
            else:
                diff = f"{len(keys)} pairs: too few for an interval"
            by_vehicle[vehicle].append([level, "ppo − rrt_mpc", diff, "", "", "", "", "", ""])
            figures[vehicle][level]["paired_success_difference"] = diff
    header = ["sensing / map", "pilot", "success", "collisions", "est. error h RMS [m], mean (max)",
              "est. error v RMS [m]", "GNSS fix", "least clearance to unmapped [m]",
              "position NEES inside its 95 % interval, mean over flights"]
    for vehicle, table in by_vehicle.items():
        print(f"\n{vehicle}\n")
        print("| " + " | ".join(header) + " |")
        print("|" + "---|" * len(header))
        for row in table:
            print("| " + " | ".join(row) + " |")
    print("\nestimation error per scenario (both pilots' flights; mean of the flights' RMS, 95 % t-interval)\n")
    print("| sensing / map | scenario | flights | horizontal RMS [m] | vertical RMS [m] |")
    print("|---|---|---|---|---|")
    for run in runs:
        rows = [r for r in _rows(run) if r["sensing"] != "perfect"]
        for scenario in sorted({r["scenario"] for r in rows}):
            mine = [r for r in rows if r["scenario"] == scenario]
            level = f"{mine[0]['sensing']} / {mine[0]['map_error']}"
            cells = [_mean_interval(np.array([float(r[c]) for r in mine]))
                     for c in ("est_error_h_rms_m", "est_error_v_rms_m")]
            print(f"| {level} | {scenario} | {len(mine)} | {cells[0]} | {cells[1]} |")
            figures.setdefault("per_scenario", {}).setdefault(level, {})[scenario] = cells[0]
    print(json.dumps(figures))


def _mean_interval(values: np.ndarray) -> str:
    """Mean and its 95 % t-interval (below `FEW` values: the values' range instead)."""
    if len(values) < FEW:
        return f"{values.mean():.2f} (range {values.min():.2f}-{values.max():.2f}; too few for an interval)"
    from scipy.stats import t

    half = t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values))
    return f"{values.mean():.2f} [{values.mean() - half:.2f}, {values.mean() + half:.2f}]"


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]])
