"""The report's robustness-sweep pages, two per vehicle: success and collision rate against density altitude
and against steady wind (the air), then against the share of the map missing, the GNSS sky and the lidar's range
(the sensing), one line per pilot in its colour with its Wilson 95 % band, steps on the x axis, the steps outside
a learned pilot's trained conditions shaded. Drawn from the run's results only (`compare.results.sweep_rates`),
for a run of a sweep set (`compare.scenarios.sweep.SWEEP_SETS`).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from compare.report.metrics_pages import PilotStyle
from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo
from compare.results.sweep_rates import AIR_AXES, SENSED_AXES, SweepRate, sweep_rates
from compare.scenarios.sweep import SWEEP_SETS

_X_LABEL = {"density altitude": "density altitude [km]", "wind": "steady wind [m/s]",
            "map missing": "buildings missing from the map [%]", "GNSS": "GNSS sky", "lidar range": "lidar range [m]"}
_X_SCALE = {"density altitude": 1e-3, "wind": 1.0, "map missing": 100.0, "GNSS": 1.0, "lidar range": 1.0}
_PAGES = (("", AIR_AXES, "air"), ("_sensing", SENSED_AXES, "sensing and map"))
DODGE = 0.012
"""Pilots are drawn this fraction of the axis span apart around each step, so equal rates stay visible."""


def sweep_pages(info: RunInfo, rows: Sequence[EpisodeMetrics], style: PilotStyle) -> list[tuple[str, Figure]]:
    """The sweep pages of a run, (name, figure) per vehicle and group of axes flown (the air's, then the sensing's);
    none unless the run flew a sweep set."""
    if info.task_set is None or info.task_set.name not in SWEEP_SETS:
        return []
    rates = sweep_rates(info, rows)
    vehicles = list(dict.fromkeys(r.vehicle for r in rates))
    records = [(p.vehicle, m, p) for m in info.pilots for p in info.policies(m)]
    out = []
    for v in vehicles:
        for suffix, axes, what in _PAGES:
            mine = [r for r in rates if r.vehicle == v and r.axis in axes]
            if not mine:
                continue
            notes = []
            for vehicle, m, p in records:
                if vehicle == v and any(r.outside for r in mine if r.pilot == m):
                    trained = "; ".join(e.describe() for e in (p.envelope, p.sensing) if e is not None)
                    notes.append(f"{style.label(m)}: shaded steps lie outside the {what} its policy was trained in "
                                 f"({trained}); they were flown all the same.")
            out.append((f"sweep_{v}{suffix}", sweep_figure(v, mine, style, notes,
                                                           f"{info.task_set.name} {info.task_set.version}", axes)))
    return out


def sweep_figure(vehicle: str, rates: Sequence[SweepRate], style: PilotStyle, notes: Sequence[str] = (),
                 subtitle: str = "", axes: Sequence[str] = AIR_AXES) -> Figure:
    """One vehicle's sweep: rows success and collision rate, columns `axes`, a line and Wilson band per pilot
    (each `DODGE` of the span aside of the step, so that equal rates stay visible); steps outside a pilot's trained
    conditions shaded in its colour and drawn with open markers.

    Args:
        vehicle: the vehicle (title).
        rates: its rates (`sweep_rates`).
        style: the pilots' order, labels and colours.
        notes: lines printed under the plots (e.g. the trained conditions of the shaded steps).
        subtitle: e.g. the task set and version.
        axes: the axes drawn, one column each (of `compare.results.sweep_rates.AXES`).
    """
    fig = Figure(figsize=(11.0, 8.5))
    grid = fig.subplots(2, len(axes), squeeze=False)
    pilots = sorted(dict.fromkeys(r.pilot for r in rates), key=style.rank)
    tasks = sorted({r.episodes for r in rates})
    n_text = f"{tasks[0]}" if len(tasks) == 1 else f"{tasks[0]}-{tasks[-1]}"
    fig.suptitle(f"Robustness sweep: {vehicle}\n{subtitle} · {n_text} episodes per step and pilot, the same tasks "
                 f"at every step · bands: Wilson 95 %", fontsize=11)
    for col, axis in enumerate(axes):
        mine = [r for r in rates if r.axis == axis]
        for row, (what, name) in enumerate((("success", "success rate"), ("collision", "collision rate"))):
            ax = grid[row][col]
            ax.set_ylim(-0.03, 1.03)
            ax.set_ylabel(name)
            ax.set_xlabel(_X_LABEL[axis])
            ax.grid(True, alpha=0.3)
            if not mine:
                ax.text(0.5, 0.5, f"no {axis} steps in this run", ha="center", va="center", transform=ax.transAxes)
                continue
            steps = sorted({r.x * _X_SCALE[axis] for r in mine})
            # pilots with equal rates would hide each other: each is drawn a little aside (1.2 % of the span)
            span = (steps[-1] - steps[0]) or 1.0
            for k, m in enumerate(pilots):
                _draw_pilot(ax, [r for r in mine if r.pilot == m], what, axis, style.color(m), style.label(m),
                            (k - (len(pilots) - 1) / 2.0) * DODGE * span)
            ax.set_xticks(steps)
            if axis == "GNSS":  # the sky's steps by name, on three short lines so that five fit side by side
                names = {r.x: r.label for r in mine}
                ax.set_xticklabels([_gnss_tick(names[x]) for x in steps], fontsize=7)
            else:
                ax.set_xticklabels([f"{x:g}" if axis != "density altitude" else f"{x:.2f}".rstrip("0").rstrip(".")
                                    for x in steps], fontsize=8)
        grid[0][col].legend(fontsize=8, loc="lower left")
    text = "\n".join(notes)
    fig.text(0.02, 0.01, text, fontsize=8, va="bottom", wrap=True)
    fig.subplots_adjust(left=0.07, right=0.98, top=0.88, bottom=0.1 + 0.03 * len(notes), hspace=0.3, wspace=0.2)
    return fig


def _gnss_tick(label: str) -> str:
    """A GNSS step's label on three short lines: "open sky" -> "open\nsky", "urban canyon, outages to 30 s" ->
    "canyon,\noutages\nto 30 s"."""
    if ", outages to " in label:
        sky, length = label.split(", outages to ")
        return f"{sky.split()[-1]},\noutages\nto {length}"
    return label.replace(" ", "\n", 1)


def _draw_pilot(ax, rates: Sequence[SweepRate], what: str, axis: str, color: str, label: str,
                dodge: float = 0.0) -> None:
    """One pilot's line, band and outside-the-envelope shading on one panel, `dodge` aside on the x axis."""
    if not rates:
        return
    rates = sorted(rates, key=lambda r: r.x)
    x = np.array([r.x * _X_SCALE[axis] for r in rates]) + dodge
    y = np.array([getattr(r, what) for r in rates])
    lo = np.array([getattr(r, f"{what}_ci95")[0] for r in rates])
    hi = np.array([getattr(r, f"{what}_ci95")[1] for r in rates])
    ax.fill_between(x, lo, hi, color=color, alpha=0.15, linewidth=0)
    ax.plot(x, y, "-", color=color, label=label, linewidth=1.6)
    out = np.array([bool(r.outside) for r in rates])
    ax.plot(x[~out], y[~out], "o", color=color, markersize=5)
    ax.plot(x[out], y[out], "o", markerfacecolor="white", markeredgecolor=color, markersize=5)
    # shade each outside step up to half-way to its neighbours, so adjoining outside steps make one region
    edges = np.concatenate([[x[0] - 0.5 * (x[1] - x[0]) if len(x) > 1 else x[0] - 0.5],
                            0.5 * (x[1:] + x[:-1]),
                            [x[-1] + 0.5 * (x[-1] - x[-2]) if len(x) > 1 else x[-1] + 0.5]])
    for k in np.flatnonzero(out):
        ax.axvspan(edges[k], edges[k + 1], color=color, alpha=0.07, hatch="//", linewidth=0)
