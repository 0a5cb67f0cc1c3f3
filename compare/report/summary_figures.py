"""Figures of a run's statistics: forest plots of means and paired differences, success along task difficulty.

Like `compare.report.figures`, builders take data already loaded (typed rows built by the report from
summary.json and metrics.csv) and return A4-landscape `matplotlib.figure.Figure`s; they never read files
and never touch pyplot's global state. Every interval drawn is a 95 % interval from the summary; the
figures only place them.
"""
from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from compare.report.layout import PAGE_SIZE_IN, content_width_in, text_width_pt, wrap_to_width
from compare.results.difficulty import DifficultyAxis

NOTE_PT = 7.5
LABEL_PT = 8.5
"""Font sizes of a forest row's note and label [pt]."""
LABEL_CHARS = 40
"""Row labels of a forest plot are shortened to this many characters."""


def subtitle_lines(text: str, size: float = 8.5) -> str:
    """A figure's subtitle broken into lines that fit the page's text column (italic at `size`)."""
    return "\n".join(wrap_to_width(text, 72.0 * content_width_in(), size, style="italic"))


@dataclass(frozen=True)
class ForestRow:
    """One row of a forest panel: a mean with its interval, already in the panel's unit.

    Attributes:
        label: the row's name (a pilot, or a pair "A − B"). color: its marker colour.
        mean, low, high: the value and its interval (None: nothing to draw, the note says why).
        note: text printed at the right of the row (e.g. "n 120" or "MDD 0.8").
        hollow: draw the marker open (a difference whose interval includes zero).
    """

    label: str
    color: str
    mean: float | None
    low: float | None
    high: float | None
    note: str = ""
    hollow: bool = False


@dataclass(frozen=True)
class ForestPanel:
    """One metric's panel: its title (with unit), rows top to bottom, whether to mark zero (differences), and
    fixed x limits (e.g. 0-100 for a rate; None: fitted to the intervals)."""

    title: str
    rows: tuple[ForestRow, ...]
    zero_line: bool = False
    limits: tuple[float, float] | None = None


def forest_figure(title: str, panels: Sequence[ForestPanel], *, subtitle: str = "", columns: int = 3,
                  legend: Sequence[tuple[str, str]] = ()) -> Figure:
    """Forest plots, one panel per metric: each row a point with its interval, its note at the right.

    Args:
        title: page title. subtitle: a line under it (how to read the page).
        panels: the metrics, left to right then top to bottom.
        columns: panels per row.
        legend: (label, colour) entries shown under the title (empty: none).
    """
    fig = Figure(figsize=PAGE_SIZE_IN)
    fig.suptitle(title, fontsize=15, fontweight="bold", y=0.97)
    if subtitle:
        fig.text(0.5, 0.925, subtitle_lines(subtitle), ha="center", va="top", fontsize=8.5, style="italic")
    rows = max(1, math.ceil(len(panels) / columns))
    # room [figure fraction] left of each panel for its row labels and right of it for the notes, as measured
    widest_label = max((text_width_pt(_short_label(r.label), LABEL_PT) for p in panels for r in p.rows),
                       default=text_width_pt("x" * 8, LABEL_PT))
    widest_note = max((text_width_pt(r.note, NOTE_PT) for p in panels for r in p.rows), default=0.0)
    label = 0.012 + widest_label / 72.0 / PAGE_SIZE_IN[0]
    note = max(0.075, 0.012 + widest_note / 72.0 / PAGE_SIZE_IN[0])
    left, right = label + 0.01, 0.99 - note
    width = (right - left - (columns - 1) * (label + note)) / columns
    grid = fig.add_gridspec(rows, columns, left=left, right=right, top=0.84, bottom=0.12,
                            wspace=(label + note) / width, hspace=0.45)
    for k, panel in enumerate(panels):
        _forest_panel(fig.add_subplot(grid[k // columns, k % columns]), panel)
    if legend:
        handles = [Line2D([], [], marker="o", color=c, linestyle="none", label=lab) for lab, c in legend]
        fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 5), fontsize=8.5, frameon=False)
    return fig


def _short_label(label: str) -> str:
    return textwrap.shorten(label, LABEL_CHARS, placeholder="…")


def _forest_panel(ax: Axes, panel: ForestPanel) -> None:
    n = len(panel.rows)
    ys = np.arange(n)[::-1]  # first row on top
    for y, row in zip(ys, panel.rows):
        if row.mean is not None and math.isfinite(row.mean):
            lo = row.mean if row.low is None else row.low
            hi = row.mean if row.high is None else row.high
            ax.errorbar([row.mean], [y], xerr=[[row.mean - lo], [hi - row.mean]], fmt="o", color=row.color,
                        markerfacecolor="white" if row.hollow else row.color, markersize=7, capsize=4, lw=1.6)
        ax.annotate(row.note or ("n/a" if row.mean is None else ""), xy=(1.0, y), xycoords=("axes fraction", "data"),
                    xytext=(5, 0), textcoords="offset points", va="center", fontsize=NOTE_PT)
    if panel.zero_line:
        ax.axvline(0.0, color="0.3", lw=0.9, ls="--")
    if panel.limits is not None:
        ax.set_xlim(*panel.limits)
    ax.set_yticks(ys, [_short_label(r.label) for r in panel.rows], fontsize=LABEL_PT)
    ax.set_ylim(-0.7, n - 0.3)
    ax.set_title(panel.title, fontsize=10)
    ax.grid(axis="x", color="0.9")
    ax.tick_params(axis="x", labelsize=8)


def difficulty_figure(title: str, axes: Sequence[DifficultyAxis], labels: Mapping[str, str],
                      colors: Mapping[str, str], *, subtitle: str = "") -> Figure:
    """Success rate [%] per bin of each difficulty axis, one panel per axis, per pilot with its Wilson interval.

    Args:
        title: page title. subtitle: a line under it.
        axes: the axes (`compare.results.difficulty.success_by_difficulty`), up to four.
        labels, colors: each pilot's label and colour (by pilot name; the pilots drawn are the axes').
    """
    fig = Figure(figsize=PAGE_SIZE_IN)
    fig.suptitle(title, fontsize=15, fontweight="bold", y=0.97)
    if subtitle:
        fig.text(0.5, 0.925, subtitle_lines(subtitle), ha="center", va="top", fontsize=8.5, style="italic")
    grid = fig.add_gridspec(2, 2, left=0.07, right=0.98, top=0.84, bottom=0.14, wspace=0.18, hspace=0.6)
    pilots: list[str] = []
    for k, axis in enumerate(axes[:4]):
        ax = fig.add_subplot(grid[k // 2, k % 2])
        _difficulty_panel(ax, axis, colors)
        pilots += [m for m in axis.rates if m not in pilots]
    handles = [Line2D([], [], marker="o", color=colors.get(m, "0.3"), label=labels.get(m, m)) for m in pilots]
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 5), fontsize=9, frameon=False)
    return fig


def _difficulty_panel(ax: Axes, axis: DifficultyAxis, colors: Mapping[str, str]) -> None:
    title = axis.name + (f" ({axis.left_out} episodes without a value left out)" if axis.left_out else "")
    ax.set_title(title, fontsize=10)
    ax.set_ylabel("success [%]")
    ax.set_ylim(-5, 105)
    ax.grid(axis="y", color="0.9")
    if not axis.bins:
        ax.text(0.5, 0.5, "not recorded in this run", ha="center", va="center", transform=ax.transAxes)
        ax.set_xticks([])
        return
    pilots = list(axis.rates)
    width = 0.5 / max(len(pilots), 1)
    x = np.arange(len(axis.bins), dtype=float)
    for i, m in enumerate(pilots):
        bins = axis.rates[m]
        xs = x + (i - (len(pilots) - 1) / 2) * width
        have = [k for k, b in enumerate(bins) if b.n]
        if not have:
            continue
        rate, low, high = (100.0 * np.array([getattr(bins[k], f) for k in have], dtype=float)
                           for f in ("rate", "low", "high"))
        ax.errorbar(xs[have], rate, yerr=[rate - low, high - rate], fmt="o-", color=colors.get(m, "0.3"),
                    markersize=5, capsize=3, lw=1.3)
    ticks = ["\n".join(textwrap.wrap(lab, 18)) + f"\n{_counts(axis, k)}" for k, lab in enumerate(axis.bins)]
    ax.set_xticks(x, ticks, fontsize=7.5)
    ax.set_xlim(-0.6, len(axis.bins) - 0.4)


def _counts(axis: DifficultyAxis, k: int) -> str:
    """The episodes in bin k: "n 40", or "n 40/38" where the pilots flew different numbers."""
    ns = [axis.rates[m][k].n for m in axis.rates]
    return f"n {ns[0]}" if len(set(ns)) == 1 else "n " + "/".join(str(n) for n in ns)
