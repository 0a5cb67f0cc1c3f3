"""Clearance margins from the vehicle's measured tracking error in the air it flies in.

The classical pilot keeps its reference `planner margin` M beyond the collision radius from every
obstacle (planner and time-parameterisation) and asks its MPC, softly, to keep M_mpc. How far the
vehicle strays from the reference depends on the vehicle and the air: a 900 kg multicopter with a
0.12 s motor lag in moderate turbulence strays metres, a small quad in calm air centimetres. So M
is not a constant but read from a table of tracking-error percentiles measured by flying this pilot
closed loop on the simulator (`perf/tracking_error.py`, on the learned pilot's *validation*
pool of generated cities, never on the comparison's scenarios), shipped as
`planners/data/tracking_error.json` with its provenance.

The rule (`MarginRule`):

    M     = max(floor_m, k · e_p99)       e_p99: the 99th percentile of the vehicle's distance from
                                          the reference curve, for its vehicle, turbulence level and
                                          air density (interpolated in density ratio)
    M_mpc = mpc_fraction · M              (0.5: the MPC's soft constraint is the promise itself,
                                           "never closer than half the nominal margin")

Why: the reference keeps M; the vehicle then keeps M − e where e is its deviation towards the
obstacle at the closest approach. The comparison's target is M − e ≥ M / 2, i.e. e ≤ M / 2; with
k = 2 that is e ≤ e_p99 (a deviation beyond the 99th percentile would also have to point at the
nearest wall at the moment of closest approach), and the MPC's constraint at M / 2 together with
replanning on a predicted violation (`planners.classical_pilot`) cover the rest. The floor (the former fixed
1 m) covers what the table does not: the reference's 5 cm clearance sampling, the MPC's half-space
linearisation at building corners, and a vehicle whose tracking in calm air is nearly perfect.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uam_fdm.air.wind import TurbulenceLevel, milspec_low_altitude
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.strict import strict_json_loads
from uam_fdm.vehicle.params import VehicleParams

log = logging.getLogger(__name__)

DEFAULT_TABLE_PATH = Path(__file__).parent / "data" / "tracking_error.json"
TABLE_FORMAT_VERSION = 2  # 2: rows carry `speed_bins`; version-1 files (no bins) still load
PERCENTILES = ("p50_m", "p95_m", "p99_m", "max_m")
# Speed-bin edges as shares of the vehicle's controller speed cap (finer where the reference slows
# down near a start or goal); a bin with fewer than MIN_BIN_SAMPLES decisions joins the next faster one.
SPEED_BIN_EDGES = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
MIN_BIN_SAMPLES = 500


@dataclass(frozen=True)
class SpeedBin:
    """Tracking-error percentiles of the decisions whose reference speed lay in [speed_lo, speed_hi].

    Attributes:
        speed_lo_m_s, speed_hi_m_s: the reference speeds of the bin's decisions, least and largest [m/s].
        samples: decisions in the bin.
        p50_m, p95_m, p99_m, max_m: percentiles of the distance to the reference curve [m].
    """

    speed_lo_m_s: float
    speed_hi_m_s: float
    samples: int
    p50_m: float
    p95_m: float
    p99_m: float
    max_m: float


def bin_by_speed(deviations_m: np.ndarray, speeds_m_s: np.ndarray, max_speed_m_s: float,
                 edges: Sequence[float] = SPEED_BIN_EDGES, min_samples: int = MIN_BIN_SAMPLES
                 ) -> tuple[SpeedBin, ...]:
    """Percentiles of the tracking error per reference-speed bin, slowest first.

    Args:
        deviations_m: (N,) distances from the vehicle to its reference curve, one per decision [m].
        speeds_m_s: (N,) the reference's speed at the same decisions [m/s].
        max_speed_m_s: the vehicle's controller speed cap [m/s]; `edges` are shares of it.
        edges: lower edges of the bins as shares of `max_speed_m_s` (the last bin is open above).
        min_samples: a bin with fewer decisions is merged into the next faster one (the fastest
            into the one below), so every p99 rests on at least this many decisions when there are.

    Returns:
        The bins; each holds its decisions' actual least and largest speed, so consecutive bins
        leave gaps between them that belong to the faster bin (see `SpeedMargins`).
    """
    dev = np.asarray(deviations_m, float).reshape(-1)
    v = np.asarray(speeds_m_s, float).reshape(-1)
    if dev.shape != v.shape or dev.size == 0:
        raise ValueError(f"deviations and speeds must be equal-length non-empty arrays, got {dev.shape}, {v.shape}")
    lower = np.asarray(edges, float) * float(max_speed_m_s)
    which = np.searchsorted(lower, v, side="right") - 1
    groups = [np.flatnonzero(which == i) for i in range(len(lower))]
    groups = [g for g in groups if g.size]
    merged: list[np.ndarray] = []
    pending = np.zeros(0, dtype=int)
    for g in groups:
        pending = np.concatenate([pending, g])
        if pending.size >= min_samples:
            merged.append(pending)
            pending = np.zeros(0, dtype=int)
    if pending.size:
        if merged:
            merged[-1] = np.concatenate([merged[-1], pending])
        else:
            merged.append(pending)
    out = []
    for g in merged:
        q = np.percentile(dev[g], [50, 95, 99])
        out.append(SpeedBin(float(v[g].min()), float(v[g].max()), int(g.size), float(q[0]), float(q[1]),
                            float(q[2]), float(dev[g].max())))
    return tuple(out)


@dataclass(frozen=True)
class TrackingErrorRow:
    """Tracking-error statistics of one vehicle in one kind of air.

    Attributes:
        vehicle: preset name; fingerprint: its `VehicleParams.fingerprint()` (a vehicle file reusing
            the name with other physics does not match).
        turbulence: the turbulence level flown.
        density_ratio: ρ/ρ0 at the field (1.0 at sea level on a standard day) [-].
        episodes: episodes flown; samples: decisions pooled.
        p50_m, p95_m, p99_m, max_m: percentiles of the distance from the vehicle to the nearest point of
            its reference curve over every decision [m].
        speed_bins: the same by the reference's speed at the decision (`bin_by_speed`), slowest
            first; () in a version-1 table (the pooled p99 then holds at every speed).
    """

    vehicle: str
    fingerprint: str
    turbulence: TurbulenceLevel
    density_ratio: float
    episodes: int
    samples: int
    p50_m: float
    p95_m: float
    p99_m: float
    max_m: float
    speed_bins: tuple[SpeedBin, ...] = ()


@dataclass(frozen=True)
class TrackingErrorTable:
    """The shipped table: rows plus how they were produced (command, seed, pool, episode count...)."""

    rows: tuple[TrackingErrorRow, ...]
    provenance: Mapping[str, object]
    source: str = ""

    def rows_for(self, vehicle: VehicleParams, turbulence: TurbulenceLevel) -> list[TrackingErrorRow]:
        """Rows measured for this vehicle (name and fingerprint) at this turbulence level, by density ratio."""
        fp = vehicle.fingerprint()
        return sorted((r for r in self.rows if r.vehicle == vehicle.name and r.fingerprint == fp
                       and r.turbulence == turbulence), key=lambda r: r.density_ratio)

    def measured_levels(self, vehicle: VehicleParams) -> list[TurbulenceLevel]:
        fp = vehicle.fingerprint()
        return sorted({r.turbulence for r in self.rows if r.vehicle == vehicle.name and r.fingerprint == fp},
                      key=lambda t: list(TurbulenceLevel).index(t))


@dataclass(frozen=True)
class MarginRule:
    """How margins follow from the table (module docstring).

    Attributes:
        floor_m: smallest planner margin [m].
        k: multiple of the 99th-percentile tracking error [-].
        mpc_fraction: the MPC's margin as a share of the planner's [-].
    """

    floor_m: float = 1.0
    k: float = 2.0
    mpc_fraction: float = 0.5

    def __post_init__(self) -> None:
        for name in ("floor_m", "k", "mpc_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"MarginRule.{name} must be a finite number >= 0, got {v!r}")
        if self.mpc_fraction > 1.0:
            raise ValueError(f"MarginRule.mpc_fraction must be <= 1, got {self.mpc_fraction!r}")


@dataclass(frozen=True)
class SpeedMargins:
    """The planner margin as a non-decreasing step function of the reference speed.

    M(v) = margins_m[i] for the first i with v <= uppers_m_s[i] (the last step holds above every
    upper), M_mpc(v) = mpc_fraction · M(v). Non-decreasing, so it has an inverse: the fastest speed
    a reference may fly where it keeps a given clearance (`speed_limit_m_s`).

    Attributes:
        uppers_m_s: (n - 1,) increasing upper speeds of the first n - 1 steps [m/s].
        margins_m: (n,) non-decreasing margins beyond the collision radius [m].
        mpc_fraction: the MPC's share of the margin [-].
    """

    uppers_m_s: tuple[float, ...]
    margins_m: tuple[float, ...]
    mpc_fraction: float = 0.5

    def __post_init__(self) -> None:
        u, m = np.asarray(self.uppers_m_s, float), np.asarray(self.margins_m, float)
        if len(m) != len(u) + 1 or not np.all(np.isfinite(m)) or np.any(m < 0) or np.any(np.diff(m) < 0):
            raise ValueError(f"margins_m must be n >= 1 finite non-decreasing values >= 0 for n - 1 uppers, "
                             f"got {self.margins_m!r} for {self.uppers_m_s!r}")
        if np.any(np.diff(u) <= 0) or not np.all(np.isfinite(u)):
            raise ValueError(f"uppers_m_s must be finite and increasing, got {self.uppers_m_s!r}")

    @classmethod
    def constant(cls, margin_m: float, mpc_fraction: float = 0.5) -> SpeedMargins:
        """The same margin at every speed."""
        return cls((), (float(margin_m),), mpc_fraction)

    @property
    def floor_m(self) -> float:
        """The margin at rest (the least in force anywhere outside a close start's or goal's zone) [m]."""
        return float(self.margins_m[0])

    @property
    def cruise_m(self) -> float:
        """The margin at the fastest speeds (the largest) [m]."""
        return float(self.margins_m[-1])

    def margin_m(self, speed_m_s: float | np.ndarray) -> np.ndarray:
        """M(v) [m] at reference speeds `speed_m_s` [m/s] (any shape)."""
        i = np.searchsorted(np.asarray(self.uppers_m_s, float), np.asarray(speed_m_s, float), side="left")
        return np.asarray(self.margins_m, float)[i]

    def speed_limit_m_s(self, clearance_m: float | np.ndarray) -> np.ndarray:
        """The fastest speed v [m/s] with M(v) <= `clearance_m` (beyond the collision radius, any shape):
        inf at or above the cruise margin; below the floor, the first step's upper speed (a start or
        goal inside the floor margin by the task itself: crawl rather than stop)."""
        m = np.asarray(self.margins_m, float)
        tops = np.append(np.asarray(self.uppers_m_s, float), np.inf)
        # the step after the last one whose margin fits, minus one: its upper speed is the limit
        j = np.searchsorted(m, np.asarray(clearance_m, float), side="right") - 1
        return tops[np.maximum(j, 0)]

    def widened(self, extra_m: float) -> SpeedMargins:
        """These margins with `extra_m` [m] added at every speed (itself when it is 0)."""
        if extra_m == 0.0:
            return self
        return SpeedMargins(self.uppers_m_s, tuple(m + float(extra_m) for m in self.margins_m), self.mpc_fraction)

    def taper(self, accel_m_s2: float, start_speed_m_s: float = 0.0) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Distances from a start or goal within which each step's margin holds for a reference that
        leaves it (or arrives at it) at `start_speed_m_s` and changes speed at most `accel_m_s2`:
        (distances_m, margins_m), the steps reached within that distance; the cruise margin beyond.
        The speed at distance d is at most sqrt(v0^2 + 2 a d), so step i holds while that stays at or
        below its upper speed (`planners.timing.MarginTaper`)."""
        if not (math.isfinite(accel_m_s2) and accel_m_s2 > 0):
            raise ValueError(f"accel_m_s2 must be positive and finite, got {accel_m_s2!r}")
        v0 = float(start_speed_m_s)
        d, m = [], []
        for upper, margin in zip(self.uppers_m_s, self.margins_m[:-1], strict=True):
            if upper > v0 and margin < self.cruise_m:
                d.append((upper * upper - v0 * v0) / (2.0 * accel_m_s2))
                m.append(float(margin))
        return tuple(d), tuple(m)


@dataclass(frozen=True)
class Margins:
    """The margins one episode flies with.

    Attributes:
        planner_m: clearance beyond the collision radius kept by the reference at cruise speed (the
            largest margin) [m].
        mpc_m: the MPC's soft-constraint margin at cruise speed [m].
        tracking_p99_m: the 99th-percentile tracking error at cruise speed [m] (NaN: none, fixed margins).
        source: where the numbers came from, in words.
        speed: the margins as a function of the reference speed (`SpeedMargins`); a constant
            `planner_m` when not given.
    """

    planner_m: float
    mpc_m: float
    tracking_p99_m: float
    source: str
    speed: SpeedMargins | None = None

    @property
    def by_speed(self) -> SpeedMargins:
        """The speed-dependent margins (constant `planner_m` when none were given)."""
        if self.speed is not None:
            return self.speed
        return SpeedMargins.constant(self.planner_m, self.mpc_m / self.planner_m if self.planner_m > 0 else 0.5)

    @property
    def floor_m(self) -> float:
        """The planner margin at rest [m]."""
        return self.by_speed.floor_m

    def widened(self, extra_m: float) -> Margins:
        """These margins with `extra_m` [m] added to the planner's at every speed (the MPC's: its share of it);
        itself when it is 0."""
        if extra_m == 0.0:
            return self
        speed = self.by_speed.widened(extra_m)
        return Margins(speed.cruise_m, speed.mpc_fraction * speed.cruise_m, self.tracking_p99_m,
                       f"{self.source} + {extra_m:.2f} m for the estimate's uncertainty", speed)


def interpolate_p99(rows: Sequence[TrackingErrorRow], density_ratio: float) -> float:
    """p99 [m] at `density_ratio` from rows sorted by density ratio: linear between the measured
    densities, the nearest measured one outside them (thin air is not extrapolated)."""
    x = np.array([r.density_ratio for r in rows])
    y = np.array([r.p99_m for r in rows])
    return float(np.interp(float(density_ratio), x, y))


def _p99_steps(row: TrackingErrorRow) -> tuple[np.ndarray, np.ndarray]:
    """A row's p99 as a step function of speed: (uppers (n-1,), p99 (n,)); one step without bins.

    A bin holds speeds [lo, hi]; the gap up to the next bin's lo belongs to the faster bin (the
    larger speed, the conservative side when the error grows with speed)."""
    if not row.speed_bins:
        return np.zeros(0), np.array([row.p99_m])
    return (np.array([b.speed_hi_m_s for b in row.speed_bins[:-1]]),
            np.array([b.p99_m for b in row.speed_bins]))


def _at(uppers: np.ndarray, values: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    return values[np.searchsorted(uppers, speeds, side="left")]


def p99_by_speed(rows: Sequence[TrackingErrorRow], density_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """p99 [m] as a step function of speed at `density_ratio`: (uppers [m/s], p99 [m]).

    Rows sorted by density ratio; each row's steps are evaluated on the union of their upper
    speeds and interpolated in density as `interpolate_p99` does."""
    uppers = np.unique(np.concatenate([_p99_steps(r)[0] for r in rows]))
    probe = np.append(uppers, np.inf)  # one speed per step of the union: its upper end
    x = np.array([r.density_ratio for r in rows])
    ys = np.array([_at(*_p99_steps(r), probe) for r in rows])  # (rows, steps)
    p99 = np.array([np.interp(float(density_ratio), x, ys[:, j]) for j in range(len(probe))])
    return uppers, p99


def speed_margins_from_p99(uppers_m_s: np.ndarray, p99_m: np.ndarray, rule: MarginRule) -> SpeedMargins:
    """M(v) = max(floor, k · p99(v)), made non-decreasing (a step takes the largest margin of the
    slower steps: the reference must be able to slow down through them), steps of equal margin merged."""
    m = np.maximum.accumulate(np.maximum(rule.floor_m, rule.k * np.asarray(p99_m, float)))
    keep = np.append(np.diff(m) > 0, True)  # the last step of each run of equal margins
    return SpeedMargins(tuple(float(u) for u in np.asarray(uppers_m_s, float)[keep[:-1]]),
                        tuple(float(x) for x in m[keep]), rule.mpc_fraction)


def margins_for(table: TrackingErrorTable | None, rule: MarginRule, vehicle: VehicleParams,
                turbulence: TurbulenceLevel | str, density_ratio: float, fixed_planner_m: float,
                fixed_mpc_m: float) -> Margins:
    """The margins for a vehicle flying in the given turbulence at the given density ratio.

    The margin is a function of the reference speed where the table has speed bins
    (`Margins.speed`); `planner_m` is its cruise (largest) value. A vehicle the table does not know
    (another name, or the same name with other physics) flies the fixed margins `fixed_planner_m` /
    `fixed_mpc_m`. A turbulence level not measured for a known vehicle (e.g. "severe") takes, at
    every speed, the largest margin of its measured levels at this density, the conservative
    choice, and says so in `source`.
    """
    level = TurbulenceLevel.parse(turbulence)
    levels = table.measured_levels(vehicle) if table is not None else []
    if table is None or not levels:
        return Margins(float(fixed_planner_m), float(fixed_mpc_m), math.nan,
                       f"fixed: no tracking-error entry for vehicle {vehicle.name!r}")
    rows = table.rows_for(vehicle, level)
    if rows:
        uppers, p99 = p99_by_speed(rows, density_ratio)
        pooled = interpolate_p99(rows, density_ratio)
        where = f"{vehicle.name}, {level.value} turbulence, density ratio {density_ratio:.2f}"
    else:
        steps = [p99_by_speed(table.rows_for(vehicle, lv), density_ratio) for lv in levels]
        uppers = np.unique(np.concatenate([u for u, _ in steps]))
        probe = np.append(uppers, np.inf)
        p99 = np.max([_at(u, v, probe) for u, v in steps], axis=0)
        pooled = max(interpolate_p99(table.rows_for(vehicle, lv), density_ratio) for lv in levels)
        where = f"{vehicle.name}, {level.value} turbulence not measured: the largest of {[lv.value for lv in levels]}"
        log.warning("tracking-error table %s: %s", table.source, where)
    by_speed = speed_margins_from_p99(uppers, p99, rule)
    cruise = by_speed.cruise_m
    steps_text = ", ".join(f"<= {u:.1f} m/s: {m:.2f} m" for u, m in zip(by_speed.uppers_m_s, by_speed.margins_m,
                                                                          strict=False))
    return Margins(cruise, rule.mpc_fraction * cruise, float(p99[-1]),
                   f"{where}: max({rule.floor_m:g}, {rule.k:g} x p99(speed)) = "
                   f"{steps_text + ', ' if steps_text else ''}faster: {cruise:.2f} m (pooled p99 {pooled:.3f} m)",
                   by_speed)


def forecast_gust_m_s(turbulence: TurbulenceLevel | str, height_agl_m: float, n_sigma: float = 2.0) -> float:
    """A gust allowance [m/s] for the forecast level: `n_sigma` x the longitudinal gust standard deviation
    of MIL-F-8785C's low-altitude model at `height_agl_m` (sigma_w = 0.1 W20, sigma_u = sigma_w x the height
    factor; the model the simulator's turbulence follows). 0 for "none". Used to keep the reference's
    speed within what the rotors can fly in gusts (`planners.timing.TimingLimits.from_vehicle`)."""
    level = TurbulenceLevel.parse(turbulence)
    ratio = float(milspec_low_altitude(float(height_agl_m))[0])
    return float(n_sigma) * 0.1 * level.w20_m_s * ratio


def load_tracking_table(path: Path | str = DEFAULT_TABLE_PATH) -> TrackingErrorTable:
    """Read a tracking-error table (JSON: `format_version`, `provenance`, `rows`).

    Raises:
        ValueError: unreadable file, wrong version, or a row with a missing or bad key, naming the file,
            the row and the key.
    """
    path = Path(path)
    try:
        data = strict_json_loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable tracking-error table ({exc})") from exc
    if not isinstance(data, dict) or data.get("format_version") not in (1, TABLE_FORMAT_VERSION):
        raise ValueError(f"{path}: format_version must be 1 or {TABLE_FORMAT_VERSION}")
    raw_rows = data.get("rows")
    if not isinstance(raw_rows, list) or not raw_rows:
        raise ValueError(f"{path}: rows: expected a non-empty list")
    rows = []
    for i, r in enumerate(raw_rows):
        where = f"{path}: rows[{i}]"
        if not isinstance(r, dict):
            raise ValueError(f"{where}: expected an object")
        try:
            values: dict[str, Any] = {"vehicle": str(r["vehicle"]), "fingerprint": str(r["fingerprint"]),
                                      "turbulence": TurbulenceLevel.parse(r["turbulence"]),
                                      "density_ratio": float(r["density_ratio"]), "episodes": int(r["episodes"]),
                                      "samples": int(r["samples"]), **{k: float(r[k]) for k in PERCENTILES}}
        except KeyError as exc:
            raise ValueError(f"{where}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        for k in ("density_ratio", *PERCENTILES):
            if not (math.isfinite(values[k]) and values[k] >= 0):
                raise ValueError(f"{where}: {k} must be finite and >= 0, got {values[k]!r}")
        values["speed_bins"] = _speed_bins(r.get("speed_bins", []), where)
        rows.append(TrackingErrorRow(**values))
    prov = data.get("provenance")
    return TrackingErrorTable(tuple(rows), dict(prov) if isinstance(prov, dict) else {}, str(path))


def _speed_bins(raw: object, where: str) -> tuple[SpeedBin, ...]:
    """A row's `speed_bins` checked: a list of bins with finite values >= 0, slowest first."""
    if not isinstance(raw, list):
        raise ValueError(f"{where}: speed_bins: expected a list")
    bins: list[SpeedBin] = []
    names = [f.name for f in dataclasses.fields(SpeedBin)]
    for j, b in enumerate(raw):
        at = f"{where}: speed_bins[{j}]"
        if not isinstance(b, dict):
            raise ValueError(f"{at}: expected an object")
        try:
            vals = {k: (int(b[k]) if k == "samples" else float(b[k])) for k in names}
        except KeyError as exc:
            raise ValueError(f"{at}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{at}: {exc}") from None
        if not all(math.isfinite(x) and x >= 0 for x in vals.values()) or vals["speed_hi_m_s"] < vals["speed_lo_m_s"]:
            raise ValueError(f"{at}: values must be finite and >= 0, speed_lo_m_s <= speed_hi_m_s")
        if bins and vals["speed_lo_m_s"] < bins[-1].speed_hi_m_s:
            raise ValueError(f"{at}: bins must be ordered by speed without overlap")
        bins.append(SpeedBin(vals["speed_lo_m_s"], vals["speed_hi_m_s"], int(vals["samples"]), vals["p50_m"],
                             vals["p95_m"], vals["p99_m"], vals["max_m"]))
    return tuple(bins)


def write_tracking_table(rows: Sequence[TrackingErrorRow], provenance: Mapping[str, object], path: Path) -> Path:
    """Write a table readable by `load_tracking_table` (atomically)."""
    out = {"format_version": TABLE_FORMAT_VERSION, "provenance": dict(provenance),
           "rows": [{"vehicle": r.vehicle, "fingerprint": r.fingerprint, "turbulence": r.turbulence.value,
                     "density_ratio": round(r.density_ratio, 4), "episodes": r.episodes, "samples": r.samples,
                     **{k: round(getattr(r, k), 4) for k in PERCENTILES},
                     "speed_bins": [{"speed_lo_m_s": round(b.speed_lo_m_s, 4), "speed_hi_m_s": round(b.speed_hi_m_s, 4),
                                     "samples": b.samples, **{k: round(getattr(b, k), 4) for k in PERCENTILES}}
                                    for b in r.speed_bins]} for r in rows]}
    return write_text_atomic(Path(path), json.dumps(out, indent=2) + "\n")
