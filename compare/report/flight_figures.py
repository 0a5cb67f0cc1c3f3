"""Figures of flights: each task's paths (3D and top-down), its time series and its 3D snapshots, and the failures.

Builders take `FlightTrace`s (`compare.report.figures`) and the scenario's city, and return A4-landscape Figures.

A static 3D view must not show a pilot flying through a building. matplotlib's 3D axes sort whole artists, not
the pieces of a line against the faces of a box, so a path drawn after the city lies on top of every building,
and one drawn before it under every building. Here the views are orthographic, so that every point is seen along
one direction, and each sample of a path is tested for a building between it and the viewer (a ray towards the
viewer against the buildings drawn: `uam_fdm.sensing.raycast.RayCaster`, exact). Where the path is seen it is
drawn solid, over the city; where a building stands in front of it, it is drawn thin and dotted, the hidden-line
convention of technical drawing, and the legend says so. The top-down view beside the 3D one shows every path
whole.
"""
from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Rectangle
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d import Axes3D

from compare.report.figures import GOAL_STYLE, PAGE_SIZE_IN, START_STYLE, FlightTrace, crop_map, flight_region
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.plot import draw_map_3d, draw_map_topdown
from uam_fdm.episode import Outcome
from uam_fdm.sensing.raycast import RayCaster

VIEW_ELEV_DEG = 35.0
VIEW_AZIM_DEG = -60.0
"""The 3D views' viewpoint: elevation above the horizon and azimuth (matplotlib's convention) [deg]."""
RAY_START_M = 0.05
"""A ray towards the viewer starts this far along it [m], off the surface a point may lie on."""
HIDDEN_STYLE: dict[str, Any] = {"ls": ":", "lw": 1.0, "alpha": 0.7}
HIDDEN_LABEL = "dotted: behind a building from this viewpoint"


# ---- what the viewer sees -----------------------------------------------------------------------------------
def toward_viewer(elev_deg: float = VIEW_ELEV_DEG, azim_deg: float = VIEW_AZIM_DEG) -> np.ndarray:
    """Unit vector from the scene towards the viewer of an orthographic 3D axes at this viewpoint, world ENU.

    Exact for axes drawn at true scale (equal metres per unit on x, y and z), as these figures are.
    """
    e, a = math.radians(elev_deg), math.radians(azim_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


class Occlusion:
    """Which points a building hides from the viewer of a 3D view of `city` (the buildings drawn).

    Args:
        city: the buildings drawn (None: nothing hides anything).
        elev_deg, azim_deg: the viewpoint.
    """

    def __init__(self, city: BuildingMap | None, elev_deg: float = VIEW_ELEV_DEG,
                 azim_deg: float = VIEW_AZIM_DEG) -> None:
        self._caster = RayCaster(city, ground=False) if city is not None and city.buildings else None
        self.direction = toward_viewer(elev_deg, azim_deg)

    def hidden(self, points_m: np.ndarray) -> np.ndarray:
        """(K,) bool: a building stands between each of the (K, 3) points (world ENU [m]) and the viewer."""
        p = np.asarray(points_m, float).reshape(-1, 3)
        if self._caster is None or not len(p):
            return np.zeros(len(p), dtype=bool)
        ok = np.all(np.isfinite(p), axis=1)
        out = np.zeros(len(p), dtype=bool)
        if np.any(ok):
            d = np.tile(self.direction, (int(ok.sum()), 1))
            out[ok] = self._caster.hits_any(p[ok] + RAY_START_M * self.direction, d)
        return out


def draw_path_3d(ax: Axes3D, pos_m: np.ndarray, hidden: np.ndarray, color: str, lw: float) -> None:
    """A path drawn solid where it is seen and dotted where a building hides it (drawn after the city).

    Args:
        pos_m: (K, 3) positions, world ENU [m]. hidden: (K,) bool (`Occlusion.hidden`).
    """
    p = np.asarray(pos_m, float)
    if len(p) == 1:
        return
    seen_seg = ~(hidden[:-1] | hidden[1:])           # a segment is seen when both its ends are
    seen = np.zeros(len(p), dtype=bool)
    seen[:-1] |= seen_seg
    seen[1:] |= seen_seg
    shade = np.zeros(len(p), dtype=bool)             # the rest, each piece with its ends, so the two meet
    shade[:-1] |= ~seen_seg
    shade[1:] |= ~seen_seg
    for mask, style in ((shade, {**HIDDEN_STYLE, "lw": 0.8 * lw}), (seen, {"lw": lw})):
        if np.any(mask):
            q = np.where(mask[:, None], p, np.nan)  # NaN breaks the line between the runs
            ax.plot(q[:, 0], q[:, 1], q[:, 2], color=color, **style)


def _marker_3d(ax: Axes3D, point: np.ndarray | Sequence[float], occlusion: Occlusion, **style: Any) -> None:
    """A marker, faint where a building hides it."""
    faint = bool(occlusion.hidden(np.asarray(point, float)[None, :])[0])
    ax.plot(*np.asarray(point, float), **style, alpha=0.35 if faint else 1.0)


# ---- the city -----------------------------------------------------------------------------------------------
def _draw_city_3d(ax: Axes3D, region_map: BuildingMap | None, lo: np.ndarray, hi: np.ndarray) -> None:
    """The buildings of the region (or an empty box) at true scale, orthographic, from the report's viewpoint."""
    ax.computed_zorder = False  # drawn in order: the city first, the paths over it where they are seen
    if region_map is not None:
        draw_map_3d(ax, region_map)
    else:
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(0.0, hi[2])
        ax.set_xlabel("x east [m]")
        ax.set_ylabel("y north [m]")
        ax.set_zlabel("z up [m]")
    spans = [abs(b - a) for a, b in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    ax.set_box_aspect(spans, zoom=0.88)  # true scale: the viewer's direction is the same in metres
    ax.set_proj_type("ortho")
    ax.view_init(elev=VIEW_ELEV_DEG, azim=VIEW_AZIM_DEG)


def _draw_city_topdown(ax: Axes, region_map: BuildingMap | None, full_map: BuildingMap | None,
                       lo: np.ndarray, hi: np.ndarray) -> None:
    if region_map is not None:
        coll = draw_map_topdown(ax, region_map, show_bounds=False)
        ax.figure.colorbar(coll, ax=ax, label="building height [m]", shrink=0.7)
    if full_map is not None:  # the real flight-volume bounds, where they cross the view
        blo, bhi = full_map.bounds_min_m, full_map.bounds_max_m
        ax.add_patch(Rectangle((blo[0], blo[1]), bhi[0] - blo[0], bhi[1] - blo[1], fill=False, ls="--",
                               lw=0.8, ec="0.4"))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")


def _trace_legend(t: FlightTrace) -> str:
    return f"{t.label}: {t.episode.outcome}, {t.end_t_s:.1f} s"


# ---- the pages ----------------------------------------------------------------------------------------------
def episode_paths_figure(title: str, traces: Sequence[FlightTrace], bmap: BuildingMap | None) -> Figure:
    """3D view of the city around the flights (left; paths dotted where a building hides them) and a top-down
    view (right), every pilot's path.

    Args:
        title: page title, e.g. "Episode suburb-quad #0 seed 0".
        traces: one per pilot, all of the same task.
        bmap: the scenario's city (None: draw the paths alone).
    """
    lo, hi = flight_region(traces)
    region = crop_map(bmap, lo, hi) if bmap is not None else None
    occlusion = Occlusion(region)
    meta = traces[0].episode
    fig = Figure(figsize=PAGE_SIZE_IN)
    fig.suptitle(title, fontsize=15, fontweight="bold", y=0.97)
    # fixed panels: a 3D axes' z label reaches past its box, which a layout engine does not see
    ax3 = fig.add_axes((0.0, 0.1, 0.53, 0.82), projection="3d")
    _draw_city_3d(ax3, region, lo, hi)
    ax2 = fig.add_axes((0.63, 0.16, 0.34, 0.7))
    _draw_city_topdown(ax2, region, bmap, lo, hi)
    ax2.add_patch(Circle(meta.goal_m[:2], meta.goal_radius_m, fill=False, ec="k", lw=0.8, ls=":"))
    any_hidden = False
    for t in traces:
        p = t.pos_m
        hidden = occlusion.hidden(p)
        any_hidden |= bool(np.any(hidden))
        draw_path_3d(ax3, p, hidden, t.color, 1.8)
        ax2.plot(p[:, 0], p[:, 1], color=t.color, lw=1.8, label=_trace_legend(t))
        end = "o" if t.episode.outcome == Outcome.SUCCESS else "X"
        _marker_3d(ax3, p[-1], occlusion, marker=end, color=t.color, markeredgecolor="k", markersize=8,
                   linestyle="none")
        ax2.plot(*p[-1, :2], marker=end, color=t.color, markeredgecolor="k", markersize=8, linestyle="none")
    s, g = np.asarray(meta.start_m), np.asarray(meta.goal_m)
    _marker_3d(ax3, s, occlusion, **START_STYLE)
    _marker_3d(ax3, g, occlusion, **GOAL_STYLE)
    ax2.plot(*s[:2], **START_STYLE, label="start")
    ax2.plot(*g[:2], **GOAL_STYLE, label=f"goal (radius {meta.goal_radius_m:g} m)")
    ax3.set_title("3D view (true scale" + ("; dotted where a building hides the path)" if any_hidden else ")"))
    ax2.set_title("top-down view")
    handles, labels = ax2.get_legend_handles_labels()
    if any_hidden:
        handles.append(Line2D([], [], color="0.3", **HIDDEN_STYLE))
        labels.append(HIDDEN_LABEL)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(handles), 4), fontsize=9)
    return fig


def episode_timeseries_figure(title: str, traces: Sequence[FlightTrace]) -> Figure:
    """Clearance (with contact and 2 m / 5 m margins), speed and rotor power (or mean rotor speed) over time.

    Rotor shaft power (the model's, saved per step in the episode file) is drawn only when every trace has
    it; otherwise (an episode file saved before it was recorded) all show mean rotor speed, and the panel
    says why.
    """
    fig = Figure(figsize=PAGE_SIZE_IN, layout="constrained")
    fig.suptitle(title, fontsize=15, fontweight="bold")
    ax_c, ax_v, ax_p = fig.subplots(3, 1, sharex=True)
    power = all(t.rotor_kw is not None for t in traces)
    radius = traces[0].episode.collision_radius_m
    ax_c.axhline(0.0, color="tab:red", lw=1.2,
                 label=f"contact (collision sphere radius {radius:g} m)")
    for margin in (2.0, 5.0):
        ax_c.axhline(margin, color="0.35", lw=0.9, ls="--", label=f"{margin:g} m margin")
    for t in traces:
        ax_c.plot(t.t_s, t.clearance_m, color=t.color, lw=1.3, label=t.label)
        ax_v.plot(t.t_s, t.speed_m_s, color=t.color, lw=1.3, label=t.label)
        ax_p.plot(t.t_s, t.rotor_kw if power else t.rotor_mean_rad_s, color=t.color, lw=1.1, label=t.label)
    ax_c.set_ylabel("clearance [m]")
    ax_c.set_title("clearance of the collision sphere to buildings and ground", fontsize=10)
    ax_c.legend(loc="upper right", fontsize=8, ncol=2)
    ax_v.set_ylabel("speed [m/s]")
    ax_v.set_title("ground speed", fontsize=10)
    ax_p.set_ylabel("rotor power [kW]" if power else "mean rotor speed [rad/s]")
    ax_p.set_title("total rotor shaft power Σ Q·Ω (the flight model's, per step)" if power
                   else "mean rotor speed (shaft power not in this episode file: saved before it was recorded)",
                   fontsize=10)
    ax_p.set_xlabel("time [s]")
    for ax in (ax_c, ax_v, ax_p):
        ax.grid(alpha=0.3)
    return fig


def episode_snapshots_figure(title: str, traces: Sequence[FlightTrace], bmap: BuildingMap | None,
                             n_panels: int = 9) -> Figure:
    """3D snapshots at t = 0, T/(n-1), …, T (T = the longer flight): vehicles as markers with trails so far,
    dotted (and the marker faint) where a building hides them.

    A vehicle whose flight ended before a snapshot stays where it ended (an "X" if it failed).
    """
    lo, hi = flight_region(traces)
    region = crop_map(bmap, lo, hi) if bmap is not None else None
    occlusion = Occlusion(region)
    hidden = [occlusion.hidden(t.pos_m) for t in traces]
    t_end = max(t.end_t_s for t in traces)
    meta = traces[0].episode
    fig = Figure(figsize=PAGE_SIZE_IN)
    fig.suptitle(title, fontsize=15, fontweight="bold", y=0.985)
    fig.subplots_adjust(left=0.0, right=0.97, bottom=0.08, top=0.92, wspace=0.02, hspace=0.14)
    cols = math.ceil(math.sqrt(n_panels))
    rows = math.ceil(n_panels / cols)
    for k in range(n_panels):
        when = t_end * k / max(n_panels - 1, 1)
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d")
        _draw_city_3d(ax, region, lo, hi)
        spans = [abs(b - a) for a, b in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
        ax.set_box_aspect(spans, zoom=1.05)  # true scale as drawn, a little larger in the small panels
        _marker_3d(ax, meta.start_m, occlusion, **{**START_STYLE, "markersize": 6})
        _marker_3d(ax, meta.goal_m, occlusion, **{**GOAL_STYLE, "markersize": 9})
        for t, hid in zip(traces, hidden):
            i = max(int(np.searchsorted(t.t_s, when, side="right")) - 1, 0)
            ended = when > t.end_t_s and t.episode.outcome != Outcome.SUCCESS
            draw_path_3d(ax, t.pos_m[:i + 1], hid[:i + 1], t.color, 1.2)
            ax.plot(*t.pos_m[i], marker="X" if ended else "o", color=t.color, markeredgecolor="k",
                    markersize=6, linestyle="none", alpha=0.35 if hid[i] else 1.0)
        ax.set_title(f"t = {when:.1f} s", fontsize=9)
        ax.tick_params(labelsize=5.5, pad=0)
        ax.zaxis.set_major_locator(MaxNLocator(2))  # the true-scale z axis is short in a small panel
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.label.set_size(6.5)
            axis.labelpad = -2
    handles = [Line2D([], [], color=t.color, marker="o", markeredgecolor="k", label=t.label) for t in traces]
    handles += [Line2D([], [], **START_STYLE, label="start"), Line2D([], [], **GOAL_STYLE, label="goal")]
    if any(np.any(h) for h in hidden):
        handles.append(Line2D([], [], color="0.3", **HIDDEN_STYLE, label=HIDDEN_LABEL))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=9, bbox_to_anchor=(0.5, 0.035))
    return fig


def failure_paths_figure(title: str, items: Sequence[tuple[FlightTrace, BuildingMap | None]]) -> Figure:
    """Small top-down views of failed flights (up to 6): the path, start, goal and where it ended."""
    fig = Figure(figsize=PAGE_SIZE_IN, layout="constrained")
    fig.suptitle(title, fontsize=15, fontweight="bold")
    n = len(items)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    for k, (t, bmap) in enumerate(items):
        ax = fig.add_subplot(rows, cols, k + 1)
        lo, hi = flight_region([t])
        region = crop_map(bmap, lo, hi) if bmap is not None else None
        if region is not None:
            draw_map_topdown(ax, region, show_bounds=False)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x east [m]")
        ax.set_ylabel("y north [m]")
        m = t.episode
        ax.plot(t.pos_m[:, 0], t.pos_m[:, 1], color=t.color, lw=1.5, label=t.label)
        ax.plot(*np.asarray(m.start_m)[:2], **START_STYLE, label="start")
        ax.plot(*np.asarray(m.goal_m)[:2], **GOAL_STYLE, label="goal")
        ax.plot(*t.pos_m[-1, :2], marker="X", color="tab:red", markeredgecolor="k", markersize=10,
                linestyle="none", label=f"ended: {m.outcome} at {t.end_t_s:.1f} s")
        k_ = m.key
        ax.set_title("\n".join(textwrap.wrap(f"{k_.scenario} #{k_.episode} seed {k_.seed}: {t.label}", 48)),
                     fontsize=9)  # a third of the page wide
        ax.legend(fontsize=7, loc="best")
    return fig
