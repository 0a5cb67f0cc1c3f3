"""The report's degradation page, one per vehicle: success and collision rate against the sensing level and against
the map-error level, one line per pilot in its colour with its Wilson 95 % band. Drawn from the run's results only
(`compare.results.level_rates`), for a run whose scenarios flew more than one sensing or map-error level.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from compare.report.metrics_pages import PilotStyle
from compare.results.level_rates import LevelRate, level_rates
from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo
from uam_fdm.city.map_error import MAP_ERROR_LEVELS
from uam_fdm.sensing.specs import LEVELS as SENSING_LEVELS

AXES = (("sensing", "sensing level", SENSING_LEVELS), ("map_error", "map-error level", MAP_ERROR_LEVELS))
"""The page's columns: axis (`level_rates.AXES`), its label, its levels in order of degradation."""
DODGE = 0.06
"""Pilots are drawn this far apart [level steps] around each level, so equal rates stay visible."""


def degradation_pages(info: RunInfo, rows: Sequence[EpisodeMetrics], style: PilotStyle) -> list[tuple[str, Figure]]:
    """The degradation pages of a run, (name, figure) per vehicle that flew more than one sensing or map-error
    level; none otherwise."""
    rates = [r for r in level_rates(info, rows) if r.axis in {a for a, _, _ in AXES}]
    out = []
    for v in dict.fromkeys(r.vehicle for r in rates):
        mine = [r for r in rates if r.vehicle == v]
        if any(len({r.level for r in mine if r.axis == axis}) > 1 for axis, _, _ in AXES):
            subtitle = "" if info.task_set is None else f"{info.task_set.name} {info.task_set.version}"
            out.append((f"degradation_{v}", degradation_figure(v, mine, style, subtitle)))
    return out


def degradation_figure(vehicle: str, rates: Sequence[LevelRate], style: PilotStyle, subtitle: str = "") -> Figure:
    """One vehicle's rates against its sensing and map-error levels: rows success and collision rate, columns the
    axes (`AXES`), a line and Wilson band per pilot over the levels flown (each `DODGE` aside).

    Args:
        vehicle: the vehicle (title).
        rates: its rates on the sensing and map-error axes (`level_rates`).
        style: the pilots' order, labels and colours.
        subtitle: e.g. the task set and version.
    """
    fig = Figure(figsize=(11.0, 8.5))
    grid = fig.subplots(2, len(AXES), squeeze=False)
    pilots = sorted(dict.fromkeys(r.pilot for r in rates), key=style.rank)
    fig.suptitle(f"Degradation: {vehicle}\n{subtitle} · each level pools the tasks flown at it (the other axis "
                 f"mixed as the run flew it) · bands: Wilson 95 %", fontsize=11)
    for col, (axis, label, order) in enumerate(AXES):
        mine = [r for r in rates if r.axis == axis]
        levels = [lv for lv in order if any(r.level == lv for r in mine)]
        for row, (what, name) in enumerate((("success", "success rate"), ("collision", "collision rate"))):
            ax = grid[row][col]
            ax.set_ylim(-0.03, 1.03)
            ax.set_ylabel(name)
            ax.set_xlabel(label)
            ax.grid(True, alpha=0.3)
            if len(levels) < 2:
                ax.text(0.5, 0.5, f"one {label} in this run" if levels else f"no {label} in this run",
                        ha="center", va="center", transform=ax.transAxes)
                continue
            for k, m in enumerate(pilots):
                _draw_pilot(ax, [r for r in mine if r.pilot == m], levels, what, style.color(m), style.label(m),
                            (k - (len(pilots) - 1) / 2.0) * DODGE)
            ax.set_xticks(range(len(levels)))
            n = {lv: max((r.episodes for r in mine if r.level == lv), default=0) for lv in levels}
            ax.set_xticklabels([f"{lv}\n(n {n[lv]})" for lv in levels], fontsize=8)
            ax.set_xlim(-0.4, len(levels) - 0.6)
        if len(levels) >= 2:
            grid[0][col].legend(fontsize=8, loc="lower left")
    fig.subplots_adjust(left=0.07, right=0.98, top=0.88, bottom=0.1, hspace=0.35, wspace=0.2)
    return fig


def _draw_pilot(ax, rates: Sequence[LevelRate], levels: Sequence[str], what: str, color: str, label: str,
                dodge: float) -> None:
    """One pilot's line and band over `levels` (those it flew), `dodge` aside on the x axis."""
    at = {r.level: r for r in rates}
    flown = [k for k, lv in enumerate(levels) if lv in at]
    if not flown:
        return
    x = np.array(flown, dtype=float) + dodge
    y = np.array([getattr(at[levels[k]], what) for k in flown])
    lo = np.array([getattr(at[levels[k]], f"{what}_ci95")[0] for k in flown])
    hi = np.array([getattr(at[levels[k]], f"{what}_ci95")[1] for k in flown])
    ax.fill_between(x, lo, hi, color=color, alpha=0.15, linewidth=0)
    ax.plot(x, y, "-o", color=color, label=label, linewidth=1.6, markersize=5)
