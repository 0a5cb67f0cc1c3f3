"""Clearance margins from the vehicle's measured tracking error in the air it flies in.

The classical pilot keeps its reference `planner margin` M beyond the collision radius from every
obstacle (planner and time-parameterisation) and asks its MPC, softly, to keep M_mpc. How far the
vehicle strays from the reference depends on the vehicle and the air: a 900 kg multicopter with a
0.12 s motor lag in moderate turbulence strays metres, a small quad in calm air centimetres. So M
is not a constant but read from a table of tracking-error percentiles measured by flying this pilot
closed loop on the simulator (`benchmarks/tracking_error.py`, on the learned pilot's *validation*
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
replanning on a predicted violation (`planners.agent`) cover the rest. The floor (the former fixed
1 m) covers what the table does not: the reference's 5 cm clearance sampling, the MPC's half-space
linearisation at building corners, and a vehicle whose tracking in calm air is nearly perfect.
"""
from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uam_fdm.air.wind import TurbulenceLevel, milspec_low_altitude
from uam_fdm.vehicle.params import VehicleParams

log = logging.getLogger(__name__)

DEFAULT_TABLE_PATH = Path(__file__).parent / "data" / "tracking_error.json"
TABLE_FORMAT_VERSION = 1
PERCENTILES = ("p50_m", "p95_m", "p99_m", "max_m")


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
class Margins:
    """The margins one episode flies with.

    Attributes:
        planner_m: clearance beyond the collision radius kept by the reference [m].
        mpc_m: the MPC's soft-constraint margin beyond the collision radius [m].
        tracking_p99_m: the 99th-percentile tracking error used [m] (NaN: none, fixed margins).
        source: where the numbers came from, in words.
    """

    planner_m: float
    mpc_m: float
    tracking_p99_m: float
    source: str


def margin_from_p99(p99_m: float, rule: MarginRule) -> Margins:
    """M = max(floor, k · p99), M_mpc = mpc_fraction · M, for a known 99th-percentile error [m]."""
    planner = max(rule.floor_m, rule.k * float(p99_m))
    return Margins(planner, rule.mpc_fraction * planner, float(p99_m), "")


def interpolate_p99(rows: Sequence[TrackingErrorRow], density_ratio: float) -> float:
    """p99 [m] at `density_ratio` from rows sorted by density ratio: linear between the measured
    densities, the nearest measured one outside them (thin air is not extrapolated)."""
    x = np.array([r.density_ratio for r in rows])
    y = np.array([r.p99_m for r in rows])
    return float(np.interp(float(density_ratio), x, y))


def margins_for(table: TrackingErrorTable | None, rule: MarginRule, vehicle: VehicleParams,
                turbulence: TurbulenceLevel | str, density_ratio: float, fixed_planner_m: float,
                fixed_mpc_m: float) -> Margins:
    """The margins for a vehicle flying in the given turbulence at the given density ratio.

    A vehicle the table does not know (another name, or the same name with other physics) flies the
    fixed margins `fixed_planner_m` / `fixed_mpc_m`. A turbulence level not measured for a known
    vehicle (e.g. "severe") takes the largest margin of its measured levels at this density, the
    conservative choice, and says so in `source`.
    """
    level = TurbulenceLevel.parse(turbulence)
    levels = table.measured_levels(vehicle) if table is not None else []
    if table is None or not levels:
        return Margins(float(fixed_planner_m), float(fixed_mpc_m), math.nan,
                       f"fixed: no tracking-error entry for vehicle {vehicle.name!r}")
    rows = table.rows_for(vehicle, level)
    if rows:
        p99 = interpolate_p99(rows, density_ratio)
        where = f"{vehicle.name}, {level.value} turbulence, density ratio {density_ratio:.2f}"
    else:
        p99 = max(interpolate_p99(table.rows_for(vehicle, lv), density_ratio) for lv in levels)
        where = f"{vehicle.name}, {level.value} turbulence not measured: the largest of {[lv.value for lv in levels]}"
        log.warning("tracking-error table %s: %s", table.source, where)
    m = margin_from_p99(p99, rule)
    return Margins(m.planner_m, m.mpc_m, p99,
                   f"{where}: p99 {p99:.3f} m -> max({rule.floor_m:g}, {rule.k:g} x p99) = {m.planner_m:.3f} m")


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
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable tracking-error table ({exc})") from exc
    if not isinstance(data, dict) or data.get("format_version") != TABLE_FORMAT_VERSION:
        raise ValueError(f"{path}: format_version must be {TABLE_FORMAT_VERSION}")
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
        rows.append(TrackingErrorRow(**values))
    prov = data.get("provenance")
    return TrackingErrorTable(tuple(rows), dict(prov) if isinstance(prov, dict) else {}, str(path))


def write_tracking_table(rows: Sequence[TrackingErrorRow], provenance: Mapping[str, object], path: Path) -> Path:
    """Write a table readable by `load_tracking_table` (atomically)."""
    from uam_fdm.files.atomic import write_text_atomic

    out = {"format_version": TABLE_FORMAT_VERSION, "provenance": dict(provenance),
           "rows": [{"vehicle": r.vehicle, "fingerprint": r.fingerprint, "turbulence": r.turbulence.value,
                     "density_ratio": round(r.density_ratio, 4), "episodes": r.episodes, "samples": r.samples,
                     **{k: round(getattr(r, k), 4) for k in PERCENTILES}} for r in rows]}
    return write_text_atomic(Path(path), json.dumps(out, indent=2) + "\n")
