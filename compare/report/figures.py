"""Figures of a comparison run: one builder per figure, through matplotlib's Figure API.

Builders take data already loaded from a run folder (`FlightTrace`, a `RewardCurve`) and return
`matplotlib.figure.Figure` objects sized as A4 landscape pages; they never read files, never simulate
and never touch pyplot's global state.  `compare.report.report` loads the run, calls these builders in
order and writes the PDF and PNGs. Here: the flights reduced for drawing and the region around them,
the training curves; the flights' own pages are `compare.report.flight_figures`'s, pages of text and
tables `compare.report.layout`'s.

Colours are fixed per pilot (`PILOT_COLORS`, from `compare.flying.pilots`, with a fallback cycle for
unknown pilots) so a pilot looks the same on every page.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ParamSpec, TypeVar

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import is_color_like
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from compare.flying.pilots import PILOTS
from compare.report.layout import PAGE_SIZE_IN
from compare.results.trajectory import EpisodeMeta, SavedEpisode
from uam_fdm.city.buildings import Building, BuildingMap, Prism

PILOT_COLORS: dict[str, str] = {name: entry.color for name, entry in PILOTS.items()}
FALLBACK_COLORS: tuple[str, ...] = ("tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink",
                                    "tab:olive", "tab:cyan", "tab:gray")
MAX_PLOT_POINTS = 2000
CROP_MARGIN_M = 30.0
START_STYLE: dict[str, Any] = {"marker": "^", "color": "tab:green", "markeredgecolor": "k", "markersize": 9,
                               "linestyle": "none"}
GOAL_STYLE: dict[str, Any] = {"marker": "*", "color": "gold", "markeredgecolor": "k", "markersize": 13,
                              "linestyle": "none"}


P = ParamSpec("P")
R = TypeVar("R")


def plain_text(func: Callable[P, R]) -> Callable[P, R]:
    """`func` with matplotlib's mathtext off: every text we draw (labels, descriptions, names from files) is shown
    as written. A '$' in a scenario description or a pilot's label would otherwise be read as mathematics and a
    stray one fail the report after all the flying. The setting is restored on return (`rc_context`)."""
    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with matplotlib.rc_context({"text.parse_math": False}):
            return func(*args, **kwargs)
    return wrapper


def pilot_colors(pilots: Iterable[str], recorded: Mapping[str, str] | None = None) -> dict[str, str]:
    """Colour of each pilot: `PILOT_COLORS` for registered ones, then the colour the run recorded for it
    (`recorded`, from run.json: a plug-in's own) when matplotlib knows it, then `FALLBACK_COLORS` in order.

    Nothing is imported by name: a pilot read from a run folder may be `module:Class`, which a reader must not
    run (the run recorded the plug-in's colour when it flew).
    """
    out: dict[str, str] = {}
    spare = iter(c for c in FALLBACK_COLORS if c not in PILOT_COLORS.values())
    for m in pilots:
        if m in out:
            continue
        own = (recorded or {}).get(m, "")
        out[m] = PILOT_COLORS.get(m) or (own if own and is_color_like(own) else "") or next(spare, "0.3")
    return out


# ---- data reduced for plotting -------------------------------------------------------------------------
@dataclass(frozen=True)
class FlightTrace:
    """One saved episode reduced to at most `MAX_PLOT_POINTS` samples for drawing.

    Attributes:
        episode: the saved episode's metadata (`compare.results.trajectory.EpisodeMeta`).
        label: the pilot's display label; color: its matplotlib colour.
        t_s: (K,) time [s]; pos_m: (K, 3) position, world ENU [m]; speed_m_s: (K,) ground speed [m/s].
        clearance_m: (K,) signed clearance of the collision sphere [m] (the minimum sample is kept).
        rotor_kw: (K,) total rotor shaft power Σ Q_i·Ω_i [kW], the model's at each step as the episode file
            saved it (`Trajectory.shaft_power_W`); None for a file saved before it was recorded.
        rotor_mean_rad_s: (K,) mean rotor speed [rad/s].
        bbox_min_m, bbox_max_m: (3,) extent of the full (not reduced) path with start and goal, ENU [m].
    """

    episode: EpisodeMeta
    label: str
    color: str
    t_s: np.ndarray
    pos_m: np.ndarray
    speed_m_s: np.ndarray
    clearance_m: np.ndarray
    rotor_kw: np.ndarray | None
    rotor_mean_rad_s: np.ndarray
    bbox_min_m: np.ndarray
    bbox_max_m: np.ndarray

    @property
    def pilot(self) -> str:
        return self.episode.key.method

    @property
    def end_t_s(self) -> float:
        return float(self.t_s[-1])


def downsample_indices(n: int, max_points: int = MAX_PLOT_POINTS, keep: Sequence[int] = ()) -> np.ndarray:
    """Sorted sample indices into a length-`n` series: an even stride, the ends and `keep`, ≤ max_points."""
    if n <= max_points:
        return np.arange(n)
    extra = sorted({0, n - 1, *(int(k) for k in keep if 0 <= k < n)})
    stride = math.ceil(n / max(max_points - len(extra), 1))
    return np.unique(np.concatenate([np.arange(0, n, stride), extra]))[:max_points]


def trace_from_episode(ep: SavedEpisode, label: str, color: str,
                       max_points: int = MAX_PLOT_POINTS) -> FlightTrace:
    """Reduce a loaded episode to what the figures draw (keeping the clearance minimum exactly).

    Rows with a non-finite position (an episode that ended "nonfinite") are left out, so the path
    ends where the vehicle was last known.
    """
    meta, tr = ep.meta, ep.trajectory
    x_all = np.asarray(tr.states, float)
    rows = np.flatnonzero(np.all(np.isfinite(x_all[:, 0:3]), axis=1))
    rows = rows if len(rows) else np.arange(min(len(x_all), 1))
    x, t_s = x_all[rows], np.asarray(tr.t_s, float)[rows]
    clear = np.asarray(tr.clearance_m, float)[rows]
    keep = [int(np.nanargmin(clear))] if np.any(np.isfinite(clear)) else []
    idx = downsample_indices(len(rows), max_points, keep)
    rotors = x[idx, 13:13 + meta.n_rotors]
    power = tr.shaft_power_W
    rotor_kw = None if power is None else np.asarray(power, float)[rows][idx] / 1e3
    ends = np.vstack([x[:, 0:3], meta.start_m, meta.goal_m])
    return FlightTrace(
        episode=meta, label=label, color=color, t_s=t_s[idx], pos_m=x[idx, 0:3],
        speed_m_s=np.linalg.norm(x[idx, 3:6], axis=1), clearance_m=clear[idx], rotor_kw=rotor_kw,
        rotor_mean_rad_s=rotors.mean(axis=1) if rotors.shape[1] else np.full(len(idx), np.nan),
        bbox_min_m=ends.min(axis=0), bbox_max_m=ends.max(axis=0))


# reward_curve.csv columns beyond timesteps, mean_episode_reward and success_rate (rl.training.loop.CURVE_COLUMNS)
CURVE_FIELDS: tuple[str, ...] = ("train_success_rate", "train_collision_rate", "train_timeout_rate",
                                 "train_episodes", "difficulty", "collision_rate", "eval_episodes", "wall_s")
SMOOTH_FRACTION = 0.02


@dataclass(frozen=True)
class RewardCurve:
    """PPO training progress, one entry per PPO update (a policy folder's `reward_curve.csv`).

    All arrays have shape (N,); NaN marks a value the row does not have (an update in which no
    training episode ended, a row without a validation evaluation, or a column an older file lacks).

    Attributes:
        timesteps: training timesteps (decisions, all vehicles) at the end of the update.
        mean_episode_reward: mean raw return of the training episodes that ended in the update.
        success_rate: held-out validation success rate (fraction), on rows where an evaluation ran.
        train_success_rate, train_collision_rate, train_timeout_rate: outcome fractions of those
            training episodes; train_episodes: how many ended.
        difficulty: the curriculum's task difficulty in (0, 1] during the update.
        collision_rate: validation collision rate (fraction); eval_episodes: validation episodes.
        wall_s: wall time since the run started [s].
    """

    timesteps: np.ndarray
    mean_episode_reward: np.ndarray
    success_rate: np.ndarray
    train_success_rate: np.ndarray | None = None
    train_collision_rate: np.ndarray | None = None
    train_timeout_rate: np.ndarray | None = None
    train_episodes: np.ndarray | None = None
    difficulty: np.ndarray | None = None
    collision_rate: np.ndarray | None = None
    eval_episodes: np.ndarray | None = None
    wall_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.timesteps)
        for name in ("timesteps", "mean_episode_reward", "success_rate", *CURVE_FIELDS):
            v = getattr(self, name)
            arr = np.full(n, np.nan) if v is None else np.asarray(v, dtype=float).reshape(-1)
            if len(arr) != n:
                raise ValueError(f"RewardCurve.{name} has {len(arr)} entries, timesteps {n}")
            object.__setattr__(self, name, arr)

    @property
    def has_validation(self) -> np.ndarray:
        """(N,) bool: rows with a validation success rate."""
        return np.isfinite(self.success_rate)

    def smoothed(self, name: str = "mean_episode_reward", fraction: float = SMOOTH_FRACTION) -> np.ndarray:
        """`moving_average` of one column over `smoothing_window(len, fraction)` updates."""
        return moving_average(getattr(self, name), smoothing_window(len(self.timesteps), fraction))


def smoothing_window(n: int, fraction: float = SMOOTH_FRACTION) -> int:
    """Window of the training-curve moving average: `fraction` of the n updates, odd, at least 1."""
    w = max(1, int(round(fraction * n)))
    return w + 1 - w % 2


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average over `window` entries (odd), ignoring NaN.

    Each entry becomes the mean of the finite values among itself and its (window - 1) / 2
    neighbours on each side; near the ends the window is cut short (fewer neighbours, never
    padded). An entry with no finite value in its window stays NaN.
    """
    v = np.asarray(values, dtype=float)
    half = max(int(window), 1) // 2
    ok = np.isfinite(v)
    csum = np.concatenate([[0.0], np.cumsum(np.where(ok, v, 0.0))])
    ccount = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(len(v))
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, len(v))
    count = ccount[hi] - ccount[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (csum[hi] - csum[lo]) / np.maximum(count, 1), np.nan)


def curriculum_stages(curve: RewardCurve) -> list[tuple[float, float, float]]:
    """(start, end, difficulty) of each run of updates at one curriculum difficulty, in order.

    A stage starts where the previous one's last update ended (the first at timestep 0) and ends at
    its own last update, so the stages tile the run. Empty when the curve has no difficulty column.
    """
    d, t = curve.difficulty, curve.timesteps
    assert d is not None  # __post_init__ fills a missing column with NaN
    stages: list[tuple[float, float, float]] = []
    for i in np.flatnonzero(np.isfinite(d) & np.isfinite(t)):
        if stages and abs(stages[-1][2] - d[i]) < 1e-9:
            stages[-1] = (stages[-1][0], float(t[i]), stages[-1][2])
        else:
            start = stages[-1][1] if stages else min(0.0, float(t[i]))
            stages.append((start, float(t[i]), float(d[i])))
    return stages


# ---- the region around some flights ---------------------------------------------------------------------
def flight_region(traces: Sequence[FlightTrace],
                  margin_m: float = CROP_MARGIN_M) -> tuple[np.ndarray, np.ndarray]:
    """Box around the traces (with start and goal) plus `margin_m`, from the ground up: (lo, hi) ENU [m]."""
    lo = np.min([t.bbox_min_m for t in traces], axis=0) - margin_m
    hi = np.max([t.bbox_max_m for t in traces], axis=0) + margin_m
    lo[2] = 0.0
    return lo, np.maximum(hi, lo + 1.0)


def crop_map(bmap: BuildingMap, lo_m: np.ndarray, hi_m: np.ndarray) -> BuildingMap:
    """The part of `bmap` inside the box [lo, hi] in x/y: footprints clipped to it (prisms), bounds = the box.

    Buildings keep their full height (the z extent of the drawing grows to show them). A raised box (a crane's jib)
    is kept whole where it lies inside the box and left out where it crosses its edge (a clipped part could only
    stand on the ground, and a jib drawn as a wall would mislead).
    """
    parts: list[Building | Prism] = []
    for b in bmap.buildings:
        if isinstance(b, Building) and b.base_m > 0.0:
            fp = b.footprint_xy_m()
            if np.all(fp >= lo_m[:2]) and np.all(fp <= hi_m[:2]):
                parts.append(b)
            continue
        poly = _clip_to_rect(b.footprint_xy_m(), lo_m[:2], hi_m[:2])
        if len(poly) >= 3 and _area(poly) > 1e-2:
            parts.append(Prism(b.id, tuple(map(tuple, poly)), b.height_m))
    return BuildingMap(parts, lo_m, hi_m, bmap.no_fly, name=bmap.name)


def _clip_to_rect(poly: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clipping of a convex counter-clockwise polygon to an axis-aligned rectangle."""
    out = [tuple(p) for p in poly]
    for axis, bound, keep_below in ((0, lo[0], False), (0, hi[0], True), (1, lo[1], False), (1, hi[1], True)):
        src, out = out, []
        if not src:
            break
        for i, cur in enumerate(src):
            prev = src[i - 1]
            cur_in = cur[axis] <= bound if keep_below else cur[axis] >= bound
            prev_in = prev[axis] <= bound if keep_below else prev[axis] >= bound
            if cur_in != prev_in:
                f = (bound - prev[axis]) / (cur[axis] - prev[axis])
                out.append((prev[0] + f * (cur[0] - prev[0]), prev[1] + f * (cur[1] - prev[1])))
            if cur_in:
                out.append(cur)
    pts = np.array(out, float).reshape(-1, 2)
    if len(pts):  # drop repeated vertices left where an edge was cut exactly at a corner
        pts = pts[np.r_[True, np.any(np.abs(np.diff(pts, axis=0)) > 1e-9, axis=1)]]
        if len(pts) > 1 and np.all(np.abs(pts[0] - pts[-1]) <= 1e-9):
            pts = pts[:-1]
    return pts


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


# ---- training ------------------------------------------------------------------------------------------
RETURN_COLOR = "tab:orange"
SUCCESS_COLOR = "tab:blue"
KEPT_COLOR = "tab:green"
STAGE_LABEL_PT = 10.0  # height of a row of curriculum-stage labels [points]


def _pct(rate: np.ndarray) -> np.ndarray:
    """Rates as percentages (a column already in percent, i.e. above 1 somewhere, is left as is)."""
    ok = np.isfinite(rate)
    return rate * 100.0 if not np.any(ok) or np.nanmax(rate[ok]) <= 1.0 else rate


def _draw_stages(ax: Axes, curve: RewardCurve) -> int:
    """Curriculum stages: faint bands (darker for easier stages, none at full difficulty) and "difficulty d"
    above the axes at each stage's start.

    Labels of stages too short to hold them are stacked; returns the number of label rows (0: no
    curriculum to mark, i.e. one stage at full difficulty).
    """
    stages = curriculum_stages(curve)
    if len(stages) < 2 and not (stages and stages[0][2] < 1.0):
        return 0
    x_end = max(s[1] for s in stages) / 1e6
    prev_frac, level, rows = -1.0, 0, 1
    for k, (start, end, d) in enumerate(stages):
        x0, x1 = start / 1e6, end / 1e6
        if d < 1.0:  # easier stages darker; full difficulty unshaded
            ax.axvspan(x0, x1, color="0.5", alpha=0.03 + 0.1 * (1.0 - d), lw=0, zorder=0)
        if k:
            ax.axvline(x0, color="0.55", lw=0.6, ls=":", zorder=0.5)
        frac = x0 / x_end if x_end > 0 else 0.0
        level = level + 1 if k and frac - prev_frac < 0.1 else 0
        prev_frac = frac if level == 0 else prev_frac
        rows = max(rows, level + 1)
        ax.annotate(f"difficulty {d:.2f}", (x0, 1.0), xycoords=ax.get_xaxis_transform(),
                    xytext=(2, 2 + STAGE_LABEL_PT * level), textcoords="offset points", fontsize=7.5,
                    color="0.35", ha="left", va="bottom", annotation_clip=False)
    return rows


def _draw_return(ax: Axes, curve: RewardCurve, x: np.ndarray, window: int, smooth_fraction: float) -> list:
    """The training return per update (faint) and its moving average over `window` updates, against x [M
    timesteps]; returns the legend handles."""
    handles: list = []
    raw = np.isfinite(curve.mean_episode_reward)
    if np.any(raw):
        if window == 1:  # too few rows to smooth (e.g. an older file with a row per evaluation only)
            handles += ax.plot(x[raw], curve.mean_episode_reward[raw], color=RETURN_COLOR, lw=1.8, marker=".",
                               label="training return (not smoothed: too few rows)")
        else:
            handles += ax.plot(x[raw], curve.mean_episode_reward[raw], color=RETURN_COLOR, lw=0.7, alpha=0.35,
                               label="training return, per update")
            smooth = moving_average(curve.mean_episode_reward, window)
            ok = np.isfinite(smooth)
            handles += ax.plot(x[ok], smooth[ok], color=RETURN_COLOR, lw=2.2,
                               label=f"training return, moving average ({window} updates ≈ "
                                     f"{100 * smooth_fraction:g} % of the run)")
        if np.nanmin(curve.mean_episode_reward) < 0 < np.nanmax(curve.mean_episode_reward):
            ax.axhline(0.0, color="0.6", lw=0.6, zorder=0.5)
    ax.set_xlabel("training timesteps [millions of decisions, all vehicles together]")
    ax.set_ylabel("training return per episode (mean over each update) [-]", color="#b35900")
    ax.grid(alpha=0.3)
    ax.set_xlim(min(0.0, float(np.nanmin(x))), float(np.nanmax(x)) * 1.01 if np.nanmax(x) > 0 else 1.0)
    return handles


def _draw_success_rates(ax2: Axes, curve: RewardCurve, x: np.ndarray, window: int) -> list:
    """The training success rate (moving average over `window` updates) and the validation success rate
    (markers), in percent, against x [M timesteps]; returns the legend handles."""
    handles: list = []
    ax2.set_ylim(-2.0, 102.0)
    ax2.set_ylabel("success rate [%]", color=SUCCESS_COLOR)
    train_rate = curve.train_success_rate
    assert train_rate is not None  # RewardCurve.__post_init__ fills an absent column with NaN
    train_ok = np.isfinite(train_rate)
    if np.any(train_ok):
        ts = moving_average(_pct(train_rate), window)
        ok = np.isfinite(ts)
        handles += ax2.plot(x[ok], ts[ok], color=SUCCESS_COLOR, lw=1.0, alpha=0.6,
                            label="training success rate, moving average (at the curriculum's difficulty)")
    val = curve.has_validation
    if np.any(val):
        handles += ax2.plot(x[val], _pct(curve.success_rate)[val], color=SUCCESS_COLOR, marker="o", ms=4.5,
                            lw=1.5, markeredgecolor="white", markeredgewidth=0.6,
                            label="validation success rate (held-out cities, full difficulty)")
    return handles


def reward_curve_figure(title: str, curve: RewardCurve | None, note: str = "",
                        kept_timesteps: float | None = None, subtitle: str = "",
                        smooth_fraction: float = SMOOTH_FRACTION) -> Figure:
    """PPO's own training return rising and levelling off, with success rates, against timesteps [millions].

    Left axis: the mean return of the training episodes that ended in each PPO update (faint) and its
    centred moving average over `smooth_fraction` of the updates (`smoothing_window`, `moving_average`).
    Right axis [%]: held-out validation success (markers, only rows with an evaluation) and the
    training episodes' success rate (moving average, thinner). Curriculum stages are banded and
    labelled "difficulty d" above the axes; `kept_timesteps` marks the checkpoint the policy folder
    ships (a run may keep an earlier checkpoint than its last).

    Args:
        title: page title; subtitle: what was trained and on what (first line under it).
        curve: the curve; None draws a page stating `note` (why there is no curve).
        note: the curve's source and run facts (second line), or the reason there is no curve.
    """
    fig = Figure(figsize=PAGE_SIZE_IN, layout="constrained")
    fig.suptitle(title, fontsize=15, fontweight="bold")
    if curve is None or not np.any(np.isfinite(curve.timesteps)):
        fig.text(0.5, 0.5, note or "No reward curve available.", ha="center", va="center", fontsize=12,
                 wrap=True)
        return fig
    ax = fig.add_subplot(1, 1, 1)
    ax2 = ax.twinx()  # success rates; drawn below `ax` (see the end), so it holds the stage bands too
    x = curve.timesteps / 1e6
    window = smoothing_window(len(x), smooth_fraction)
    stage_rows = _draw_stages(ax2, curve)
    handles = _draw_return(ax, curve, x, window, smooth_fraction) + _draw_success_rates(ax2, curve, x, window)
    if kept_timesteps is not None:
        handles.append(ax.axvline(kept_timesteps / 1e6, color=KEPT_COLOR, ls="--", lw=1.3,
                                  label=f"kept checkpoint ({kept_timesteps / 1e6:.2f} M timesteps)"))
    if stage_rows:
        handles.append(Rectangle((0, 0), 1, 1, color="0.5", alpha=0.15,
                                 label="curriculum stages below full difficulty (shorter legs; darker: easier)"))
    ax.set_zorder(ax2.get_zorder() + 1)  # the return lines over the success lines, ...
    ax.patch.set_visible(False)          # ... without hiding them
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=9, frameon=False)
    head = "\n".join(t for t in (subtitle, note) if t)
    if head:
        ax.set_title(head, fontsize=9.5, pad=8 + STAGE_LABEL_PT * stage_rows)
    return fig


SEED_GRID_POINTS = 400


def _common_grid(series: Sequence[tuple[np.ndarray, np.ndarray]], points: int = SEED_GRID_POINTS
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """(grid, values (series, points)): each non-empty (x, y) series interpolated linearly on an even grid over
    the x range every one of them covers; None when all are empty or they share no range."""
    usable = [(x, y) for x, y in series if len(x)]
    if not usable:
        return None
    lo, hi = max(float(x[0]) for x, _ in usable), min(float(x[-1]) for x, _ in usable)
    if not hi > lo:
        return None
    grid = np.linspace(lo, hi, points)
    return grid, np.array([np.interp(grid, x, y) for x, y in usable])


def _finite_series(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(x) & np.isfinite(y)
    order = np.argsort(x[ok], kind="stable")
    return x[ok][order], y[ok][order]


def seed_curves_figure(curves: Sequence[RewardCurve], labels: Sequence[str], *,
                       title: str = "Learned pilot: plain PPO from scratch across seeds",
                       smooth_fraction: float = SMOOTH_FRACTION) -> Figure:
    """Training runs of several seeds: (a) the smoothed training return, (b) the validation success rate.

    Each seed is a thin line; the thick line is the mean across seeds and the band spans the minimum
    to the maximum, both on a common grid of timesteps (each seed's curve interpolated linearly; the
    grid covers the range every seed covers). The return is each seed's centred moving average over
    `smooth_fraction` of its updates (`RewardCurve.smoothed`); the validation success rate is taken
    at the rows where a validation evaluation ran.

    Args:
        curves: one `RewardCurve` per seed; labels: their legend labels (same length).

    Raises:
        ValueError: no curves, or labels of another length.
    """
    if not curves:
        raise ValueError("seed_curves_figure needs at least one curve")
    if len(labels) != len(curves):
        raise ValueError(f"{len(curves)} curves but {len(labels)} labels")
    fig = Figure(figsize=(12.0, 5.2), layout="constrained")
    fig.suptitle(title, fontsize=14, fontweight="bold")
    ax_r, ax_s = fig.subplots(1, 2)
    palette = FALLBACK_COLORS  # not the mean lines' orange and blue
    returns = [_finite_series(c.timesteps / 1e6, c.smoothed("mean_episode_reward", smooth_fraction)) for c in curves]
    success = [_finite_series(c.timesteps / 1e6, _pct(c.success_rate)) for c in curves]
    panels = ((ax_r, RETURN_COLOR, returns), (ax_s, SUCCESS_COLOR, success))
    for ax, color, series in panels:
        for k, ((x, y), label) in enumerate(zip(series, labels, strict=True)):
            if len(x):
                ax.plot(x, y, color=palette[k % len(palette)], lw=0.9, alpha=0.75, label=label,
                        marker="." if ax is ax_s else None, ms=3)
        common = _common_grid(series)
        if common is not None:
            grid, values = common
            n = len(values)
            seeds = f"{n} seed{'s' if n > 1 else ''}"
            ax.fill_between(grid, values.min(axis=0), values.max(axis=0), color=color, alpha=0.18, lw=0,
                            label=f"min–max across {seeds}")
            ax.plot(grid, values.mean(axis=0), color=color, lw=2.4, label=f"mean of {seeds}")
        else:
            ax.text(0.5, 0.5, "no range common to the seeds", transform=ax.transAxes, ha="center", color="0.4")
        ax.set_xlabel("training timesteps [millions]")
        ax.grid(alpha=0.3)
        ax.set_xlim(left=0.0)
    ax_r.set_ylabel("training return per episode [-]")
    ax_r.set_title(f"(a) training return, moving average over {100 * smooth_fraction:g} % of the updates",
                   fontsize=10)
    ax_s.set_ylabel("validation success rate [%]")
    ax_s.set_ylim(-2.0, 102.0)
    ax_s.set_title("(b) success on held-out validation cities (full difficulty)", fontsize=10)
    ax_r.legend(fontsize=8, loc="lower right")
    ax_s.legend(fontsize=8, loc="lower right")
    return fig
