"""Flights as a Rerun recording (`.rrd`), for those who work in Rerun's viewer (`uam-compare export --rerun`).

Two sources: a run folder's saved episodes (every comparison cell: its city, each pilot's path and vehicle) and
a policy folder's recorded training flights (`rl.policies.flights`: each fixed task's city, and its flight by
every recorded checkpoint). World ENU metres (`ViewCoordinates.RIGHT_HAND_Z_UP`), one timeline `t` [s] from each
flight's start. Entities:

```
run:      cells/<scenario>__ep<episode>__s<seed>/city            Boxes3D (prism parts: Mesh3D city_prisms), static
          cells/<cell>/start, goal                               Points3D, static
          cells/<cell>/<pilot>/path                             LineStrips3D, static
          cells/<cell>/<pilot>/vehicle                          Points3D over t
          cells/<cell>/<pilot>/clearance_m, speed_m_s           Scalars over t
training: tasks/task_<k>/city, start, goal                       static
          tasks/task_<k>/step_<timesteps>/path, vehicle, clearance_m, speed_m_s   (as above)
```

rerun-sdk is an optional extra (`pip install -e '.[rerun]'` in a clone, `pip install 'uam-compare[rerun]'` for an
installed package), imported only here and only when asked;
the recording is written with rerun-sdk's version (`RERUN_READS` says which viewer reads it) and atomically.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.colors import to_rgba

from compare.playback.flights import flight_groups, sample_flight
from rl.policies.flights import CityBoxes, TrainingFlights
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.files.atomic import atomic_path

EXTRA = "rerun"
RERUN_READS = "the Rerun viewer of the same minor version as the rerun-sdk that wrote it (0.41 when tested)"
RUN_SAMPLE_HZ = 20.0  # a run's physics-rate episodes are sampled at this rate [Hz] (the viewer interpolates none)
OUTCOME_RGBA = {"success": (44, 160, 44, 255), "collision": (214, 39, 40, 255), "timeout": (255, 127, 14, 255),
                "out_of_bounds": (148, 103, 189, 255), "nonfinite": (127, 127, 127, 255)}


def require_rerun() -> Any:
    """The `rerun` module.

    Raises:
        ValueError: rerun-sdk is not installed, naming the extra that installs it.
    """
    try:
        # optional (rerun-sdk, ~60 MB): imported only when a recording is asked for
        import rerun
    except ImportError:
        raise ValueError(f"export needs the optional package rerun-sdk: in a clone of the repository pip install -e "
                         f"'.[{EXTRA}]', for an installed uam-compare pip install 'uam-compare[{EXTRA}]' (or pip "
                         f"install rerun-sdk alone)") from None
    return rerun


def _boxes(rr: Any, rows: np.ndarray, color: tuple[int, int, int, int] = (170, 170, 170, 255)) -> Any:
    """Buildings (B, 6: centre x, y, size x, y, height, yaw) as one `Boxes3D` standing on the ground."""
    rows = np.asarray(rows, float).reshape(-1, 6)
    centers = np.column_stack([rows[:, 0], rows[:, 1], rows[:, 4] / 2.0])
    half = np.column_stack([rows[:, 2] / 2.0, rows[:, 3] / 2.0, rows[:, 4] / 2.0])
    turns = [rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=float(y)) for y in rows[:, 5]]
    return rr.Boxes3D(centers=centers, half_sizes=half, rotation_axis_angles=turns, colors=[color] * len(rows),
                      fill_mode="solid")


def _prism_mesh(rr: Any, bmap: BuildingMap) -> Any | None:
    """The non-box parts of a map as one `Mesh3D` (roof fans and wall quads), or None when there are none."""
    verts: list[np.ndarray] = []
    tris: list[list[int]] = []
    for b in bmap.buildings:
        if isinstance(b, Building):
            continue
        fp = b.footprint_xy_m()
        n, base = len(fp), sum(len(v) for v in verts)
        verts.append(np.vstack([np.column_stack([fp, np.zeros(n)]), np.column_stack([fp, np.full(n, b.height_m)])]))
        tris += [[base + n, base + n + v, base + n + v + 1] for v in range(1, n - 1)]
        for v in range(n):
            w = (v + 1) % n
            tris += [[base + v, base + w, base + n + w], [base + v, base + n + w, base + n + v]]
    if not verts:
        return None
    return rr.Mesh3D(vertex_positions=np.vstack(verts), triangle_indices=np.array(tris))


def _city(rr: Any, rec: Any, path: str, boxes: np.ndarray, prisms: Any | None = None) -> None:
    rec.log(f"{path}/city", _boxes(rr, boxes), static=True)
    if prisms is not None:
        rec.log(f"{path}/city_prisms", prisms, static=True)


def _flight(rr: Any, rec: Any, path: str, t_s: np.ndarray, pos_m: np.ndarray, speed_m_s: np.ndarray,
            clearance_m: np.ndarray, rgba: tuple[int, int, int, int]) -> None:
    """One flight: its whole path (static) and, over `t`, the vehicle, its clearance and its speed."""
    pos = np.asarray(pos_m, np.float32)
    rec.log(f"{path}/path", rr.LineStrips3D([pos], colors=[rgba]), static=True)
    time = [rr.TimeColumn("t", duration=np.asarray(t_s, float))]
    rec.send_columns(f"{path}/vehicle", indexes=time,
                     columns=rr.Points3D.columns(positions=pos, colors=[rgba] * len(pos), radii=[0.6] * len(pos)))
    rec.send_columns(f"{path}/clearance_m", indexes=time,
                     columns=rr.Scalars.columns(scalars=np.nan_to_num(np.asarray(clearance_m, float))))
    rec.send_columns(f"{path}/speed_m_s", indexes=time,
                     columns=rr.Scalars.columns(scalars=np.asarray(speed_m_s, float)))


def _map_rows(bmap: BuildingMap) -> np.ndarray:
    return np.array([[*b.center_xy_m, *b.size_xy_m, b.height_m, b.yaw_rad] for b in bmap.buildings
                     if isinstance(b, Building)], float).reshape(-1, 6)


def _write(out: Path, recording_id: str, log: Any) -> Path:
    """Write a recording to `out` atomically: `log(rr, rec)` logs everything into the stream."""
    rr = require_rerun()
    with atomic_path(out, suffix=".rrd") as tmp:
        rec = rr.RecordingStream("uam-compare", recording_id=recording_id, send_properties=False)
        rec.save(str(tmp))
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # world ENU: x east, y north, z up
        log(rr, rec)
        rec.flush()
        rec.disconnect()
    return out


def run_recording(run_dir: Path, out: Path) -> Path:
    """A run folder's flights as a Rerun recording at `out` (see the module docstring); returns `out`.

    Raises:
        ValueError: rerun-sdk missing, or not a run folder with readable episodes (naming it).
    """
    require_rerun()
    groups = flight_groups(Path(run_dir))

    def log(rr: Any, rec: Any) -> None:
        for g in groups:
            cell = f"cells/{rr.escape_entity_path_part(g.stem)}"
            _city(rr, rec, cell, _map_rows(g.city), _prism_mesh(rr, g.city))
            meta = g.meta
            rec.log(f"{cell}/start", rr.Points3D([meta.start_m], colors=[(44, 160, 44, 255)], radii=[1.0]), static=True)
            rec.log(f"{cell}/goal", rr.Points3D([meta.goal_m], colors=[(255, 215, 0, 255)], radii=[1.0]), static=True)
            for p in g.flights:
                t = np.arange(0.0, p.end_t_s + 1e-9, 1.0 / RUN_SAMPLE_HZ)
                if not len(t) or t[-1] < p.end_t_s:
                    t = np.r_[t, p.end_t_s]
                s = sample_flight(p.episode, t)
                rgba = tuple(int(round(255 * v)) for v in to_rgba(p.color))
                _flight(rr, rec, f"{cell}/{rr.escape_entity_path_part(p.pilot)}", t, s.pos_m, s.speed_m_s,
                        s.clearance_m, rgba)  # type: ignore[arg-type]

    return _write(Path(out), f"run-{Path(run_dir).resolve().name}", log)


def training_recording(policy_dir: Path, out: Path) -> Path:
    """A policy folder's recorded training flights as a Rerun recording at `out`; returns `out`.

    Raises:
        ValueError: rerun-sdk missing, or the folder has no recorded flights (naming it and how to get them).
    """
    require_rerun()
    flights = TrainingFlights.open(Path(policy_dir))
    tasks = flights.tasks

    def log(rr: Any, rec: Any) -> None:
        for k, task in enumerate(tasks.tasks):
            city: CityBoxes = tasks.cities[task.city]
            base = f"tasks/task_{k}"
            _city(rr, rec, base, city.boxes)
            rec.log(f"{base}/start", rr.Points3D([task.start_m], colors=[(44, 160, 44, 255)], radii=[1.0]), static=True)
            rec.log(f"{base}/goal", rr.Points3D([task.goal_m], colors=[(255, 215, 0, 255)], radii=[1.0]), static=True)
        for step in flights.steps:
            for f in flights.checkpoint(step).flights:
                t = np.arange(len(f.pos_m)) / tasks.control_hz
                _flight(rr, rec, f"tasks/task_{f.task}/step_{step:011d}", t, f.pos_m,
                        np.linalg.norm(f.vel_m_s.astype(float), axis=1), f.clearance_m,
                        OUTCOME_RGBA.get(f.outcome, (0, 0, 0, 255)))

    return _write(Path(out), f"training-{Path(policy_dir).resolve().name}", log)
