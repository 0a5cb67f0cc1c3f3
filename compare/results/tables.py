"""An episode as rows of the run store's two tables: its row of the episode table and its samples.

The episode table has one row per episode: the cell (scenario, episode, method, seed), every column of
`metrics.csv` (computed in the cell from the physics-rate flight, before anything is thinned), the conditions
it flew in (`EpisodeConditions`), the episode's metadata as JSON (`meta_json`, the same JSON an `.npz` episode
file holds, read back by the one reader in `compare.results.trajectory`), and where its samples are.

The samples table has one row per kept sample of the flight: the cell again (so a query can join or filter
without the episode table), time, state, rotor commands, wind, clearance, shaft power, and at the rows where
the pilot decided, the decision's time and its compute time. Which rows are kept (`kept_rows`):

* "control" (the default): the control rate (row 0, then the end of every control period: 50 Hz in the
  shipped scenarios, everything the report, viewer and animation draw) plus the physics-rate row of least
  clearance (so a drawn minimum is the flight's), with each number rounded to a stated power-of-two quantum
  (`QUANTA`: the low mantissa bits become zeros, which the compression then removes);
* "full": every physics-rate row, numbers unrounded.

Types: time, position and the decision times float64 (a float32 time would drift by 0.2 ms after an hour,
and a float32 position holds only ~6 cm ±1,000 km from the origin a flight volume may sit at); every other
sample float32 (velocity, quaternion, body rates, rotor speeds and commands, wind, clearance, power, compute
time: at least 6 significant digits, far below what the pages show).
"""
from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import astuple, dataclass, fields
from typing import Any

import numpy as np
import pyarrow as pa

from compare.flying.episode_loop import ROTOR_SPEEDS, DecisionRecord, Trajectory
from compare.results.metrics import MAPPING_METRICS, SENSING_METRICS, EpisodeMetrics
from compare.results.store_schema import CONDITION_COLUMNS as CONDITION_SPECS
from compare.results.store_schema import DECISION_COLUMNS, EPISODE_COLUMNS, SAMPLE_COLUMNS, schema_of
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode, meta_from_json, meta_to_json
from uam_fdm.files.strict import strict_json_loads

STORE_MODES = ("control", "full")
"""Sample rates a run can store: the control rate (default) or the physics rate (`--store full`)."""

QUANTA: dict[str, int] = {
    "position": 10, "velocity": 10, "quaternion": 16, "body_rates": 12, "rotors": 6, "wind": 10, "power": 4,
    "heading": 16, "observation": 12}
"""Sample quantum as a power of two, 2**-k, per group of columns in "control" mode: position and velocity
2^-10 m, m/s (~1 mm, mm/s), quaternion 2^-16 (1.5e-5), body rates 2^-12 rad/s, rotor speeds and commands
2^-6 rad/s (0.016 rad/s of hundreds), wind 2^-10 m/s, shaft power 2^-4 W; a decision's command as its kind's
(rotor speeds, velocity) and its heading 2^-16 rad; the pilots' observation vectors 2^-12 (the learned pilot's
features lie in [-1, 1], their training spread at least 0.16: 0.15 % of it). Clearance is kept at float32 (the
viewer states the least clearance to the millimetre). Times are never rounded."""

KEY_COLUMNS = ("scenario", "episode", "method", "seed")
POSITION = ("x_m", "y_m", "z_m")
VELOCITY = ("vx_m_s", "vy_m_s", "vz_m_s")
QUATERNION = ("qw", "qx", "qy", "qz")
BODY_RATES = ("wx_rad_s", "wy_rad_s", "wz_rad_s")
WIND = ("wind_e_m_s", "wind_n_m_s", "wind_u_m_s")
ROTOR_SPEED, ROTOR_COMMAND = "rotor_speed_rad_s", "rotor_command_rad_s"
ESTIMATE = ("est_x_m", "est_y_m", "est_z_m")
LIDAR_HITS = "lidar_hits_m"

_F32 = pa.float32()

SAMPLE_SCHEMA = schema_of(SAMPLE_COLUMNS)
"""One row per kept sample (see the module docstring; every column's unit, frame and meaning:
`compare.results.store_schema.SAMPLE_COLUMNS`): world ENU [m, m/s], body FLU [rad/s], quaternion body -> world
[w, x, y, z]. shaft_power_w is null in an episode saved before it was recorded; decision_t_s, compute_s and the
decision's command (action_kind, action, action_hold_periods, and the pilot's observation vector where it has one)
are null except at the row where the pilot decided (the start of that control period). est_*_m: the navigation
estimate's position (null at perfect sensing: it is the truth); lidar_hits_m: at the first kept row at or after each
lidar scan, a thinned set of its true hit points, flattened [x, y, z, ...] world ENU (null elsewhere and at perfect
sensing)."""
SAMPLE_SCHEMA_BEFORE_DECISIONS = pa.schema([f for f in SAMPLE_SCHEMA if f.name not in
                                            {c.name for c in DECISION_COLUMNS}])
"""The samples of a store written before the decisions' commands were recorded: read, those columns null."""
SAMPLE_SCHEMA_BEFORE_SENSING = pa.schema([f for f in SAMPLE_SCHEMA_BEFORE_DECISIONS if f.name not in
                                          (*ESTIMATE, LIDAR_HITS)])
"""The samples of a store written before the vehicle sensed: read, the sensing columns null."""
_OLDER_SAMPLES = (SAMPLE_SCHEMA_BEFORE_SENSING, SAMPLE_SCHEMA_BEFORE_DECISIONS)


def upgraded_samples(table: pa.Table) -> pa.Table:
    """A samples table of a store written before the vehicle sensed or before the decisions' commands were
    recorded, with the columns it lacks added as nulls (any other table is returned as it is, for the caller's
    schema check)."""
    if not any(table.schema.remove_metadata().equals(s) for s in _OLDER_SAMPLES):
        return table
    for f in SAMPLE_SCHEMA:
        if f.name not in table.column_names:
            table = table.append_column(f, pa.nulls(table.num_rows, f.type))
    return table


@dataclass(frozen=True)
class EpisodeConditions:
    """The air and city an episode flew in (the episode table's condition columns).

    Attributes:
        field_density_kg_m3: air density at the field [kg/m³] (run.json's, rounded to 4 decimals).
        density_altitude_m: the ISA altitude of that density [m].
        turbulence: the turbulence level's name.
        steady_wind_enu_m_s: the steady wind at its reference height, world ENU [m/s].
        building_coverage: share of the map's ground area under building footprints, in [0, 1].
    """

    field_density_kg_m3: float
    density_altitude_m: float
    turbulence: str
    steady_wind_enu_m_s: tuple[float, float, float]
    building_coverage: float


METRIC_COLUMNS = tuple(f.name for f in fields(EpisodeMetrics))
CONDITION_COLUMNS = tuple(c.name for c in CONDITION_SPECS)

_ADDED_WITH_SENSING = ("sensing", "map_error", *SENSING_METRICS, *MAPPING_METRICS)
EPISODE_SCHEMA = schema_of(EPISODE_COLUMNS)
"""One row per episode: the metrics.csv columns (same names and order), the conditions (null where not
recorded), how its samples were kept ("control" or "full") and how many, the file of the run store holding them
(relative to the store folder) and the first of them there, and the episode's metadata as JSON (every column:
`compare.results.store_schema.EPISODE_COLUMNS`)."""
EPISODE_SCHEMA_BEFORE_SENSING = pa.schema([f for f in EPISODE_SCHEMA if f.name not in _ADDED_WITH_SENSING])
"""The episode table of a store written before the vehicle sensed: read, its rows given the metrics' defaults."""


def upgraded_episodes(table: pa.Table) -> pa.Table:
    """An episode table of a store written before some of the sensing columns existed (`sensing`, `map_error`,
    `SENSING_METRICS`), with the missing ones added at the metrics' defaults (perfect sensing, an exact map, NaN), in
    `EPISODE_SCHEMA`'s order; any other table is returned as it is, for the caller's schema check."""
    have = table.schema.remove_metadata()
    missing = [n for n in EPISODE_SCHEMA.names if n not in have.names]
    if (not missing or not set(missing) <= set(_ADDED_WITH_SENSING) or len(set(have.names)) != len(have.names)
            or any(f.name not in EPISODE_SCHEMA.names or not EPISODE_SCHEMA.field(f.name).equals(f) for f in have)):
        return table
    defaults = {f.name: f.default for f in fields(EpisodeMetrics)}
    for name in missing:
        field = EPISODE_SCHEMA.field(name)
        table = table.append_column(field, pa.array([defaults[name]] * table.num_rows, field.type))
    return table.select(list(EPISODE_SCHEMA.names))


def with_metric_defaults(row: dict[str, Any]) -> dict[str, Any]:
    """An episode-table row with the columns a store written before the vehicle sensed lacks, at the metrics'
    defaults (perfect sensing, an exact map)."""
    for f in fields(EpisodeMetrics):
        if f.name in _ADDED_WITH_SENSING and f.name not in row:
            row[f.name] = f.default
    return row


def kept_rows(traj: Trajectory, mode: str, period_rows: int) -> np.ndarray:
    """Indices of the trajectory rows a store keeps (sorted, unique).

    Args:
        traj: the physics-rate flight.
        mode: "control" (row 0, every `period_rows`-th row, the last row and the least-clearance row) or "full".
        period_rows: physics steps per control period.
    """
    n = len(traj.t_s)
    if mode == "full" or n == 0:
        return np.arange(n)
    if mode != "control":
        raise ValueError(f"store {mode!r}: choose from {', '.join(STORE_MODES)}")
    clear = np.asarray(traj.clearance_m, float)
    least = [int(np.nanargmin(clear))] if np.any(np.isfinite(clear)) else []
    return np.unique(np.concatenate([np.arange(0, n, max(1, int(period_rows))), [n - 1], least])).astype(np.int64)


def _quantized(values: np.ndarray, group: str, mode: str) -> np.ndarray:
    """`values` rounded to the group's quantum in "control" mode (non-finite values kept as they are)."""
    if mode != "control":
        return values
    scale = 2.0 ** QUANTA[group]
    with np.errstate(invalid="ignore", over="ignore"):
        return np.where(np.isfinite(values), np.round(values * scale) / scale, values)


def samples_table(key: EpisodeKey, traj: Trajectory, n_rotors: int, mode: str, period_rows: int) -> pa.Table:
    """The samples of one flight (`SAMPLE_SCHEMA`), thinned and rounded as `mode` says."""
    rows = kept_rows(traj, mode, period_rows)
    t = np.asarray(traj.t_s, float)[rows]
    x = np.asarray(traj.states, float)[rows]
    m = len(rows)

    def f32(values: np.ndarray, group: str | None) -> pa.Array:
        return pa.array((values if group is None else _quantized(values, group, mode)).astype(np.float32))

    def rotor_lists(values: np.ndarray) -> pa.Array:
        flat = f32(np.ascontiguousarray(values, dtype=float).reshape(-1), "rotors")
        return pa.ListArray.from_arrays(pa.array(np.arange(0, m * n_rotors + 1, n_rotors, dtype=np.int32)), flat)

    cols: dict[str, Any] = {
        "scenario": pa.array([key.scenario] * m, pa.string()), "episode": pa.array(np.full(m, key.episode, np.int32)),
        "method": pa.array([key.method] * m, pa.string()), "seed": pa.array(np.full(m, key.seed, np.int64)),
        "t_s": pa.array(t)}
    for i, name in enumerate(POSITION):
        cols[name] = pa.array(_quantized(x[:, i], "position", mode))
    for names, first, group in ((VELOCITY, 3, "velocity"), (QUATERNION, 6, "quaternion"),
                                (BODY_RATES, 10, "body_rates")):
        for i, name in enumerate(names):
            cols[name] = f32(x[:, first + i], group)
    cols[ROTOR_SPEED] = rotor_lists(x[:, 13:13 + n_rotors])
    cols[ROTOR_COMMAND] = rotor_lists(np.asarray(traj.rotor_commands, float)[rows])
    wind = np.asarray(traj.wind_enu_m_s, float)[rows]
    for i, name in enumerate(WIND):
        cols[name] = f32(wind[:, i], "wind")
    cols["clearance_m"] = f32(np.asarray(traj.clearance_m, float)[rows], None)
    power = traj.shaft_power_W
    cols["shaft_power_w"] = pa.nulls(m, _F32) if power is None else f32(np.asarray(power, float)[rows], "power")
    on_rows = _decision_rows(t, np.asarray(traj.decision_t_s, float))
    decided_t, compute = np.full(m, np.nan), np.full(m, np.nan)
    decided_t[on_rows], compute[on_rows] = traj.decision_t_s, traj.compute_s
    cols["decision_t_s"] = pa.array(decided_t, pa.float64(), from_pandas=True)
    cols["compute_s"] = pa.array(compute.astype(np.float32), _F32, from_pandas=True)
    est = traj.estimate_m
    for i, name in enumerate(ESTIMATE):
        cols[name] = pa.nulls(m, pa.float64()) if est is None else pa.array(
            _quantized(np.asarray(est, float)[rows, i], "position", mode))
    cols[LIDAR_HITS] = _lidar_on_rows(t, traj.lidar_hits_m)
    cols.update(_commands_on_rows(m, on_rows, traj.decisions, mode))
    return pa.table(cols, schema=SAMPLE_SCHEMA)


def _commands_on_rows(m: int, on_rows: np.ndarray, record: DecisionRecord | None, mode: str) -> dict[str, pa.Array]:
    """The decision columns (`store_schema.DECISION_COLUMNS`) of `m` rows: each decision's command, hold and
    observation on its row `on_rows[i]` (increasing; in "control" mode rounded to `QUANTA`: a command as its kind's
    samples, an observation to 2^-12), null elsewhere; all null for an episode recorded without them."""
    kind: list[str | None] = [None] * m
    if record is None:
        nulls = pa.nulls(m, pa.list_(_F32))
        return {"action_kind": pa.array(kind, pa.string()), "action": nulls,
                "action_hold_periods": pa.nulls(m, pa.int32()), "observation": nulls}
    if len(record.commands) != len(on_rows):
        raise ValueError(f"{len(record.commands)} recorded commands for {len(on_rows)} decisions")
    hold = np.zeros(m, np.int32)
    hold[on_rows] = record.hold_periods
    for r, k in zip(on_rows, record.kinds):
        kind[r] = k
    rotor = np.array([k == ROTOR_SPEEDS for k in record.kinds], bool)
    action, sizes = _flat(record.commands)
    at = np.arange(len(action)) - np.repeat(np.cumsum(sizes) - sizes, sizes)  # each value's index in its command
    quantum = np.where(np.repeat(rotor, sizes), QUANTA["rotors"],
                       np.where(at < 3, QUANTA["velocity"], QUANTA["heading"]))
    seen = on_rows[np.array([o is not None for o in record.observations], bool)]
    observation, seen_sizes = _flat([o for o in record.observations if o is not None])
    if mode == "control":
        action = _rounded(action, 2.0 ** quantum)
        observation = _rounded(observation, 2.0 ** QUANTA["observation"])
    return {"action_kind": pa.array(kind, pa.string()), "action": _lists(m, on_rows, sizes, action),
            "action_hold_periods": pa.array(hold, pa.int32(), mask=~np.isin(np.arange(m), on_rows)),
            "observation": _lists(m, seen, seen_sizes, observation)}


def _flat(vectors: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Vectors one after another (float64), and their lengths."""
    sizes = np.array([np.size(v) for v in vectors], np.int64)
    return (np.concatenate([np.asarray(v, float).reshape(-1) for v in vectors]) if len(vectors) else np.zeros(0),
            sizes)


def _rounded(values: np.ndarray, scale: float | np.ndarray) -> np.ndarray:
    """`values` rounded to 1/`scale` (a non-finite value, or one too large to round, stays as it is)."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.round(values * scale) / scale
    return np.where(np.isfinite(out), out, values)


def _lists(m: int, rows: np.ndarray, sizes: np.ndarray, values: np.ndarray) -> pa.Array:
    """A list<float32> column of `m` rows: on row `rows[i]` (increasing) the next `sizes[i]` of `values`, null on
    every other row."""
    lengths = np.zeros(m, np.int64)
    lengths[rows] = sizes
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
    return pa.ListArray.from_arrays(pa.array(offsets), pa.array(values.astype(np.float32)),
                                    mask=pa.array(~np.isin(np.arange(m), rows)))


def _lidar_on_rows(t_s: np.ndarray, hits: np.ndarray | None) -> pa.Array:
    """Each scan's thinned true hit points (hits: (H, 4) [t, x, y, z]) on the first kept row at or after its time,
    flattened [x, y, z, ...] (null on rows without a scan)."""
    per_row: list[list[float] | None] = [None] * len(t_s)
    if hits is not None and len(hits):
        rows = np.minimum(np.searchsorted(t_s, hits[:, 0] - 1e-9), len(t_s) - 1)
        for r in np.unique(rows):
            per_row[int(r)] = np.round(hits[rows == r, 1:4], 2).astype(np.float32).ravel().tolist()
    return pa.array(per_row, pa.list_(_F32))


def _decision_rows(t_s: np.ndarray, decision_t_s: np.ndarray) -> np.ndarray:
    """The kept row of each decision (D,).

    A decision is made at the start of a control period, which is a kept row in either mode (row 0 or the end of
    the period before); it goes to the row nearest its time (the runner's clocks may differ in the last bit).

    Raises:
        ValueError: a decision with no row of its own (two on one row), which the runner never makes.
    """
    if len(decision_t_s) == 0:
        return np.zeros(0, np.int64)
    right = np.clip(np.searchsorted(t_s, decision_t_s), 1, len(t_s) - 1) if len(t_s) > 1 else np.zeros(
        len(decision_t_s), int)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(t_s[left] - decision_t_s) <= np.abs(t_s[right] - decision_t_s), left, right)
    if len(np.unique(nearest)) != len(nearest):
        raise ValueError("two decisions fall on one stored row")
    return nearest.astype(np.int64)


def episode_row(meta: EpisodeMeta, metrics: EpisodeMetrics, conditions: EpisodeConditions | None, mode: str,
                samples: int) -> dict[str, Any]:
    """The episode table's row of an episode (`EPISODE_SCHEMA`), before its samples have a place in a file
    (`samples_file` "", `row_start` 0: the compaction fills them)."""
    row: dict[str, Any] = dict(zip(METRIC_COLUMNS, astuple(metrics)))
    if conditions is None:
        row.update(dict.fromkeys(CONDITION_COLUMNS))
    else:
        wind = conditions.steady_wind_enu_m_s
        row.update(field_density_kg_m3=conditions.field_density_kg_m3, density_altitude_m=conditions.density_altitude_m,
                   turbulence=conditions.turbulence, steady_wind_m_s=math.hypot(*wind), steady_wind_e_m_s=wind[0],
                   steady_wind_n_m_s=wind[1], steady_wind_u_m_s=wind[2], building_coverage=conditions.building_coverage)
    row.update(store=mode, samples=int(samples), samples_file="", row_start=0,
               meta_json=json.dumps(meta_to_json(meta), sort_keys=True, allow_nan=True))
    return row


def metrics_from_row(row: Mapping[str, Any]) -> EpisodeMetrics:
    """The metrics.csv row an episode table's row holds (values exactly as computed in the cell)."""
    return EpisodeMetrics(**{name: row[name] for name in METRIC_COLUMNS if name in row})


def meta_from_row(row: Mapping[str, Any]) -> EpisodeMeta:
    """The episode's metadata from its row.

    Raises:
        ValueError: its meta_json is not an episode's metadata.
    """
    try:
        return meta_from_json(strict_json_loads(row["meta_json"]))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"its metadata is not readable ({exc})") from exc


def episode_from_tables(meta: EpisodeMeta, samples: pa.Table, *, with_decisions: bool = False) -> SavedEpisode:
    """An episode from its metadata and its samples (as stored: thinned in "control" mode), as float64 arrays.

    `with_decisions`: read the decisions' commands and observations into `Trajectory.decisions` too (by default
    left as None: the pages never draw them, and `compare.results.run_tables.load_run` reads them as a table).

    Raises:
        ValueError: samples that are not a flight (no rows, times not finite and increasing, rotor lists of
            another length than the vehicle's rotors).
    """
    n = samples.num_rows
    if n == 0:
        raise ValueError("it has no samples")

    def col(name: str) -> np.ndarray:
        return samples.column(name).to_numpy(zero_copy_only=False).astype(float)

    def rotors(name: str) -> np.ndarray:
        values = samples.column(name).combine_chunks()
        flat = values.flatten().to_numpy(zero_copy_only=False).astype(float)
        if len(flat) != n * meta.n_rotors:
            raise ValueError(f"{name} holds {len(flat)} values for {n} samples of {meta.n_rotors} rotors")
        return flat.reshape(n, meta.n_rotors)

    t = col("t_s")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ValueError("its times t_s are not finite and increasing")
    states = np.column_stack([col(c) for c in (*POSITION, *VELOCITY, *QUATERNION, *BODY_RATES)]
                             + [rotors(ROTOR_SPEED)])
    decided = col("decision_t_s")
    has = ~np.isnan(decided)
    power = col("shaft_power_w")
    est = None
    if ESTIMATE[0] in samples.column_names and samples.column(ESTIMATE[0]).null_count < n:
        est = np.column_stack([col(c) for c in ESTIMATE])
    traj = Trajectory(t_s=t, states=states, rotor_commands=rotors(ROTOR_COMMAND),
                      wind_enu_m_s=np.column_stack([col(c) for c in WIND]), clearance_m=col("clearance_m"),
                      decision_t_s=decided[has], compute_s=col("compute_s")[has], energy_J=meta.energy_J,
                      outcome=meta.outcome, plan_time_s=meta.plan_time_s, detail=meta.detail,
                      shaft_power_W=None if samples.column("shaft_power_w").null_count == n else power,
                      estimate_m=est, lidar_hits_m=_lidar_from_samples(samples),
                      decisions=_decisions_from_samples(samples, has) if with_decisions else None)
    return SavedEpisode(meta, traj)


def _decisions_from_samples(samples: pa.Table, decided: np.ndarray) -> DecisionRecord | None:
    """The decisions' commands a samples table holds on its decision rows (`decided`: (M,) bool), None where it
    holds none (a store written before they were recorded)."""
    if "action_kind" not in samples.column_names:
        return None
    rows = pa.array(np.flatnonzero(decided))
    kinds = samples.column("action_kind").take(rows).to_pylist()
    if not kinds or any(k is None for k in kinds):
        return None
    commands = [np.asarray(v, float) for v in samples.column("action").take(rows).to_pylist()]
    observations = [None if v is None else np.asarray(v, float)
                    for v in samples.column("observation").take(rows).to_pylist()]
    holds = samples.column("action_hold_periods").take(rows).to_numpy(zero_copy_only=False).astype(np.int64)
    return DecisionRecord(tuple(kinds), tuple(commands), holds, tuple(observations))


def _lidar_from_samples(samples: pa.Table) -> np.ndarray | None:
    """The lidar hit points a samples table holds, (H, 4) [t, x, y, z] world ENU (None: none stored)."""
    if LIDAR_HITS not in samples.column_names or samples.column(LIDAR_HITS).null_count == samples.num_rows:
        return None
    t = samples.column("t_s").to_numpy(zero_copy_only=False)
    out = []
    for ti, flat in zip(t, samples.column(LIDAR_HITS).to_pylist()):
        if flat:
            pts = np.asarray(flat, float).reshape(-1, 3)
            out.append(np.column_stack([np.full(len(pts), ti), pts]))
    return np.concatenate(out) if out else None
