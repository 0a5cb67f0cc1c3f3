"""The classical pilot's clearance margin against the reference speed, for the docs: one panel per vehicle.

Reads the tracking-error table (`planners/data/tracking_error.json`, or `--table`) and draws, for each
(turbulence, air) row, M(v) = max(1 m, 2 x p99(v)) made non-decreasing (`planners.margins.margins_for`
with the shipped `MarginRule`) as a step function of the reference speed, with each speed bin's
measured p99 x 2 as points. The PNG is written atomically.

    python docs/margin_figure.py [--table planners/data/tracking_error.json] [--out docs/margin_by_speed.png]
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from planners.margins import DEFAULT_TABLE_PATH, MarginRule, load_tracking_table, margins_for
from uam_fdm.city.plot import save_figure
from uam_fdm.vehicle.params import load_vehicle

DEFAULT_OUT = Path(__file__).resolve().parent / "margin_by_speed.png"


def margin_figure(table_path: Path) -> Figure:
    """M(v) per vehicle (panels) and row (lines) of the table at `table_path`."""
    table, rule = load_tracking_table(table_path), MarginRule()
    vehicles = list(dict.fromkeys(r.vehicle for r in table.rows))
    fig = Figure(figsize=(5.0 * len(vehicles), 4.6), layout="constrained")
    axes = fig.subplots(1, len(vehicles), squeeze=False)[0]
    for ax, name in zip(axes, vehicles, strict=True):
        vehicle = load_vehicle(name)
        rows = [r for r in table.rows if r.vehicle == name]
        top = max((b.speed_hi_m_s for r in rows for b in r.speed_bins), default=vehicle.controller.max_speed_m_s)
        v = np.linspace(0.0, 1.02 * top, 600)
        for row in rows:
            m = margins_for(table, rule, vehicle, row.turbulence, row.density_ratio, 1.0, 0.5).by_speed
            air = "sea level" if row.density_ratio > 0.99 else f"σ = {row.density_ratio:.2f}"
            line = ax.step(v, m.margin_m(v), where="post", label=f"{row.turbulence.value}, {air}")[0]
            centres = [0.5 * (b.speed_lo_m_s + b.speed_hi_m_s) for b in row.speed_bins]
            ax.plot(centres, [rule.k * b.p99_m for b in row.speed_bins], "o", ms=3, color=line.get_color())
        ax.axhline(rule.floor_m, color="0.4", lw=0.8, ls="--")
        ax.set_title(f"{name} (collision radius {vehicle.collision_radius_m:g} m)")
        ax.set_xlabel("reference speed [m/s]")
        ax.set_ylabel("planner margin M beyond the radius [m]")
        ax.set_ylim(bottom=0.0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, title="turbulence, air (points: 2 x p99 per bin)", title_fontsize=7, ncol=2,
                  loc="upper center", bbox_to_anchor=(0.5, -0.16))
    return fig


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, default=DEFAULT_TABLE_PATH, help="tracking-error table to draw")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"PNG to write (default {DEFAULT_OUT})")
    args = ap.parse_args(argv)
    save_figure(margin_figure(args.table), args.out, dpi=130)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
