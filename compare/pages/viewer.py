"""The interactive viewer of a run: one self-contained HTML file (`RUN_DIR/viewer.html`).

The page holds everything it needs: plotly.js (from the installed `plotly` package), the viewer's
own script and style (`compare/pages/viewer_assets/`), and the run's flights as JSON. It opens from disk
with no network. Per comparison cell (chosen in a list) it shows the city cropped to the flights in
3D (plotly `Mesh3d`, coloured by height), every pilot's path, and a time slider with a play button
that moves the vehicles along them; hovering a path or a vehicle reads out time, speed and clearance,
and a panel beside the plot reads them out for the slider's time.

Plotly figures are built here through `plotly.graph_objects` (validated); the script only switches
figures (`Plotly.react`) and moves the trail and vehicle traces (`Plotly.restyle`).
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Collection
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import IO

import numpy as np
import plotly
import plotly.graph_objects as go
import plotly.io as pio
from matplotlib import colormaps
from matplotlib.colors import to_hex

from compare.pages.embed import code_for_script, json_for_script, text_for_html
from compare.playback.flights import FlightGroup, flight_groups, sample_flight
from compare.results.run_info import WindInfo, read_run_info
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.files.atomic import atomic_open

VIEWER_NAME = "viewer.html"
START_COLOR, GOAL_COLOR = "#2ca02c", "#ffd700"
UNMAPPED_COLOR = "#e4572e"  # obstacles the prior map lacks: one colour of their own, not the height scale
LIDAR_COLOR = "#17becf"
_BUILDING_SCALE = [[i / 8, to_hex(colormaps["viridis"](0.15 + 0.75 * i / 8))] for i in range(9)]


@dataclass(frozen=True)
class ViewerConfig:
    """What the page holds: `max_samples` time samples per cell (the slider's steps) at most, positions rounded
    to `round_m` [m] and times to `round_s` [s] (small files, no visible loss)."""

    max_samples: int = 1200
    min_step_s: float = 0.02
    round_m: float = 0.01
    round_s: float = 0.001


def building_mesh(bmap: BuildingMap, skip: frozenset[int] = frozenset(), only: frozenset[int] | None = None,
                  color: str | None = None, name: str = "buildings") -> go.Mesh3d:
    """The buildings of `bmap` as one `Mesh3d` (ENU metres): fan-triangulated roofs and two triangles per wall.

    Vertices carry (building id, height) as customdata for the hover text; colour is by height, or `color` for all.
    `skip`: ids left out; `only`: the ids drawn (None: all). A raised box (a crane's jib) starts at its base.
    """
    xs: list[float] = []
    ys, zs, ii, jj, kk, ids, heights = [], [], [], [], [], [], []
    for b in bmap.buildings:
        if b.id in skip or (only is not None and b.id not in only):
            continue
        fp = b.footprint_xy_m()
        n, base = len(fp), len(xs)
        for z in (getattr(b, "base_m", 0.0), b.height_m):
            xs += fp[:, 0].tolist()
            ys += fp[:, 1].tolist()
            zs += [z] * n
        ids += [b.id] * 2 * n
        heights += [b.height_m] * 2 * n
        for v in range(1, n - 1):  # roof: footprints are convex (city.Prism), so a fan is exact
            ii.append(base + n)
            jj.append(base + n + v)
            kk.append(base + n + v + 1)
        for v in range(n):
            w = (v + 1) % n
            ii += [base + v, base + v]  # the wall's quad (v, w, w', v') as (v, w, w') and (v, w', v')
            jj += [base + w, base + n + w]
            kk += [base + n + w, base + n + v]
    top = max(heights, default=1.0)
    scale = _BUILDING_SCALE if color is None else [[0.0, color], [1.0, color]]
    what = "building" if color is None else "unmapped"
    return go.Mesh3d(
        x=rounded(xs, 0.01), y=rounded(ys, 0.01), z=rounded(zs, 0.01), i=ii, j=jj, k=kk,
        intensity=rounded(heights, 0.01),
        intensitymode="vertex", colorscale=scale, cmin=0.0, cmax=top, showscale=False, flatshading=True,
        lighting={"ambient": 0.55, "diffuse": 0.75, "specular": 0.05, "roughness": 0.9},
        lightposition={"x": -4000, "y": -6000, "z": 7000},
        customdata=np.column_stack([ids, heights]) if ids else None,
        hovertemplate=what + " %{customdata[0]}<br>height %{customdata[1]:.1f} m<extra></extra>",
        name=name, showlegend=color is not None)


def city_scene(lo: np.ndarray, hi: np.ndarray, top_m: float) -> dict:
    """A plotly 3D scene over the region lo..hi (ENU metres), up to `top_m`, to scale, seen from the south-west."""
    extent = np.maximum(hi - lo, 1.0)
    return {"xaxis": {"title": {"text": "x east [m]"}, "range": [float(lo[0]), float(hi[0])]},
            "yaxis": {"title": {"text": "y north [m]"}, "range": [float(lo[1]), float(hi[1])]},
            "zaxis": {"title": {"text": "z up [m]"}, "range": [0.0, top_m]},
            "aspectmode": "manual",
            "aspectratio": {"x": 1.0, "y": float(extent[1] / extent[0]), "z": float(top_m / extent[0])},
            "camera": {"eye": {"x": -0.9, "y": -1.3, "z": 0.9}}}


def rounded(values, step: float) -> list:
    """Values rounded to a multiple of `step` (JSON stays short); NaN becomes None (JSON null)."""
    a = np.round(np.asarray(values, float) / step) * step
    digits = max(0, -math.floor(math.log10(step)))
    return [None if not math.isfinite(v) else round(float(v), digits) for v in a.ravel()]


def _time_grid(group: FlightGroup, opts: ViewerConfig) -> np.ndarray:
    end = max(group.duration_s, opts.min_step_s)
    n = int(min(opts.max_samples, math.ceil(end / opts.min_step_s))) + 1
    return np.linspace(0.0, end, n)


def group_payload(group: FlightGroup, opts: ViewerConfig) -> dict:
    """One cell for the page: its plotly figure (JSON) and, per pilot, samples on the cell's time grid.

    Trace order in the figure: 0 buildings, 1 start, 2 goal, then per pilot: path, trail, vehicle; then the layers
    the script never moves: the obstacles the prior map lacks (their own colour), each pilot's estimated path
    (dashed) and the lidar's hits (hidden until chosen in the legend).
    """
    city, lo, hi = group.region()
    meta = group.meta
    unmapped = group.unmapped_ids
    t = _time_grid(group, opts)
    fig = go.Figure()
    fig.add_trace(building_mesh(city, skip=unmapped))
    for name, xyz, color, symbol in (("start", meta.start_m, START_COLOR, "diamond"),
                                     ("goal", meta.goal_m, GOAL_COLOR, "circle")):
        fig.add_trace(go.Scatter3d(
            x=[xyz[0]], y=[xyz[1]], z=[xyz[2]], mode="markers", name=name,
            marker={"size": 7, "color": color, "symbol": symbol, "line": {"color": "black", "width": 1}},
            hovertemplate=f"{name}<br>(%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}}) m<extra></extra>"))
    pilots = []
    for p in group.flights:
        s = sample_flight(p.episode, t)
        color = to_hex(p.color)
        last = int(np.searchsorted(t, p.end_t_s, side="right"))  # samples up to the flight's end
        last = max(last, 1)
        label = text_for_html(p.label)  # plotly renders names and hover texts as HTML
        hover = (f"<b>{label}</b><br>t %{{customdata[0]:.2f}} s<br>speed %{{customdata[1]:.2f}} m/s"
                 "<br>clearance %{customdata[2]:.2f} m<br>(%{x:.1f}, %{y:.1f}, %{z:.1f}) m<extra></extra>")
        custom = np.column_stack([t[:last], s.speed_m_s[:last], s.clearance_m[:last]])
        fig.add_trace(go.Scatter3d(
            x=s.pos_m[:last, 0], y=s.pos_m[:last, 1], z=s.pos_m[:last, 2], mode="lines", name=f"{label} path",
            line={"color": color, "width": 4}, opacity=0.55, customdata=custom, hovertemplate=hover,
            legendgroup=p.pilot, showlegend=False))
        fig.add_trace(go.Scatter3d(
            x=s.pos_m[:1, 0], y=s.pos_m[:1, 1], z=s.pos_m[:1, 2], mode="lines", name=label,
            line={"color": color, "width": 8}, customdata=custom[:1], hovertemplate=hover, legendgroup=p.pilot))
        fig.add_trace(go.Scatter3d(
            x=s.pos_m[:1, 0], y=s.pos_m[:1, 1], z=s.pos_m[:1, 2], mode="markers", name=f"{label} vehicle",
            marker={"size": 7, "color": color, "line": {"color": "black", "width": 2}}, customdata=custom[:1],
            hovertemplate=hover, legendgroup=p.pilot, showlegend=False))
        pilots.append({
            "method": p.pilot, "label": p.label, "color": color, "end_t_s": round(p.end_t_s, 3),
            "outcome": p.episode.meta.outcome, "outcome_words": p.outcome_words, "last": last,
            "x": rounded(s.pos_m[:, 0], opts.round_m), "y": rounded(s.pos_m[:, 1], opts.round_m),
            "z": rounded(s.pos_m[:, 2], opts.round_m), "speed": rounded(s.speed_m_s, 0.001),
            "clearance": rounded(s.clearance_m, 0.001),
            "min_clearance_m": _finite_min(p.episode.trajectory.clearance_m)})
    _add_belief_layers(fig, group, city, unmapped, t, opts)
    top = max([float(hi[2])] + [b.height_m for b in city.buildings])
    fig.update_layout(
        margin={"l": 0, "r": 0, "t": 0, "b": 0}, paper_bgcolor="white", uirevision=group.spec,
        legend={"x": 0.01, "y": 0.99, "bgcolor": "rgba(255,255,255,0.7)"}, scene=city_scene(lo, hi, top))
    wind = group.wind or WindInfo()
    return {
        "spec": group.spec, "scenario": group.scenario, "episode": group.episode, "seed": group.seed,
        "description": group.description, "vehicle": meta.vehicle, "map": meta.map_name,
        "wind": {"steady_enu_m_s": wind.steady_enu_m_s and list(wind.steady_enu_m_s), "turbulence": wind.turbulence},
        "t": rounded(t, opts.round_s), "duration_s": round(float(t[-1]), 3), "pilots": pilots,
        "figure": json.loads(pio.to_json(fig, validate=True, remove_uids=True)),
    }


def _add_belief_layers(fig: go.Figure, group: FlightGroup, city: BuildingMap, unmapped: frozenset[int],
                       t: np.ndarray, opts: ViewerConfig) -> None:
    """The traces after the pilots': what the prior map lacks, where each pilot thought it was, what its lidar hit."""
    if unmapped & {int(i) for i in city.building_ids}:
        fig.add_trace(building_mesh(city, only=unmapped, color=UNMAPPED_COLOR, name="not in the prior map"))
    for p in group.flights:
        tr = p.episode.trajectory
        label = text_for_html(p.label)
        if tr.estimate_m is not None and len(tr.t_s):
            est = np.column_stack([np.interp(t, tr.t_s, tr.estimate_m[:, i]) for i in range(3)])
            last = max(int(np.searchsorted(t, p.end_t_s, side="right")), 1)
            fig.add_trace(go.Scatter3d(
                x=rounded(est[:last, 0], opts.round_m), y=rounded(est[:last, 1], opts.round_m),
                z=rounded(est[:last, 2], opts.round_m), mode="lines", name=f"{label}: estimated path",
                line={"color": to_hex(p.color), "width": 3, "dash": "dash"}, opacity=0.8, legendgroup=p.pilot,
                hovertemplate=f"<b>{label}</b> estimate<br>(%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}}) m<extra></extra>"))
        hits = tr.lidar_hits_m
        if hits is not None and len(hits):
            keep = hits[np.linspace(0, len(hits) - 1, min(len(hits), LIDAR_POINTS_SHOWN)).astype(int)]
            fig.add_trace(go.Scatter3d(
                x=rounded(keep[:, 1], 0.1), y=rounded(keep[:, 2], 0.1), z=rounded(keep[:, 3], 0.1), mode="markers",
                name=f"{label}: lidar hits", marker={"size": 1.5, "color": LIDAR_COLOR}, visible="legendonly",
                legendgroup=f"{p.pilot} lidar", hovertemplate="lidar hit<extra></extra>"))


LIDAR_POINTS_SHOWN = 4000  # per pilot and cell: a layer to see what was seen, not a point cloud to measure


def _finite_min(values) -> float | None:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return round(float(v.min()), 3) if len(v) else None


def write_viewer_page(run_dir: Path, out: IO[str], opts: ViewerConfig = ViewerConfig(), *,
                      warn_unreadable: bool = True, warned: Collection[str] = ()) -> None:
    """Write the viewer page of a run folder to `out`, piece by piece: each cell's data is written as it is
    made, so a run's cells are never held together (a benchmark run's page is hundreds of MB; held as one
    string, with the copies that assembling it makes, it took gigabytes).

    The template's placeholders are found in the template alone; inserted texts are never scanned.
    """
    run_dir = Path(run_dir)
    info = read_run_info(run_dir)
    groups = flight_groups(run_dir, warn_unreadable=warn_unreadable, warned=warned)
    run = {"folder": run_dir.name, "command": info.command, "created_utc": info.created_utc}

    def data() -> None:  # the same text as json_for_script({"run": run, "groups": [...]})
        out.write('{"run":' + json_for_script(run) + ',"groups":[')
        for k, g in enumerate(groups):
            out.write(("," if k else "") + json_for_script(group_payload(g, opts)))
        out.write("]}")

    assets = resources.files("compare.pages") / "viewer_assets"
    template = (assets / "viewer.html").read_text(encoding="utf-8")
    parts: dict[str, str | Callable[[], None]] = {
        "TITLE": text_for_html(f"uam-compare viewer: {run_dir.name}"),
        "STYLE": (assets / "viewer.css").read_text(encoding="utf-8"),
        "PLOTLY_JS": code_for_script(plotly.offline.get_plotlyjs()),
        "PLOTLY_VERSION": text_for_html(plotly.__version__),
        "DATA_JSON": data,  # every text of the run folder and its scenarios goes in here, as json_for_script
        "PLAYER_JS": code_for_script((assets / "player.js").read_text(encoding="utf-8")),
        "VIEWER_JS": code_for_script((assets / "viewer.js").read_text(encoding="utf-8")),
    }
    at = {}
    for key in parts:
        i = template.find("{{" + key + "}}")
        if i < 0:
            raise RuntimeError(f"viewer template lacks {{{{{key}}}}}")
        at[key] = i
    pos = 0
    for key in sorted(parts, key=at.__getitem__):
        out.write(template[pos:at[key]])
        part = parts[key]
        if callable(part):
            part()
        else:
            out.write(part)
        pos = at[key] + len(key) + 4
    out.write(template[pos:])


def build_viewer(run_dir: Path, out: Path | None = None, opts: ViewerConfig = ViewerConfig(), *,
                 warn_unreadable: bool = True, warned: Collection[str] = ()) -> Path:
    """Write the viewer of a run folder (default `RUN_DIR/viewer.html`) atomically; returns its path.

    An unreadable episode file is left out with a warning (INFO when `warn_unreadable` is False: the caller has
    named the files its listing finds unreadable); a flight that does not draw, with one warning line each (INFO
    for the file names in `warned`: the caller has named them).

    Raises:
        ValueError: not a run folder, no readable saved episodes, an unreadable map, or a link in the run folder
            on the way to the default file (`uam_fdm.files.inside`), naming the file.
    """
    root = None if out is not None else Path(run_dir)  # the run's own file: no link in the run folder followed
    out = Path(out) if out is not None else Path(run_dir) / VIEWER_NAME
    with atomic_open(out, "w", root=root, encoding="utf-8", newline="") as f:
        write_viewer_page(run_dir, f, opts, warn_unreadable=warn_unreadable, warned=warned)
    return out
