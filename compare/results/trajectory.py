"""Saved episodes: one `.npz` per (scenario, episode, method, seed), written atomically.

A saved episode holds the runner's `Trajectory` arrays plus what the metrics and the report need
to read it without the world that produced it (task, vehicle, map name, outcome). Files are written
under a temporary name in the same folder and renamed, so an interrupted run never leaves a
half-written episode: a file either exists complete or not at all.
"""
from __future__ import annotations

import json
import re
import zipfile
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from compare.episode_loop import Trajectory
from uam_fdm.files.atomic import atomic_open

FORMAT_VERSION = 1
_ARRAYS = ("t_s", "states", "rotor_commands", "wind_enu_m_s", "clearance_m", "decision_t_s", "compute_s")
# Arrays added after format 1 was fixed: absent from older files (None when loaded), so files of either age
# read with either code.
_OPTIONAL_ARRAYS = ("shaft_power_W",)
_STEM = re.compile(r"^(?P<scenario>.+)__ep(?P<episode>\d+)__(?P<method>.+)__s(?P<seed>-?\d+)$")


@dataclass(frozen=True)
class EpisodeKey:
    """Which cell of the comparison an episode is: scenario, episode index, method and seed."""

    scenario: str
    episode: int
    method: str
    seed: int

    @property
    def stem(self) -> str:
        """File stem, e.g. `default-suburb__ep003__ppo__s0`."""
        return f"{self.scenario}__ep{self.episode:03d}__{self.method}__s{self.seed}"

    @classmethod
    def from_stem(cls, stem: str) -> EpisodeKey | None:
        """The key whose `stem` is `stem`, or None when `stem` is not one (a file named otherwise)."""
        m = _STEM.match(stem)
        if m is None:
            return None
        key = cls(m["scenario"], int(m["episode"]), m["method"], int(m["seed"]))
        return key if key.stem == stem else None  # e.g. "ep7" is not written by `stem` (it pads to "ep007")


@dataclass(frozen=True)
class EpisodeMeta:
    """What is needed to score and draw an episode without rebuilding its world.

    Attributes:
        key: the comparison cell.
        map_name: the city's name (the map itself is saved once per scenario by the runner).
        vehicle: vehicle preset name.
        start_m, goal_m: task endpoints, world ENU [m].
        goal_radius_m: success radius [m]; timeout_s: time limit [s].
        collision_radius_m: the vehicle's collision sphere [m].
        n_rotors: rotor count (to split the state vector).
        energy_J: rotor shaft energy over the flight [J].
        outcome: one of `compare.episode_loop.OUTCOMES`.
        plan_time_s: planning time reported by the agent at reset [s].
        detail: why the episode ended.
        extra: method-specific counters (e.g. MPC failures), JSON-serialisable.
    """

    key: EpisodeKey
    map_name: str
    vehicle: str
    start_m: tuple[float, float, float]
    goal_m: tuple[float, float, float]
    goal_radius_m: float
    timeout_s: float
    collision_radius_m: float
    n_rotors: int
    energy_J: float
    outcome: str
    plan_time_s: float
    detail: str = ""
    extra: dict | None = None


@dataclass(frozen=True)
class SavedEpisode:
    """A loaded episode: its metadata and its trajectory."""

    meta: EpisodeMeta
    trajectory: Trajectory


def save_episode(path: Path, meta: EpisodeMeta, traj: Trajectory) -> Path:
    """Write one episode to `path` (.npz) atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {name: np.asarray(getattr(traj, name)) for name in _ARRAYS}
    arrays.update({name: np.asarray(getattr(traj, name)) for name in _OPTIONAL_ARRAYS
                   if getattr(traj, name) is not None})
    header = {"format_version": FORMAT_VERSION, "meta": asdict(meta)}
    with atomic_open(path, "wb") as f:
        np.savez_compressed(f, meta_json=np.array(json.dumps(header)), **arrays)
    return path


def load_episode(path: Path) -> SavedEpisode:
    """Read an episode written by `save_episode`.

    Raises:
        ValueError: the file is not a saved episode (or of a newer format), is truncated or corrupt,
            naming the file.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["meta_json"]))
            arrays = {name: np.array(z[name]) for name in _ARRAYS}
            arrays.update({name: np.array(z[name]) if name in z.files else None for name in _OPTIONAL_ARRAYS})
    # a truncated or damaged file fails inside zipfile/zlib (BadZipFile, EOFError, zlib.error on a bad CRC)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ValueError(f"{path}: not a saved episode, or truncated or corrupt ({exc})") from exc
    if not isinstance(header, dict) or header.get("format_version") != FORMAT_VERSION:
        version = header.get("format_version") if isinstance(header, dict) else None
        raise ValueError(f"{path}: episode format {version!r}, expected {FORMAT_VERSION}")
    try:
        m = dict(header["meta"])
        m["key"] = EpisodeKey(**m["key"])
        for k in ("start_m", "goal_m"):
            m[k] = tuple(float(v) for v in m[k])
        meta = EpisodeMeta(**m)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a saved episode (its metadata is incomplete: {exc})") from exc
    n = len(arrays["t_s"])
    if arrays["states"].ndim != 2 or len(arrays["states"]) != n or len(arrays["clearance_m"]) != n:
        raise ValueError(f"{path}: not a saved episode (time, state and clearance rows disagree)")
    power = arrays["shaft_power_W"]
    if power is not None and power.shape != (n,):
        raise ValueError(f"{path}: shaft_power_W has shape {power.shape}, expected ({n},) like t_s")
    traj = Trajectory(**arrays, energy_J=meta.energy_J, outcome=meta.outcome, plan_time_s=meta.plan_time_s,
                      detail=meta.detail)
    return SavedEpisode(meta, traj)


def episode_files(run_dir: Path) -> list[Path]:
    """Saved episodes of a run, sorted by name (temporary files are ignored)."""
    return sorted(p for p in (Path(run_dir) / "episodes").glob("*.npz") if not p.name.startswith("."))
