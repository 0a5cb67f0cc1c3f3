"""Saved episodes: an episode's key, its metadata and the `.npz` file of a run saved before the run store.

A run now keeps its episodes in the store (`compare.results.store`, `compare.results.tables`), whose
episode table holds this module's metadata JSON; a run folder of the store's predecessors holds one `.npz`
per (scenario, episode, pilot, seed) at the physics rate, which `load_episode` reads (and `save_episode`
still writes, for tests and the storage benchmark). A saved episode holds the runner's `Trajectory` arrays
plus what the metrics and the report need to read it without the world that produced it (task, vehicle,
map name, outcome, the pilot's end-of-episode report). Files are written under a temporary name in the same
folder and renamed, so an interrupted run never leaves a half-written episode.

The metadata is JSON inside the file; `meta_to_json` writes it and `meta_from_json` reads it, and
nothing else touches it. The run's context and the pilot's report sit under "extra" (the report as
"tracker", the name the classical pilot's report was first saved under); a file saved before the
report existed keeps the classical pilot's few counters at the top of "extra", read into its report.
"""
from __future__ import annotations

import io
import json
import re
import zipfile
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from compare.flying import pilots
from compare.flying.episode_loop import Trajectory
from uam_fdm.episode import Outcome
from uam_fdm.files.atomic import atomic_open
from uam_fdm.files.strict import strict_json_loads
from uam_fdm.pilot import PilotReport

FORMAT_VERSION = 1
_ARRAYS = ("t_s", "states", "rotor_commands", "wind_enu_m_s", "clearance_m", "decision_t_s", "compute_s")
# Arrays added after format 1 was fixed: absent from older files (None when loaded), so files of either age
# read with either code.
_OPTIONAL_ARRAYS = ("shaft_power_W",)
_STEM = re.compile(r"^(?P<scenario>.+)__ep(?P<episode>\d+)__(?P<pilot>.+)__s(?P<seed>-?\d+)$")
_COMPONENT = re.compile(r"[A-Za-z0-9_.:-]+")  # scenario names (the loader's rule) and pilot names (plug-ins too)
MAX_STEM_BYTES = 200  # an episode's file name, with its suffixes, within the 255 bytes a file system allows


@dataclass(frozen=True)
class EpisodeKey:
    """Which cell of the comparison an episode is: scenario, episode index, pilot and seed.

    `method` is the pilot's name: the field keeps the name it is written under (the key of an episode file's
    meta, of a failed cell's record, the store's and metrics.csv's column), which scripts read.
    """

    scenario: str
    episode: int
    method: str
    seed: int

    def __post_init__(self) -> None:
        # the key names files (episode parts, videos, maps/<scenario>.yaml): whatever a file says, it stays one
        # plain component inside the run folder
        for field, value in (("scenario", self.scenario), ("method", self.method)):
            if not (isinstance(value, str) and _COMPONENT.fullmatch(value) and not value.startswith(".")):
                raise ValueError(f"{field} {str(value)[:80]!r}: not a name this tool writes (letters, digits and "
                                 f"_ . : - only, not starting with a dot)")
        if len(self.stem.encode()) > MAX_STEM_BYTES:
            raise ValueError(f"episode {self.stem[:80]!r}...: its file name would be longer than "
                             f"{MAX_STEM_BYTES} bytes")

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
        key = cls(m["scenario"], int(m["episode"]), m["pilot"], int(m["seed"]))
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
        outcome: how it ended (a name is read as its `Outcome`; an unknown one is an error naming the episode).
        plan_time_s: planning time of the episode [s]: the pilot's report's when it gives one (at reset
            and every replan), else the runner's measure around reset.
        detail: why the episode ended.
        wind_seed, agent_seed: the seeds of the episode's wind and of its pilot (None: not recorded).
        mean_decision_ms: the mean wall time per decision [ms] (None: no decision).
        failure_reason: a more specific reason for a failure than the outcome, from the pilot's report
            (e.g. `Outcome.SOLVER_FAILURE`), else None.
        vehicle_fingerprint: the vehicle's parameters' fingerprint (`VehicleParams.fingerprint`; "" in files saved
            before it was recorded): two vehicles that share a name are told apart by it.
        report: the pilot's end-of-episode report (`uam_fdm.pilot.PilotReport`; its type is the
            pilot's `compare.flying.pilots.PilotEntry.report_type`), None when it gives none.
        sensing, map_error: the labels of the scenario's sensing and map-error levels (files saved before they
            existed: "perfect", "exact").
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
    outcome: Outcome
    plan_time_s: float
    detail: str = ""
    wind_seed: int | None = None
    agent_seed: int | None = None
    mean_decision_ms: float | None = None
    failure_reason: Outcome | None = None
    vehicle_fingerprint: str = ""
    report: PilotReport | None = None
    sensing: str = "perfect"
    map_error: str = "exact"

    def __post_init__(self) -> None:
        where = f"episode {self.key.stem}"
        object.__setattr__(self, "outcome", Outcome.parse(self.outcome, where))
        if self.failure_reason is not None:
            object.__setattr__(self, "failure_reason", Outcome.parse(self.failure_reason, where))


def xyz(values: Iterable[float]) -> tuple[float, float, float]:
    """Three numbers as a tuple of floats (a point such as `EpisodeMeta.start_m`); ValueError unless three."""
    x, y, z = (float(v) for v in values)
    return x, y, z


@dataclass(frozen=True)
class SavedEpisode:
    """A loaded episode: its metadata and its trajectory."""

    meta: EpisodeMeta
    trajectory: Trajectory


def save_episode(path: Path, meta: EpisodeMeta, traj: Trajectory) -> Path:
    """Write one episode to `path` (.npz) atomically; returns the path."""
    return write_episode_bytes(path, episode_bytes(meta, traj))


def episode_bytes(meta: EpisodeMeta, traj: Trajectory) -> bytes:
    """The content of one episode file (what `save_episode` writes), e.g. to send it to another machine."""
    arrays = {name: np.asarray(getattr(traj, name)) for name in _ARRAYS}
    arrays.update({name: np.asarray(getattr(traj, name)) for name in _OPTIONAL_ARRAYS
                   if getattr(traj, name) is not None})
    header = {"format_version": FORMAT_VERSION, "meta": meta_to_json(meta)}
    buffer = io.BytesIO()
    # numpy's stub lets ** fill its allow_pickle: bool; the keys here are the array names only
    np.savez_compressed(buffer, meta_json=np.array(json.dumps(header)), **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def write_episode_bytes(path: Path, data: bytes) -> Path:
    """Write an episode file's content (`episode_bytes`) to `path` atomically; returns the path."""
    path = Path(path)
    with atomic_open(path, "wb") as f:
        f.write(data)
    return path


MAX_EPISODE_BYTES = 2**30
"""Largest episode in memory [bytes] (an hour at 500 Hz takes about 300 MB): a larger file is refused unread."""


def load_episode(path: Path) -> SavedEpisode:
    """Read an episode written by `save_episode`.

    Raises:
        ValueError: the file is not a saved episode (or of a newer format), is truncated or corrupt,
            naming the file.
    """
    path = Path(path)
    if not path.is_file():  # a FIFO or a device named like an episode would block or never end
        raise ValueError(f"{path}: not a saved episode (not a regular file)")
    try:
        with zipfile.ZipFile(path) as archive:  # sizes before anything is inflated: a zip bomb is refused here
            inflated = sum(info.file_size for info in archive.infolist())
        if inflated > MAX_EPISODE_BYTES:
            raise ValueError(f"its arrays would take {inflated / 2**20:,.0f} MiB in memory; at most "
                             f"{MAX_EPISODE_BYTES / 2**20:,.0f} MiB")
        with np.load(path, allow_pickle=False) as z:
            header = strict_json_loads(str(z["meta_json"]))
            arrays = {name: np.array(z[name]) for name in _ARRAYS}
            optional = {name: np.array(z[name]) if name in z.files else None for name in _OPTIONAL_ARRAYS}
    # a truncated or damaged file fails inside zipfile/zlib (BadZipFile, EOFError, zlib.error on a bad CRC)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ValueError(f"{path}: not a saved episode, or truncated or corrupt ({exc})") from exc
    if not isinstance(header, dict) or header.get("format_version") != FORMAT_VERSION:
        version = header.get("format_version") if isinstance(header, dict) else None
        raise ValueError(f"{path}: episode format {version!r}, expected {FORMAT_VERSION}")
    try:
        meta = meta_from_json(header["meta"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a saved episode (its metadata is incomplete: {exc})") from exc
    n = len(arrays["t_s"])
    t_s = arrays["t_s"]
    if t_s.ndim != 1 or t_s.dtype.kind not in "fiu" or not np.all(np.isfinite(t_s)):
        raise ValueError(f"{path}: not a saved episode (its times t_s are not a list of finite numbers)")
    if arrays["states"].ndim != 2 or len(arrays["states"]) != n or len(arrays["clearance_m"]) != n:
        raise ValueError(f"{path}: not a saved episode (time, state and clearance rows disagree)")
    power = optional["shaft_power_W"]
    if power is not None and power.shape != (n,):
        raise ValueError(f"{path}: shaft_power_W has shape {power.shape}, expected ({n},) like t_s")
    columns: dict[str, Any] = dict(arrays)
    traj = Trajectory(**columns, shaft_power_W=power, energy_J=meta.energy_J, outcome=meta.outcome,
                      plan_time_s=meta.plan_time_s, detail=meta.detail)
    return SavedEpisode(meta, traj)


_CONTEXT = ("wind_seed", "agent_seed", "mean_decision_ms")
"""The run's context of an episode, saved under "extra"."""
_REPORT_KEY = "tracker"


def meta_to_json(meta: EpisodeMeta) -> dict[str, Any]:
    """The metadata as JSON-ready data (the one writer; `meta_from_json` reads it back)."""
    extra: dict[str, Any] = {name: getattr(meta, name) for name in _CONTEXT}
    if meta.report is not None:
        extra[_REPORT_KEY] = meta.report.to_json()
    if meta.failure_reason is not None:
        extra["failure_reason"] = meta.failure_reason.value
    if meta.vehicle_fingerprint:
        extra["vehicle_fingerprint"] = meta.vehicle_fingerprint
    for level, plain in (("sensing", "perfect"), ("map_error", "exact")):
        if getattr(meta, level) != plain:  # a file of a run before either existed stays as it was
            extra[level] = getattr(meta, level)
    return {"key": asdict(meta.key), "map_name": meta.map_name, "vehicle": meta.vehicle,
            "start_m": list(meta.start_m), "goal_m": list(meta.goal_m), "goal_radius_m": meta.goal_radius_m,
            "timeout_s": meta.timeout_s, "collision_radius_m": meta.collision_radius_m, "n_rotors": meta.n_rotors,
            "energy_J": meta.energy_J, "outcome": meta.outcome.value, "plan_time_s": meta.plan_time_s,
            "detail": meta.detail, "extra": extra}


def meta_from_json(m: Mapping[str, Any]) -> EpisodeMeta:
    """The metadata `meta_to_json` wrote, or an older file's (the one reader).

    Raises:
        KeyError, TypeError, ValueError: incomplete or malformed metadata.
    """
    key = EpisodeKey(**m["key"])
    extra = m.get("extra") or {}
    if not isinstance(extra, Mapping):
        raise TypeError(f"extra must be a mapping, got {type(extra).__name__}")
    entry = pilots.registered(key.method)  # never a plug-in's import: the file names the pilot
    report_type = entry.report_type if entry is not None else None
    report = None
    if report_type is not None:
        saved = extra.get(_REPORT_KEY)
        report = report_type.from_json(saved if isinstance(saved, Mapping) else extra)  # else: an older file's counters
    context = {name: extra.get(name) for name in _CONTEXT}
    return EpisodeMeta(
        key=key, map_name=m["map_name"], vehicle=m["vehicle"], start_m=xyz(m["start_m"]),
        goal_m=xyz(m["goal_m"]), goal_radius_m=m["goal_radius_m"], timeout_s=m["timeout_s"],
        collision_radius_m=m["collision_radius_m"], n_rotors=m["n_rotors"], energy_J=m["energy_J"],
        outcome=m["outcome"], plan_time_s=m["plan_time_s"], detail=m.get("detail", ""), **context,
        failure_reason=extra.get("failure_reason") or None, report=report,
        vehicle_fingerprint=str(extra.get("vehicle_fingerprint") or ""),
        sensing=_label(extra.get("sensing"), "perfect"), map_error=_label(extra.get("map_error"), "exact"))


def _label(value: Any, default: str) -> str:
    """A level's label read from a file: a short plain word (anything else: the default, so a file's text never
    reaches a page or a path as a label)."""
    if isinstance(value, str) and re.fullmatch(r"[a-z]{1,16}\+?", value):
        return value
    return default


def episode_files(run_dir: Path) -> list[Path]:
    """Saved episodes of a run, sorted by name (temporary files, and anything not a regular file, e.g. a FIFO
    that would block its reader, are ignored)."""
    return sorted(p for p in (Path(run_dir) / "episodes").glob("*.npz") if not p.name.startswith(".")
                  and p.is_file())
