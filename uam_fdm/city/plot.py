"""Figures of a city: top-down footprints and shaded 3D boxes, through matplotlib's Figure API.

Library functions draw into a given Axes (so reports can compose them) or return a Figure; nothing
here touches pyplot's global state.  `python -m uam_fdm.city.plot OUT_DIR` renders the shipped maps;
`task_preview_figure` draws a city with tasks to fly and its prior map's differences (`uam-compare maps FILE`).
"""
from __future__ import annotations

import contextlib
import sys
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import colormaps
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch, Polygon, Rectangle
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from uam_fdm.city.buildings import BuildingMap, Obstacle
from uam_fdm.city.mapfile import load_named_map, named_maps
from uam_fdm.files.atomic import atomic_path

if TYPE_CHECKING:  # the task type only: uam_fdm.pilot imports the vehicle model
    from uam_fdm.pilot import Task

_CMAP = "viridis"
_LIGHT = np.array([-0.4, -0.6, 0.7]) / np.linalg.norm([-0.4, -0.6, 0.7])  # from the south-west, above


def _height_norm(bmap: BuildingMap) -> Normalize:
    heights = [p.height_m for p in bmap.buildings] or [1.0]
    return Normalize(vmin=0.0, vmax=max(heights))


def draw_map_topdown(ax: Axes, bmap: BuildingMap, *, show_bounds: bool = True,
                     show_no_fly: bool = True) -> PolyCollection:
    """Draw footprints coloured by height into a 2D Axes (x east, y north, metres, equal aspect).

    Args:
        ax: a 2D matplotlib Axes.
        bmap: the map.
        show_bounds: draw the flight-volume bounds as a dashed rectangle.
        show_no_fly: draw no-fly zones hatched in red.

    Returns:
        The footprints' PolyCollection (a ScalarMappable of height [m], for a colour bar).
    """
    norm = _height_norm(bmap)
    polys = [p.footprint_xy_m() for p in bmap.buildings]
    coll = PolyCollection(polys, array=np.array([p.height_m for p in bmap.buildings]), cmap=_CMAP,
                          norm=norm, edgecolors="0.15", linewidths=0.3)
    ax.add_collection(coll)
    lo, hi = bmap.bounds_min_m, bmap.bounds_max_m
    if show_bounds:
        ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, ls="--", lw=0.8,
                               ec="0.4"))
    if show_no_fly:
        for z in bmap.no_fly:
            ax.add_patch(_polygon_patch(z.footprint_xy_m()))
    pad = 0.02 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    return coll


def _polygon_patch(xy: np.ndarray) -> Polygon:
    return Polygon(xy, closed=True, fill=False, ec="tab:red", hatch="//", lw=0.8)


def draw_map_3d(ax: Axes3D, bmap: BuildingMap, *, shade: bool = True) -> Poly3DCollection:
    """Draw buildings as shaded prisms into a 3D Axes (ENU metres, true proportions).

    Args:
        ax: a 3D Axes (`fig.add_subplot(projection="3d")`).
        bmap: the map.
        shade: darken faces turned away from a light in the south-west sky.

    Returns:
        The Poly3DCollection of building faces.
    """
    norm = _height_norm(bmap)
    cmap = colormaps[_CMAP]
    faces, colors = [], []
    for p in bmap.buildings:
        base = np.array(cmap(norm(p.height_m)))
        for face, normal in _prism_faces(p):
            faces.append(face)
            colors.append(_shaded(base, normal, shade))
    coll = Poly3DCollection(faces, facecolors=colors, edgecolors=(0, 0, 0, 0.25), linewidths=0.2)
    # the limits are set just below: autoscaling first can reach infinite limits (numpy overflow warnings)
    ax.add_collection3d(coll, autolim=False)
    lo, hi = bmap.bounds_min_m, bmap.bounds_max_m
    top = max([float(hi[2])] + [p.height_m for p in bmap.buildings])
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(0.0, top)
    ax.set_box_aspect((float(hi[0] - lo[0]), float(hi[1] - lo[1]), top), zoom=0.88)  # room for labels
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_zlabel("z up [m]")
    ax.zaxis.set_major_locator(MaxNLocator(3))  # the z axis is short at true scale: few ticks stay legible
    ax.view_init(elev=35.0, azim=-60.0)
    return coll


def _prism_faces(part: Obstacle) -> list[tuple[np.ndarray, np.ndarray]]:
    """A part's roof and walls as (4+, 3) ENU polygons [m], each with its outward unit normal; from its base
    (a crane's jib stands off the ground) to its roof."""
    fp = part.footprint_xy_m()
    h, z0 = part.height_m, float(getattr(part, "base_m", 0.0))
    k = len(fp)
    faces = [(np.column_stack([fp, np.full(k, h)]), np.array([0.0, 0.0, 1.0]))]
    for i in range(k):
        a, b = fp[i], fp[(i + 1) % k]
        edge = b - a
        normal = np.array([edge[1], -edge[0], 0.0]) / max(float(np.hypot(*edge)), 1e-12)
        faces.append((np.array([[a[0], a[1], z0], [b[0], b[1], z0], [b[0], b[1], h], [a[0], a[1], h]]), normal))
    return faces


def _shaded(base: np.ndarray, normal: np.ndarray, shade: bool) -> np.ndarray:
    if not shade:
        return base
    light = 0.55 + 0.45 * max(float(np.dot(normal, _LIGHT)), 0.0)
    out = base.copy()
    out[:3] = base[:3] * light
    return out


def map_figure(bmap: BuildingMap, title: str | None = None) -> Figure:
    """A two-panel figure of a map: top-down (with a height colour bar) and 3D.

    Args:
        bmap: the map.
        title: figure title (default: the map's name and building count).
    """
    fig = Figure(figsize=(14.0, 6.5), layout="constrained")
    ax2d = fig.add_subplot(1, 2, 1)
    coll = draw_map_topdown(ax2d, bmap)
    fig.colorbar(coll, ax=ax2d, label="building height [m]", shrink=0.8)
    ax3d = fig.add_subplot(1, 2, 2, projection="3d")
    ax3d.set_anchor("W")  # keep the 3D panel off the right edge, where its z label would be clipped
    draw_map_3d(ax3d, bmap)
    n = len(bmap.building_ids)
    fig.suptitle(title if title is not None else f"{bmap.name or 'map'}: {n} buildings")
    return fig


_TRUTH_ONLY_COLOR = "magenta"  # obstacles the pilots' prior map lacks (red hatches the no-fly zones)
_PRIOR_COLOR = "tab:orange"  # the prior map's footprint of a building it has moved or resized
_TASK_COLORS = colormaps["tab10"]


def prior_differences(truth: BuildingMap, prior: BuildingMap) -> tuple[tuple[Obstacle, ...], tuple[Obstacle, ...]]:
    """How a prior map differs from the true world, part by part (parts matched by building id).

    Returns:
        (the truth's parts whose id the prior lacks: unmapped or missing buildings, cranes and masts; the prior's
        parts unlike every true part of their id: moved, or another height).
    """
    prior_ids = {p.id for p in prior.buildings}
    by_id: dict[int, list[Obstacle]] = {}
    for p in truth.buildings:
        by_id.setdefault(p.id, []).append(p)
    only = tuple(p for p in truth.buildings if p.id not in prior_ids)
    changed = tuple(p for p in prior.buildings if p not in by_id.get(p.id, ()))
    return only, changed


def draw_prior_differences_topdown(ax: Axes, truth: BuildingMap, prior: BuildingMap) -> tuple[int, int]:
    """Hatch in red the footprints only the truth has and outline, dashed orange, where the prior map puts the
    buildings it has moved or resized (2D Axes, ENU metres); returns (buildings only in the truth, changed ones)."""
    only, changed = prior_differences(truth, prior)
    for p in only:
        ax.add_patch(Polygon(p.footprint_xy_m(), closed=True, fill=False, ec=_TRUTH_ONLY_COLOR, hatch="xxxx", lw=1.0,
                             zorder=3))
    for p in changed:
        ax.add_patch(Polygon(p.footprint_xy_m(), closed=True, fill=False, ec=_PRIOR_COLOR, ls="--", lw=0.9, zorder=3))
    return len({p.id for p in only}), len({p.id for p in changed})


def _task_color(i: int) -> tuple[float, float, float, float]:
    return _TASK_COLORS(i % _TASK_COLORS.N)


def draw_tasks_topdown(ax: Axes, tasks: Sequence[Task], labels: Sequence[str] | None = None) -> None:
    """Draw each task into a 2D Axes (x east, y north, metres): its start (a dot with its label), an arrow along the
    straight line to its goal (a cross) and the goal radius as a circle to scale, one colour per task.

    Args:
        ax: a 2D Axes.
        tasks: the tasks (start, goal and goal radius, ENU metres).
        labels: one per task (default: the index).
    """
    for i, t in enumerate(tasks):
        c = _task_color(i)
        s, g = np.asarray(t.start_m, float), np.asarray(t.goal_m, float)
        ax.annotate("", xy=(g[0], g[1]), xytext=(s[0], s[1]), zorder=5,
                    arrowprops={"arrowstyle": "-|>", "color": c, "lw": 1.3, "shrinkA": 3, "shrinkB": 3})
        ax.add_patch(Circle((g[0], g[1]), t.goal_radius_m, fill=False, ec=c, lw=1.0, zorder=5))
        ax.plot([s[0]], [s[1]], "o", ms=6, mfc=c, mec="black", mew=0.7, zorder=6)
        ax.plot([g[0]], [g[1]], "X", ms=7, mfc=c, mec="black", mew=0.6, zorder=6)
        ax.annotate(labels[i] if labels is not None else str(i), (s[0], s[1]), xytext=(4, 4),
                    textcoords="offset points", fontsize=8, zorder=7,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": c, "lw": 0.8, "alpha": 0.9})


def draw_tasks_3d(ax: Axes3D, tasks: Sequence[Task], labels: Sequence[str] | None = None) -> None:
    """Draw each task into a 3D Axes (ENU metres): its start (a dot with its label), the straight line to its goal
    (a cross), one colour per task."""
    for i, t in enumerate(tasks):
        c = _task_color(i)
        s, g = np.asarray(t.start_m, float), np.asarray(t.goal_m, float)
        ax.plot([s[0], g[0]], [s[1], g[1]], [s[2], g[2]], color=c, lw=1.6)
        ax.scatter([s[0]], [s[1]], [s[2]], marker="o", s=28, color=c, edgecolors="black", depthshade=False)
        ax.scatter([g[0]], [g[1]], [g[2]], marker="X", s=40, color=c, edgecolors="black", depthshade=False)
        ax.text(s[0], s[1], s[2], f" {labels[i] if labels is not None else i}", fontsize=8)


def draw_volume_3d(ax: Axes3D, bmap: BuildingMap) -> None:
    """Draw the flight volume's twelve edges, dashed, into a 3D Axes (ENU metres)."""
    lo, hi = np.asarray(bmap.bounds_min_m, float), np.asarray(bmap.bounds_max_m, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for a in range(8):
        for b in range(a + 1, 8):
            if np.count_nonzero(corners[a] != corners[b]) == 1:  # an edge: the corners differ along one axis
                ax.plot(*zip(corners[a], corners[b]), color="0.35", ls="--", lw=0.7)


def task_preview_figure(truth: BuildingMap, tasks: Sequence[Task], *, prior: BuildingMap | None = None,
                        labels: Sequence[str] | None = None, title: str | None = None) -> Figure:
    """A city with the tasks to fly in it: top view (buildings by height, the prior map's differences, no-fly
    zones, the flight volume, each task's start, straight line, goal and goal radius) and a 3D view.

    Args:
        truth: the world as it stands (ENU metres).
        tasks: the tasks (labelled by `labels`, default their index).
        prior: the map the pilots are given, when it differs from `truth` (None or `truth`: no differences).
        labels: one per task.
        title: the figure's title (default: the map's name, its buildings and the number of tasks).
    """
    fig = Figure(figsize=(15.0, 7.5), layout="constrained")
    ax2d = fig.add_subplot(1, 2, 1)
    coll = draw_map_topdown(ax2d, truth)
    fig.colorbar(coll, ax=ax2d, label="building height [m]", shrink=0.8)
    only: tuple[Obstacle, ...] = ()
    handles: list[Artist] = [
        Line2D([], [], ls="", marker="o", mfc="0.6", mec="black", label="start (label: episode)"),
        Line2D([], [], ls="", marker="X", mfc="0.6", mec="black", label="goal; circle: goal radius"),
        Line2D([], [], color="0.4", marker=">", lw=1.3, label="straight line (not the path flown)"),
        Patch(fill=False, ls="--", ec="0.4", label="flight volume"),
    ]
    if truth.no_fly:
        handles.append(Patch(fill=False, ec="tab:red", hatch="//", label="no-fly zone"))
    if prior is not None and prior is not truth:
        only, changed = prior_differences(truth, prior)
        n_only, n_changed = draw_prior_differences_topdown(ax2d, truth, prior)
        handles.append(Patch(fill=False, ec=_TRUTH_ONLY_COLOR, hatch="xxxx",
                             label=f"not in the prior map ({n_only}: unmapped, missing, cranes, masts)"))
        if n_changed:
            handles.append(Patch(fill=False, ec=_PRIOR_COLOR, ls="--",
                                 label=f"prior map's footprint, moved or another height ({n_changed})"))
    draw_tasks_topdown(ax2d, tasks, labels)
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    ax3d = fig.add_subplot(1, 2, 2, projection="3d")
    ax3d.set_anchor("W")  # keep the 3D panel off the right edge, where its z label would be clipped
    ax3d.computed_zorder = False  # drawn in order: the tasks over the buildings
    only_ids = {p.id for p in only}
    rest = truth if not only_ids else BuildingMap([p for p in truth.buildings if p.id not in only_ids],
                                                  truth.bounds_min_m, truth.bounds_max_m, truth.no_fly,
                                                  name=truth.name)
    draw_map_3d(ax3d, rest)
    lo, hi = truth.bounds_min_m, truth.bounds_max_m
    top = max([float(hi[2])] + [p.height_m for p in truth.buildings])
    ax3d.set_box_aspect((float(hi[0] - lo[0]), float(hi[1] - lo[1]), top), zoom=0.8)  # room for the z label
    if only:
        faces = [face for p in only for face, _ in _prism_faces(p)]
        ax3d.add_collection3d(Poly3DCollection(faces, facecolors=_TRUTH_ONLY_COLOR, edgecolors=(0, 0, 0, 0.4),
                                               linewidths=0.2), autolim=False)
    draw_volume_3d(ax3d, truth)
    draw_tasks_3d(ax3d, tasks, labels)
    fig.suptitle(title if title is not None else f"{truth.name or 'map'}: {len(truth.building_ids)} buildings, "
                                                 f"{len(tasks)} tasks; flight volume x [{lo[0]:g}, {hi[0]:g}], "
                                                 f"y [{lo[1]:g}, {hi[1]:g}], z [{lo[2]:g}, {hi[2]:g}] m")
    return fig


@contextlib.contextmanager
def missing_glyphs_unsaid() -> Iterator[None]:
    """Draw without matplotlib's warning for each character its font lacks: names come from users' files (a
    scenario, a city, a pilot's label) in any script, and such a character is drawn as a box on the page, where
    it is seen; the warning would repeat it on stderr, glyph by glyph, with a library's path. Every other warning
    is left as it is."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font", category=UserWarning)
        yield


def save_figure(fig: Figure, path: Path, dpi: int = 110, *, root: Path | None = None) -> Path:
    """Save a figure atomically (temp file in the same folder, then os.replace); returns the path (`root`: the
    folder this tool owns that `path` lies in, as `uam_fdm.files.atomic.atomic_path`'s)."""
    path = Path(path)
    with atomic_path(path, suffix=path.suffix, root=root) as tmp, missing_glyphs_unsaid():
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    return path


def render_named_maps(out_dir: Path, names: Sequence[str] | None = None) -> list[Path]:
    """Render shipped maps to `<out_dir>/map_<name>.png`.

    Args:
        out_dir: output folder (created if missing).
        names: which maps (default: all of `named_maps()`).

    Returns:
        The written PNG paths, in name order.
    """
    out = []
    for name in sorted(names if names is not None else named_maps()):
        out.append(save_figure(map_figure(load_named_map(name)), Path(out_dir) / f"map_{name}.png"))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m uam_fdm.city.plot OUT_DIR`: render the shipped maps to PNG."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1 or args[0].startswith("-"):
        print("usage: python -m uam_fdm.city.plot OUT_DIR", file=sys.stderr)
        return 2
    for path in render_named_maps(Path(args[0])):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
