"""Training flights: what a policy flew at each checkpoint of its training, and the one reader of them.

Training (`rl.training.recording`) flies a fixed set of validation tasks with the current deterministic
policy at step 0 and at every validation evaluation, and writes them into the policy folder:

```
folder/training_flights/tasks.json               the fixed tasks, how they were chosen, their cities as boxes
folder/training_flights/step_<timesteps:011d>.npz one checkpoint: its flights and the policy that flew them
```

A checkpoint file holds (all plain arrays, read without unpickling): `timesteps` (); per flight, in task
order, `task` (F,) int, `outcome` (F,) str, `time_s` (F,), `min_clearance_m` (F,); the samples of every
flight one after the other, at the control rate from the start (t = k / control_hz), flight f being rows
`offsets[f]:offsets[f + 1]`: `pos_m` (T, 3) float32 (ENU metres), `vel_m_s` (T, 3) float32 and
`clearance_m` (T,) float32 (the collision sphere's distance to the nearest building or the ground, capped at
the clearance sensor's range); the actor's weights as `actor/<SB3 parameter name>` float32 and the
normalisation statistics as `obs_norm/<mean|var|count|epsilon|clip_obs>`, so the checkpoint can be flown again
(`rl.pilots.learned.load_checkpoint_policy`). A flight's clearance is measured at the control rate, not at
the physics rate the comparison's metrics use.
"""
from __future__ import annotations

import json
import math
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rl.policies.reader import OBS_NORM_KEYS, ObsNorm
from uam_fdm.episode import OUTCOMES
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.npz import check_declared_size, write_npz
from uam_fdm.files.strict import strict_json_loads

FLIGHTS_DIR = "training_flights"
TASKS_FILE = "tasks.json"
FORMAT = "uam-compare training flights"
VERSION = 1
_STEP_RE = re.compile(r"^step_(\d{11})\.npz$")
MAX_CHECKPOINT_BYTES = 64 * 2**20
"""A checkpoint file's arrays together, uncompressed, at most [bytes] (a recorded checkpoint holds about 1 MB: 8
flights of at most a few thousand samples). The sizes the file's zip directory and each array's header declare
are checked before any array is read: a small file that inflates to gigabytes (zeros compress a thousandfold) is
refused unread, and no reader holds more than this of one checkpoint."""
HOW_TO_RECORD = ("train it with `uam-compare train` of this version (it records the flights of every checkpoint "
                 "into training_flights/)")


@dataclass(frozen=True, eq=False)
class CityBoxes:
    """A city drawn as boxes.

    Attributes:
        name: the city's name.
        bounds_min_m, bounds_max_m: the flight volume's corners (ENU metres).
        boxes: (B, 6) per building: centre x, y [m], size along its own x, y [m], roof height [m], yaw [rad].
    """

    name: str
    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]
    boxes: np.ndarray


@dataclass(frozen=True)
class RecordedTask:
    """One of the fixed tasks every checkpoint flies.

    Attributes:
        city: index into `FlightTasks.cities`; leg: "short" or "long".
        start_m, goal_m: ENU metres; goal_radius_m [m]; timeout_s [s]; start_yaw_rad [rad].
        turbulence: the turbulence level's name; elevation_m, isa_offset_k: the field's atmosphere.
        wind_m_s: steady wind (east, north, up) [m/s].
    """

    city: int
    leg: str
    start_m: tuple[float, float, float]
    goal_m: tuple[float, float, float]
    goal_radius_m: float
    timeout_s: float
    start_yaw_rad: float
    turbulence: str
    elevation_m: float
    isa_offset_k: float
    wind_m_s: tuple[float, float, float]


@dataclass(frozen=True)
class FlightTasks:
    """tasks.json: the fixed tasks, the rule that chose them and the cities they are flown in.

    Attributes:
        rule: how the tasks were chosen (words, for the reader of the page).
        seed: the training run's seed they were drawn from.
        control_hz: the samples' rate [Hz]; vehicle: its preset name; collision_radius_m [m].
    """

    rule: str
    seed: int
    control_hz: float
    vehicle: str
    collision_radius_m: float
    tasks: tuple[RecordedTask, ...]
    cities: tuple[CityBoxes, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "rule": self.rule, "seed": self.seed,
                "control_hz": self.control_hz, "vehicle": self.vehicle, "collision_radius_m": self.collision_radius_m,
                "tasks": [vars(t) | {"start_m": list(t.start_m), "goal_m": list(t.goal_m),
                                     "wind_m_s": list(t.wind_m_s), "elevation_m": _known(t.elevation_m),
                                     "isa_offset_k": _known(t.isa_offset_k)} for t in self.tasks],
                "cities": [{"name": c.name, "bounds_min_m": list(c.bounds_min_m), "bounds_max_m": list(c.bounds_max_m),
                            "boxes": np.round(c.boxes, 3).tolist()} for c in self.cities]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FlightTasks:
        """From tasks.json's object (KeyError, TypeError, ValueError when it is not one; a number that is not
        finite is named by its key, e.g. "tasks[3].timeout_s"; an unknown field's atmosphere is null).
        """
        if d.get("format") != FORMAT or d.get("version") != VERSION:
            raise ValueError(f"not version {VERSION} of the {FORMAT!r} format")
        cities = tuple(CityBoxes(str(c["name"]), _triple(c["bounds_min_m"], f"cities[{i}].bounds_min_m"),
                                 _triple(c["bounds_max_m"], f"cities[{i}].bounds_max_m"),
                                 _boxes(c["boxes"], f"cities[{i}].boxes")) for i, c in enumerate(d["cities"]))

        def task(k: int, t: dict[str, Any]) -> RecordedTask:
            def real(key: str) -> float:
                return _finite(t[key], f"tasks[{k}].{key}")

            def triple(key: str) -> tuple[float, float, float]:
                return _triple(t[key], f"tasks[{k}].{key}")

            air = {key: float("nan") if t[key] is None else float(t[key]) for key in ("elevation_m", "isa_offset_k")}
            for key, v in air.items():  # NaN: written so before unknown fields were null
                if math.isinf(v):
                    raise ValueError(f"tasks[{k}].{key} must be a finite number or null, got {t[key]!r}")
            return RecordedTask(_integer(t["city"], f"tasks[{k}].city"), str(t["leg"]), triple("start_m"),
                                triple("goal_m"), real("goal_radius_m"), real("timeout_s"), real("start_yaw_rad"),
                                str(t["turbulence"]), air["elevation_m"], air["isa_offset_k"], triple("wind_m_s"))

        tasks = tuple(task(k, t) for k, t in enumerate(d["tasks"]))
        if not tasks or any(not 0 <= t.city < len(cities) for t in tasks):
            raise ValueError("no tasks, or a task names a city that is not listed")
        control_hz = _finite(d["control_hz"], "control_hz")
        if control_hz <= 0:
            raise ValueError(f"control_hz must be positive, got {control_hz!r}")
        return cls(str(d["rule"]), _integer(d["seed"], "seed"), control_hz, str(d["vehicle"]),
                   _finite(d["collision_radius_m"], "collision_radius_m"), tasks, cities)


@dataclass(frozen=True, eq=False)
class Flight:
    """One task flown by one checkpoint (samples at the control rate from t = 0).

    Attributes:
        task: index into `FlightTasks.tasks`; outcome: how it ended (`uam_fdm.episode.Outcome` values).
        time_s: when it ended [s]; min_clearance_m: the least clearance of its samples [m].
        pos_m, vel_m_s: (T, 3) float32 position [m] and velocity [m/s], ENU; clearance_m: (T,) float32 [m].
    """

    task: int
    outcome: str
    time_s: float
    min_clearance_m: float
    pos_m: np.ndarray
    vel_m_s: np.ndarray
    clearance_m: np.ndarray


@dataclass(frozen=True, eq=False)
class CheckpointFlights:
    """One checkpoint's flights of the fixed tasks, and the policy that flew them.

    Attributes:
        timesteps: decisions trained when the checkpoint flew.
        flights: one per task, in task order.
        actor: the actor's weights by SB3 parameter name (float32), empty when not stored.
        obs_norm: the observation statistics it flew with (None when not stored).
    """

    timesteps: int
    flights: tuple[Flight, ...]
    actor: dict[str, np.ndarray] = field(default_factory=dict)
    obs_norm: ObsNorm | None = None


def flights_dir(policy_dir: Path | str) -> Path:
    """A policy folder's training flights folder."""
    return Path(policy_dir) / FLIGHTS_DIR


def checkpoint_file(policy_dir: Path | str, timesteps: int) -> Path:
    """The file of the checkpoint recorded after `timesteps` decisions."""
    return flights_dir(policy_dir) / f"step_{int(timesteps):011d}.npz"


def tasks_text(tasks: FlightTasks) -> str:
    """tasks.json's text (the same tasks give the same text)."""
    return json.dumps(tasks.to_dict(), indent=1, sort_keys=True) + "\n"


def write_tasks(policy_dir: Path | str, tasks: FlightTasks) -> Path:
    """Write tasks.json (atomic; no link in the policy folder followed); returns its path."""
    return write_text_atomic(flights_dir(policy_dir) / TASKS_FILE, tasks_text(tasks), root=policy_dir)


def write_checkpoint(policy_dir: Path | str, ckpt: CheckpointFlights) -> Path:
    """Write one checkpoint's file (reproducibly: the same flights give the same bytes; no link in the policy
    folder followed); returns its path."""
    fl = ckpt.flights
    lengths = [len(f.pos_m) for f in fl]
    arrays: dict[str, np.ndarray] = {
        "timesteps": np.array(ckpt.timesteps, dtype=np.int64),
        "task": np.array([f.task for f in fl], dtype=np.int64),
        "outcome": np.array([str(f.outcome) for f in fl], dtype="<U16"),
        "time_s": np.array([f.time_s for f in fl], dtype=np.float64),
        "min_clearance_m": np.array([f.min_clearance_m for f in fl], dtype=np.float64),
        "offsets": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        "pos_m": np.concatenate([f.pos_m for f in fl]).astype(np.float32).reshape(-1, 3),
        "vel_m_s": np.concatenate([f.vel_m_s for f in fl]).astype(np.float32).reshape(-1, 3),
        "clearance_m": np.concatenate([f.clearance_m for f in fl]).astype(np.float32).reshape(-1),
    }
    for name in sorted(ckpt.actor):
        arrays[f"actor/{name}"] = np.asarray(ckpt.actor[name], dtype=np.float32)
    if ckpt.obs_norm is not None:
        for k in OBS_NORM_KEYS:
            arrays[f"obs_norm/{k}"] = np.asarray(getattr(ckpt.obs_norm, k), dtype=np.float64)
    return write_npz(checkpoint_file(policy_dir, ckpt.timesteps), arrays, root=policy_dir)


@dataclass(frozen=True)
class TrainingFlights:
    """A policy folder's recorded training flights: the fixed tasks and the checkpoints that flew them.

    Attributes:
        folder: the policy folder; tasks: tasks.json; steps: the recorded checkpoints' timesteps, ascending.
    """

    folder: Path
    tasks: FlightTasks
    steps: tuple[int, ...]

    @classmethod
    def open(cls, policy_dir: Path | str) -> TrainingFlights:
        """The training flights of `policy_dir`.

        Raises:
            ValueError: one line naming the folder when it has no recorded flights (and how to get them), or
                naming tasks.json when it cannot be read.
        """
        folder = Path(policy_dir)
        d = flights_dir(folder)
        steps = sorted(int(m.group(1)) for p in (d.iterdir() if d.is_dir() else ())
                       if (m := _STEP_RE.match(p.name)))
        if not (d / TASKS_FILE).is_file() or not steps:
            raise ValueError(f"{folder}: no training flights recorded ({FLIGHTS_DIR}/ is missing or empty); "
                             f"{HOW_TO_RECORD}")
        path = d / TASKS_FILE
        try:
            tasks = FlightTasks.from_dict(strict_json_loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"{path}: not a training-flights task list ({exc})") from None
        return cls(folder, tasks, tuple(steps))

    def checkpoint(self, timesteps: int) -> CheckpointFlights:
        """The flights of the checkpoint at `timesteps` (read without unpickling, checked).

        Raises:
            ValueError: the file is missing or malformed, naming it and what is wrong.
        """
        return read_checkpoint(checkpoint_file(self.folder, timesteps), len(self.tasks.tasks))


def read_checkpoint(path: Path, n_tasks: int) -> CheckpointFlights:
    """One checkpoint file of a folder whose tasks.json lists `n_tasks` tasks.

    Raises:
        ValueError: the file is missing, unreadable, holds objects, would inflate past `MAX_CHECKPOINT_BYTES`, or
            its arrays do not fit together (more flights than tasks among them).
    """
    check_declared_size(path, MAX_CHECKPOINT_BYTES)
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: np.array(z[k]) for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{path}: unreadable ({exc})") from None

    def need(k: str) -> np.ndarray:
        if k not in a:
            raise ValueError(f"{path}: array {k!r} is missing")
        return a[k]

    task, offsets = need("task").astype(np.int64), need("offsets").astype(np.int64)
    outcome, time_s, min_c = need("outcome"), need("time_s").astype(float), need("min_clearance_m").astype(float)
    pos, vel, clear = need("pos_m"), need("vel_m_s"), need("clearance_m")
    f = len(task)
    if f > n_tasks:  # one flight per task: more would each cost the page a row, whatever tasks.json says
        raise ValueError(f"{path}: {f:,} flights, but tasks.json lists {n_tasks} tasks (one flight per task)")
    if (outcome.shape != (f,) or time_s.shape != (f,) or min_c.shape != (f,) or offsets.shape != (f + 1,)
            or offsets[0] != 0 or np.any(np.diff(offsets) < 1) or pos.ndim != 2 or pos.shape[1] != 3
            or vel.shape != pos.shape or clear.shape != (len(pos),) or offsets[-1] != len(pos)):
        raise ValueError(f"{path}: its arrays do not fit together (flights, offsets and samples)")
    if np.any(task < 0) or np.any(task >= n_tasks):
        raise ValueError(f"{path}: a flight names a task that tasks.json does not list")
    for key, values in (("pos_m", pos), ("vel_m_s", vel), ("time_s", time_s), ("min_clearance_m", min_c)):
        if not np.isfinite(values.astype(float)).all():
            raise ValueError(f"{path}: array {key!r} has non-finite values")
    known = {str(o) for o in OUTCOMES}
    bad = next((str(o) for o in outcome if str(o) not in known), None)
    if bad is not None:
        raise ValueError(f"{path}: unknown outcome {bad[:40]!r}")
    flights = tuple(Flight(int(task[i]), str(outcome[i]), float(time_s[i]), float(min_c[i]),
                           pos[offsets[i]:offsets[i + 1]].astype(np.float32),
                           vel[offsets[i]:offsets[i + 1]].astype(np.float32),
                           clear[offsets[i]:offsets[i + 1]].astype(np.float32)) for i in range(f))
    actor = {k[len("actor/"):]: v.astype(np.float32) for k, v in a.items() if k.startswith("actor/")}
    broken = next((k for k, v in a.items() if k.startswith(("actor/", "obs_norm/")) and not np.isfinite(v).all()),
                  None)
    if broken is not None:  # the checkpoint can be flown again (`rl.pilots.learned.load_checkpoint_policy`)
        raise ValueError(f"{path}: array {broken!r} has non-finite values")
    norm = None
    if all(f"obs_norm/{k}" in a for k in OBS_NORM_KEYS):
        n = {k: a[f"obs_norm/{k}"].astype(np.float64) for k in OBS_NORM_KEYS}
        norm = ObsNorm(n["mean"], n["var"], float(n["count"]), float(n["epsilon"]), float(n["clip_obs"]))
    return CheckpointFlights(int(need("timesteps")), flights, actor, norm)


def _known(v: float) -> float | None:
    """A number for tasks.json: None (null) when not known (NaN), as JSON has no NaN."""
    return None if math.isnan(v) else v


def _finite(v: Any, key: str) -> float:
    """`v` as a finite float, else a ValueError naming `key`."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{key} must be a finite number, got {str(v)[:60]}")
    return float(v)


def _integer(v: Any, key: str) -> int:
    """`v` as an int (a JSON integer), else a ValueError naming `key`."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"{key} must be an integer, got {str(v)[:60]}")
    return v


def _triple(v: Any, key: str) -> tuple[float, float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise ValueError(f"{key} must be three numbers, got {str(v)[:60]}")
    return (_finite(v[0], key), _finite(v[1], key), _finite(v[2], key))


def _boxes(v: Any, key: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1, 6) if len(v) else np.zeros((0, 6))
    if not np.isfinite(a).all():
        raise ValueError(f"{key} holds non-finite numbers")
    return a
