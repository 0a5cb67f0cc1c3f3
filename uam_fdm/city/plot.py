"""Figures of a city: top-down footprints and shaded 3D boxes, through matplotlib's Figure API.

Library functions draw into a given Axes (so reports can compose them) or return a Figure; nothing
here touches pyplot's global state.  `python -m uam_fdm.city.plot OUT_DIR` renders the shipped maps.
"""
from __future__ import annotations

import contextlib
import sys
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.mapfile import load_named_map, named_maps
from uam_fdm.files.atomic import atomic_path

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
        fp = p.footprint_xy_m()
        h = p.height_m
        base = np.array(cmap(norm(h)))
        k = len(fp)
        roof = np.column_stack([fp, np.full(k, h)])
        faces.append(roof)
        colors.append(_shaded(base, np.array([0.0, 0.0, 1.0]), shade))
        for i in range(k):
            a, b = fp[i], fp[(i + 1) % k]
            faces.append(np.array([[a[0], a[1], 0.0], [b[0], b[1], 0.0], [b[0], b[1], h], [a[0], a[1], h]]))
            edge = b - a
            normal = np.array([edge[1], -edge[0], 0.0]) / max(float(np.hypot(*edge)), 1e-12)
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
