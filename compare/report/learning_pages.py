"""The report's "learning in pictures" pages: a policy's fixed training tasks (rows) flown by a few of its
recorded checkpoints (columns), top-down, each flight coloured by outcome with its time.

Drawn from the policy folder's training flights (`rl.policies.flights`) only; a policy without them gets no
page. Checkpoints shown (`chosen_checkpoints`): `COLUMNS` spread evenly over the recorded ones from the first
(step 0) to the last, the kept checkpoint always among them.
"""
from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from compare.report import figures as F
from compare.report.layout import text_pages
from rl.policies.flights import CheckpointFlights, CityBoxes, TrainingFlights, flights_dir
from rl.policies.folder import PolicyFolder

COLUMNS = 5
ROWS_PER_PAGE = 4
MARGIN_M = 25.0
OUTCOME_COLORS = {"success": "tab:green", "collision": "tab:red", "timeout": "tab:orange",
                  "out_of_bounds": "tab:purple", "nonfinite": "tab:gray"}
OUTCOME_WORDS = {"success": "arrived", "collision": "collided", "timeout": "timed out",
                 "out_of_bounds": "left bounds", "nonfinite": "diverged"}


def chosen_checkpoints(steps: Sequence[int], kept: int | None, columns: int = COLUMNS) -> list[int]:
    """Up to `columns` (+1 for the kept one) recorded checkpoints: evenly spread from the first to the last, with
    `kept` among them when it was recorded."""
    steps = sorted(steps)
    idx = np.unique(np.round(np.linspace(0, len(steps) - 1, min(columns, len(steps)))).astype(int))
    out = [steps[i] for i in idx]
    if kept is not None and kept in steps and kept not in out:
        out = sorted(out + [kept])
    return out


def _footprints(city: CityBoxes) -> list[np.ndarray]:
    """Each box's footprint corners (4, 2) [m]."""
    polys = []
    for cx, cy, w, d, _h, yaw in city.boxes:
        c, s = math.cos(yaw), math.sin(yaw)
        local = np.array([[-w, -d], [w, -d], [w, d], [-w, d]]) / 2.0
        polys.append(local @ np.array([[c, s], [-s, c]]) + [cx, cy])
    return polys


def learning_figures(policy_dir: Path | str, title: str = "Learning in pictures") -> list[Figure]:
    """The pages of a policy's recorded training flights; [] when the folder has none (no page, no error).

    A folder whose flights cannot be read gets one page saying why (naming the file).
    """
    folder = PolicyFolder(Path(policy_dir))
    if not flights_dir(folder.path).is_dir():
        return []
    try:
        flights = TrainingFlights.open(folder.path)
        prov = folder.provenance()
        steps = chosen_checkpoints(flights.steps, prov.kept_timesteps if prov is not None else None)
        ckpts = [flights.checkpoint(s) for s in steps]
    except ValueError as exc:
        return text_pages(title, [("p", f"The training flights could not be read: {exc}")])
    kept = prov.kept_timesteps if prov is not None else None
    n_tasks = len(flights.tasks.tasks)
    return [_page(title, flights, ckpts, kept, list(range(k, min(k + ROWS_PER_PAGE, n_tasks))))
            for k in range(0, n_tasks, ROWS_PER_PAGE)]


def _page(title: str, flights: TrainingFlights, ckpts: list[CheckpointFlights], kept: int | None,
          rows: list[int]) -> Figure:
    fig = Figure(figsize=F.PAGE_SIZE_IN, layout="constrained")
    fig.suptitle(title, fontsize=15, fontweight="bold")
    axes = fig.subplots(len(rows), len(ckpts), squeeze=False)
    tasks = flights.tasks
    for r, k in enumerate(rows):
        task = tasks.tasks[k]
        city = tasks.cities[task.city]
        pts = np.vstack([c.flights[k].pos_m[:, :2] for c in ckpts] + [np.array([task.start_m[:2], task.goal_m[:2]])])
        lo = np.maximum(pts.min(axis=0) - MARGIN_M, city.bounds_min_m[:2])
        hi = np.minimum(pts.max(axis=0) + MARGIN_M, city.bounds_max_m[:2])
        polys = _footprints(city)
        for c, ckpt in enumerate(ckpts):
            ax = axes[r][c]
            f = ckpt.flights[k]
            color = OUTCOME_COLORS.get(f.outcome, "black")
            ax.add_collection(PolyCollection(polys, facecolors="0.75", edgecolors="0.55", linewidths=0.4))
            ax.plot(f.pos_m[:, 0], f.pos_m[:, 1], color=color, lw=1.4)
            ax.plot(*task.start_m[:2], marker="D", color="tab:green", ms=4, mec="black", mew=0.5)
            ax.plot(*task.goal_m[:2], marker="o", color="gold", ms=5, mec="black", mew=0.5)
            ax.plot(*f.pos_m[-1, :2], marker="o", color=color, ms=3.5)
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{OUTCOME_WORDS.get(f.outcome, f.outcome)} {f.time_s:.1f} s", fontsize=8.5, color=color,
                         pad=2)
            if r == 0:
                head = f"{_steps(ckpt.timesteps)} steps" + (" (kept)" if ckpt.timesteps == kept else "")
                ax.annotate(head, (0.5, 1.22), xycoords="axes fraction", ha="center", fontsize=9.5,
                            fontweight="bold")
            if c == 0:
                dist = math.dist(task.start_m, task.goal_m)
                ax.set_ylabel(f"task {k}: {task.leg}\n{dist:.0f} m, {task.turbulence}", fontsize=8.5)
    fig.supxlabel(textwrap.fill(f"Fixed tasks, top-down (x east, y north; buildings grey; start green diamond, "
                                f"goal yellow). {tasks.rule}.", 190), fontsize=7)
    return fig


def _steps(n: int) -> str:
    return f"{n / 1e6:.2f} M" if n >= 1_000_000 else f"{n / 1e3:.0f} k" if n >= 10_000 else f"{n:,d}"
