"""Wind from JSBSim: a steady wind plus a gust time series from JSBSim's Dryden turbulence model.

What the model is
    The wind at time t is ``steady + gust(t)`` in the world ENU frame (m/s), the same at every
    point of the map. The steady part comes from the scenario (``wind_mps: [e, n, u]``). The gust
    part is a time series produced by JSBSim's own turbulence model (``FGWinds``, turb-type 3,
    "Milspec": the MIL-F-8785C Dryden spectra in the MIL-STD-1797A discrete form, Yeager 1998),
    run once per episode and tabulated; the physics loop then only interpolates in NumPy.

Probe-airspeed modelling choice
    Dryden turbulence is a *time* series seen by a body moving through a frozen turbulent field
    at airspeed V: its correlation times are the scale lengths over V (L_u/V, L_w/V). It is not
    a spatial field that could be queried at arbitrary points. We therefore fly a point-mass JSBSim
    probe (``uam_fdm/jsbsim/aircraft/windprobe``: no aerodynamics, an external LOCAL-frame force
    that cancels its weight) level at a constant reference airspeed chosen by the caller, for
    example ``max(vehicle cruise speed, |steady wind|)`` and at least a few m/s, and at the
    flight's mean height above the field. The vehicle then sees that one series whatever its
    actual path: spatial variation across the map and the dependence on the vehicle's own
    airspeed are deliberately not modelled. (The shipped ``ball`` model cannot be used: it
    falls at hundreds of m/s, which ruins the spectrum.)

Height: above the field, not above sea level
    MIL-F-8785C's low-altitude model (below 1000 ft) is defined in terms of height above ground
    (h), and its medium/high-altitude model in terms of altitude. JSBSim's FGWinds evaluates both
    at the vehicle's altitude above sea level, i.e. it assumes terrain at sea level. We fly the
    probe at the flight's height *above the field*, so a city at 1500 m elevation still gets the
    near-ground turbulence that MIL-F-8785C prescribes for flight 100 m above its rooftops.

Orientation
    With no steady wind set inside JSBSim (we never set one there: JSBSim's wind would also change
    the probe's airspeed) JSBSim's longitudinal component comes out along north, lateral along
    east, vertical down. We rotate the horizontal pair so that the longitudinal component lies
    along the scenario's steady horizontal wind (as MIL-F-8785C aligns u with the mean wind) and
    the lateral one 90 degrees to its right; in calm air they stay north/east. We do this rotation
    ourselves because FGWinds only updates its wind azimuth when the north wind component is
    non-zero, and its rotation turns the longitudinal axis to heading -psi instead of +psi (for
    a wind towards the north-east it would lie north-west, across the wind).

Translational components only
    JSBSim's rotational turbulence (p, q, r) is ignored: it models the gust gradient across a
    wing span, and for multirotors of a few metres it is small next to the translational gusts.

Intensity
    Levels follow MIL-F-8785C 3.7.2.3 and JSBSim's FGWinds.h reference table: the wind speed at
    20 ft above ground W20 is 15 / 30 / 45 kt for light / moderate / severe (low-altitude
    sigma_w = 0.1 W20), and the high-altitude probability-of-exceedance curve (MIL-F-8785C Fig. 7)
    is 1e-2 / 1e-3 / 1e-5, which is JSBSim's ``milspec/severity`` index 3 / 4 / 6.

Reproducibility and cost
    One integer seed in (JSBSim's ``atmosphere/randomseed``, a private Mersenne twister in
    FGWinds): the same seed gives bit-identical series, in the same or another process. The
    Dryden filters start at rest, so we first run a spin-up of three times the largest
    MIL-F-8785C scale length (1750 ft) over the airspeed, then record. Measured here (median,
    2-core machine, ~4.4 us per JSBSim step): a 120 s series at 120 Hz costs 0.20 / 0.13 /
    0.10 s at 5 / 10 / 20 m/s probe airspeed (the recorded 14,401 steps 0.06 s, the rest is
    spin-up). Queries are NumPy-only: ~2 us for one time, ~40 us for 1024 times.

Statistics (tests/test_wind.py and a 3000 s check): at 100 m above the field the RMS of each
axis is within 0.96-1.06 of the MIL-F-8785C low-altitude intensities sigma_w = 0.1 W20,
sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h_ft)^0.4.
"""

from __future__ import annotations

import enum
import logging
import math
import operator
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uam_fdm.atmosphere import FT_TO_M, checked_number, jsbsim_exec, load_probe_model

__all__ = [
    "TurbulenceLevel",
    "WindConditions",
    "GustSeries",
    "WindField",
    "gust_series",
]

_log = logging.getLogger(__name__)

KNOT_TO_M_S = 1852.0 / 3600.0

#: JSBSim turbulence model "Milspec": Dryden spectra, MIL-STD-1797A discretisation (FGWinds.h).
JSBSIM_TURB_TYPE_MILSPEC = 3

#: Largest MIL-F-8785C Dryden scale length, 1750 ft (Sec. 3.7.2.1, medium/high altitude);
#: bounds every correlation time L/V, so it sizes the spin-up.
MAX_SCALE_LENGTH_M = 1750.0 * FT_TO_M
SPINUP_SCALE_LENGTHS = 3.0  # 3 L/V: variance of a first-order filter within e^-6 = 0.25 % of stationary

# Input bounds: wide enough for any plausible flight, tight enough to catch unit mistakes.
MAX_STEADY_WIND_M_S = 60.0
AIRSPEED_RANGE_M_S = (1.0, 100.0)
HEIGHT_RANGE_M = (0.0, 10000.0)
MAX_DURATION_S = 7200.0
MAX_DT_S = 0.1
MAX_SEED = 2**31 - 1  # JSBSim's atmosphere/randomseed is a C int


class TurbulenceLevel(str, enum.Enum):
    """Turbulence intensity, as named in scenario files (``none|light|moderate|severe``)."""

    NONE = "none"
    LIGHT = "light"
    MODERATE = "moderate"
    SEVERE = "severe"

    @classmethod
    def parse(cls, value: str | TurbulenceLevel) -> TurbulenceLevel:
        """The level named by ``value`` (case-insensitive).

        Raises:
            ValueError: Naming the accepted values, if ``value`` is not one of them.
        """
        if isinstance(value, cls):
            return value
        if isinstance(value, str):
            try:
                return cls(value.strip().lower())
            except ValueError:
                pass
        names = ", ".join(level.value for level in cls)
        raise ValueError(f"turbulence must be one of {names}; got {value!r}")

    @property
    def w20_m_s(self) -> float:
        """MIL-F-8785C low-altitude wind speed at 20 ft above ground, W20, m/s (0 for none)."""
        return _LEVEL_PARAMS[self][0] * KNOT_TO_M_S

    @property
    def milspec_severity(self) -> int:
        """JSBSim ``atmosphere/turbulence/milspec/severity`` index (0 disables turbulence)."""
        return _LEVEL_PARAMS[self][1]

    @property
    def exceedance_probability(self) -> float:
        """MIL-F-8785C Fig. 7 high-altitude probability of exceedance (0 for none)."""
        return _LEVEL_PARAMS[self][2]


# (W20 in knots, JSBSim severity index, probability of exceedance).
# W20: MIL-F-8785C 3.7.2.3 (light 15 kt, moderate 30 kt, severe 45 kt); the same values are in
# the reference table of JSBSim's src/models/atmosphere/FGWinds.h (25 / 50 / 75 ft/s).
# Severity: FGWinds.cpp's POE_Table rows are the Fig. 7 curves 2e-1, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5,
# 1e-6 (index 1..7); FGWinds.h: "3=light, 4=moderate, 6=severe turbulence".
_LEVEL_PARAMS: dict[TurbulenceLevel, tuple[float, int, float]] = {
    TurbulenceLevel.NONE: (0.0, 0, 0.0),
    TurbulenceLevel.LIGHT: (15.0, 3, 1e-2),
    TurbulenceLevel.MODERATE: (30.0, 4, 1e-3),
    TurbulenceLevel.SEVERE: (45.0, 6, 1e-5),
}


@dataclass(frozen=True)
class WindConditions:
    """Wind part of a scenario's atmosphere.

    Attributes:
        steady_enu_m_s: Steady wind velocity (east, north, up), m/s, world ENU. The direction the
            air moves *towards* (a wind "from the west" is (+v, 0, 0)).
        turbulence: Intensity of JSBSim's Dryden turbulence; a string is accepted and parsed.

    Raises:
        ValueError: If the wind is not three finite numbers, exceeds 60 m/s, or the turbulence
            level is unknown.
    """

    steady_enu_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence: TurbulenceLevel = TurbulenceLevel.NONE

    def __post_init__(self) -> None:
        object.__setattr__(self, "steady_enu_m_s", _checked_vector3("steady_enu_m_s", self.steady_enu_m_s))
        speed = math.hypot(*self.steady_enu_m_s)
        if speed > MAX_STEADY_WIND_M_S:
            raise ValueError(
                f"steady wind speed {speed:.1f} m/s exceeds {MAX_STEADY_WIND_M_S} m/s "
                "(wind_mps is in metres per second, [east, north, up])"
            )
        object.__setattr__(self, "turbulence", TurbulenceLevel.parse(self.turbulence))


@dataclass(frozen=True, eq=False)
class GustSeries:
    """A tabulated turbulence time series (gusts only, without the steady wind).

    Attributes:
        t_s: (M,) sample times, seconds from the start of the episode, ``k * dt_s``.
        gust_enu_m_s: (M, 3) gust velocity, m/s, world ENU.
        dt_s: Sample spacing, seconds.
        turbulence: Level the series was generated for.
        seed: Seed the series was generated from.
        airspeed_m_s: Probe airspeed that set the Dryden time scales, m/s.
        height_agl_m: Probe height above the field, metres.
    """

    t_s: NDArray[np.float64]
    gust_enu_m_s: NDArray[np.float64]
    dt_s: float
    turbulence: TurbulenceLevel
    seed: int
    airspeed_m_s: float
    height_agl_m: float

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=np.float64)
        g = np.array(self.gust_enu_m_s, dtype=np.float64)
        if t.ndim != 1 or t.size < 2 or g.shape != (t.size, 3):
            raise ValueError(
                f"GustSeries needs t_s (M>=2,) and gust_enu_m_s (M, 3); got {t.shape}, {g.shape}"
            )
        t.setflags(write=False)
        g.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "gust_enu_m_s", g)

    @property
    def duration_s(self) -> float:
        """Time of the last sample, seconds."""
        return float(self.t_s[-1])


def gust_series(
    conditions: WindConditions,
    seed: int,
    duration_s: float,
    height_agl_m: float,
    airspeed_m_s: float,
    dt_s: float = 1.0 / 120.0,
    spinup_s: float | None = None,
) -> GustSeries:
    """Run JSBSim's Dryden turbulence once for a whole episode and tabulate the gusts.

    Args:
        conditions: Steady wind (sets the longitudinal axis) and turbulence level.
        seed: Integer seed in [0, 2**31 - 1]; the same seed gives an identical series.
        duration_s: Length to cover, seconds; the series spans at least ``[0, duration_s]``.
            Ask for at least the last time the caller will query (e.g. the episode timeout).
        height_agl_m: Height of the probe above the field (mean flight height), metres.
        airspeed_m_s: Reference airspeed of the probe, m/s (e.g. max(cruise, |steady wind|)).
        dt_s: Sample spacing, seconds (JSBSim's integration step for the probe).
        spinup_s: Time the filters run before recording starts, seconds; default
            ``3 * 1750 ft / airspeed`` so that the series starts statistically stationary.

    Returns:
        The tabulated gusts (exactly zero, without running JSBSim, for ``TurbulenceLevel.NONE``).

    Raises:
        ValueError: If an argument is out of range.
        RuntimeError: If JSBSim fails to load the probe or produces non-finite values.
    """
    seed = _checked_seed(seed)
    duration_s = checked_number("duration_s", duration_s, (0.0, MAX_DURATION_S), "s", open_low=True)
    height_agl_m = checked_number("height_agl_m", height_agl_m, HEIGHT_RANGE_M, "m above the field")
    airspeed_m_s = checked_number("airspeed_m_s", airspeed_m_s, AIRSPEED_RANGE_M_S, "m/s")
    dt_s = checked_number("dt_s", dt_s, (0.0, MAX_DT_S), "s", open_low=True)
    if spinup_s is None:
        spinup_s = SPINUP_SCALE_LENGTHS * MAX_SCALE_LENGTH_M / airspeed_m_s
    spinup_s = checked_number("spinup_s", spinup_s, (0.0, 1e5), "s")
    # JSBSim's discrete Dryden filters, x_k = (1 - 2 dt/tau) x_(k-1) + ..., need dt well below the
    # shortest time constant tau_w = L_w / V, where L_w >= min(max(h, 10 ft), 1000 ft) (MIL-F-8785C).
    tau_w_min_s = min(max(height_agl_m, 10.0 * FT_TO_M), 1000.0 * FT_TO_M) / airspeed_m_s
    if dt_s > 0.2 * tau_w_min_s:
        raise ValueError(
            f"dt_s={dt_s} s is too coarse for the Dryden time scale L_w/V = {tau_w_min_s:.3f} s at "
            f"{height_agl_m} m and {airspeed_m_s} m/s; use dt_s <= {0.2 * tau_w_min_s:.4f} s"
        )

    n_samples = int(math.ceil(duration_s / dt_s - 1e-9)) + 1
    t_s = dt_s * np.arange(n_samples)
    level = conditions.turbulence
    if level is TurbulenceLevel.NONE:
        gusts = np.zeros((n_samples, 3))
    else:
        ned = _run_probe(level, seed, n_samples, height_agl_m, airspeed_m_s, dt_s, spinup_s)
        gusts = _ned_to_enu_wind_axes(ned, conditions.steady_enu_m_s)
    return GustSeries(t_s, gusts, dt_s, level, seed, airspeed_m_s, height_agl_m)


def _run_probe(
    level: TurbulenceLevel,
    seed: int,
    n_samples: int,
    height_agl_m: float,
    airspeed_m_s: float,
    dt_s: float,
    spinup_s: float,
) -> NDArray[np.float64]:
    """Fly the windprobe and return JSBSim's turbulence, (n_samples, 3) NED m/s (u, v, w axes)."""
    n_spinup = int(math.ceil(spinup_s / dt_s - 1e-9))
    h_ft = height_agl_m / FT_TO_M  # see module docstring: JSBSim's "ASL" stands in for AGL here
    out = np.empty((n_samples, 3))
    t0 = time.perf_counter()
    with jsbsim_exec() as fdm:
        load_probe_model(fdm)
        fdm.set_dt(dt_s)
        fdm["ic/h-sl-ft"] = h_ft
        fdm["ic/lat-geod-deg"] = 0.0  # the probe's weight cancellation is exact at the equator
        fdm["ic/psi-true-deg"] = 0.0  # flying north: Coriolis from the motion vanishes there
        fdm["ic/u-fps"] = airspeed_m_s / FT_TO_M
        fdm["atmosphere/turb-type"] = JSBSIM_TURB_TYPE_MILSPEC
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = level.w20_m_s / FT_TO_M
        fdm["atmosphere/turbulence/milspec/severity"] = level.milspec_severity
        # A private generator for FGWinds, independent of JSBSim's global one.
        fdm["atmosphere/randomseed"] = seed
        if not fdm.run_ic():
            raise RuntimeError("JSBSim run_ic() failed for the wind probe")
        for _ in range(n_spinup):
            fdm["position/h-sl-ft"] = h_ft  # pin the height: removes the tiny residual drift
            fdm.run()
        for k in range(n_samples):
            fdm["position/h-sl-ft"] = h_ft
            fdm.run()
            out[k, 0] = fdm["atmosphere/turb-north-fps"]
            out[k, 1] = fdm["atmosphere/turb-east-fps"]
            out[k, 2] = fdm["atmosphere/turb-down-fps"]
        airspeed_end = fdm["velocities/vt-fps"] * FT_TO_M
    out *= FT_TO_M
    if not np.all(np.isfinite(out)):
        raise RuntimeError("JSBSim turbulence produced non-finite values")
    _log.debug(
        "gust series %s seed=%d: %d+%d steps of %.4f s at %.1f m/s, %.0f m AGL in %.3f s "
        "(probe airspeed at end %.2f m/s); rms NED %s m/s",
        level.value, seed, n_spinup, n_samples, dt_s, airspeed_m_s, height_agl_m,
        time.perf_counter() - t0, airspeed_end, np.array2string(out.std(axis=0), precision=2),
    )
    return out


def _ned_to_enu_wind_axes(
    ned: NDArray[np.float64], steady_enu_m_s: tuple[float, float, float]
) -> NDArray[np.float64]:
    """Map JSBSim's (longitudinal=N, lateral=E, down) turbulence to ENU, u along the steady wind.

    Args:
        ned: (M, 3) JSBSim turbulence with zero wind azimuth: [:, 0] longitudinal (north),
            [:, 1] lateral (east), [:, 2] vertical (down), m/s.
        steady_enu_m_s: Steady wind (e, n, u), m/s; its horizontal direction sets the
            longitudinal axis (north if the horizontal wind is zero).

    Returns:
        (M, 3) gusts in world ENU, m/s.
    """
    e, n = steady_enu_m_s[0], steady_enu_m_s[1]
    speed = math.hypot(e, n)
    long_en = (e / speed, n / speed) if speed > 0.0 else (0.0, 1.0)
    lat_en = (long_en[1], -long_en[0])  # 90 degrees clockwise seen from above: north -> east
    u, v, w = ned[:, 0], ned[:, 1], ned[:, 2]
    enu = np.empty_like(ned)
    enu[:, 0] = u * long_en[0] + v * lat_en[0]
    enu[:, 1] = u * long_en[1] + v * lat_en[1]
    enu[:, 2] = -w
    return enu


class WindField:
    """Wind seen by the vehicle: steady + tabulated gusts, queried by time (NumPy only).

    Queries before t = 0 or after the end of the gust series raise ``ValueError``: holding the
    last value would silently freeze the turbulence, and the caller knows its episode length
    (build with ``duration_s`` >= the last time it will ask for). :meth:`calm` and a field
    without gusts have no time limit.
    """

    def __init__(self, steady_enu_m_s: ArrayLike = (0.0, 0.0, 0.0), gusts: GustSeries | None = None) -> None:
        """Combine a steady wind with an optional gust series.

        Args:
            steady_enu_m_s: Steady wind (east, north, up), m/s, world ENU.
            gusts: Tabulated gusts, or None for a steady wind only.
        """
        steady = np.array(_checked_vector3("steady_enu_m_s", steady_enu_m_s), dtype=np.float64)
        steady.setflags(write=False)
        self._steady = steady
        self._gusts = gusts
        if gusts is None:
            self._total: NDArray[np.float64] | None = None
            self._dt = math.inf
            self._t_end = math.inf
        else:
            total = gusts.gust_enu_m_s + steady  # pre-added: one interpolation per query
            total.setflags(write=False)
            self._total = total
            self._dt = gusts.dt_s
            self._t_end = gusts.duration_s
            self._last = total.shape[0] - 2

    @classmethod
    def calm(cls) -> WindField:
        """No wind at all, at any time."""
        return cls()

    @classmethod
    def from_conditions(
        cls,
        conditions: WindConditions,
        seed: int,
        duration_s: float,
        height_agl_m: float,
        airspeed_m_s: float,
        dt_s: float = 1.0 / 120.0,
    ) -> WindField:
        """Steady wind plus a gust series from :func:`gust_series` (same arguments).

        Returns:
            The wind field; with ``TurbulenceLevel.NONE`` its gusts are exactly zero.
        """
        gusts = gust_series(conditions, seed, duration_s, height_agl_m, airspeed_m_s, dt_s)
        return cls(conditions.steady_enu_m_s, gusts)

    @property
    def steady_enu_m_s(self) -> NDArray[np.float64]:
        """(3,) read-only steady wind, m/s, ENU."""
        return self._steady

    @property
    def gusts(self) -> GustSeries | None:
        """The gust series, or None."""
        return self._gusts

    @property
    def duration_s(self) -> float:
        """Last time that may be queried, seconds (inf without gusts)."""
        return self._t_end

    def wind_enu_m_s(self, t_s: float) -> NDArray[np.float64]:
        """Wind velocity at one time.

        Args:
            t_s: Time since the start of the episode, seconds, in ``[0, duration_s]``.

        Returns:
            (3,) new array, wind (east, north, up), m/s, world ENU.

        Raises:
            ValueError: If ``t_s`` is outside the series (or not finite).
        """
        t = float(t_s)
        if not 0.0 <= t <= self._t_end:
            raise ValueError(self._range_message(t))
        if self._total is None:
            return self._steady.copy()
        s = t / self._dt
        i = min(int(s), self._last)
        f = s - i
        lo = self._total[i]
        return lo + f * (self._total[i + 1] - lo)

    def wind_enu_m_s_batch(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Wind velocity at many times.

        Args:
            t_s: Times since the start of the episode, seconds, any shape (...).

        Returns:
            (..., 3) wind (east, north, up), m/s, world ENU.

        Raises:
            ValueError: If any time is outside the series (or not finite).
        """
        t = np.asarray(t_s, dtype=np.float64)
        bad = ~((t >= 0.0) & (t <= self._t_end))
        if np.any(bad):
            raise ValueError(self._range_message(float(t[bad].flat[0])))
        if self._total is None:
            return np.broadcast_to(self._steady, t.shape + (3,)).copy()
        s = t / self._dt
        idx = np.minimum(s.astype(np.intp), self._last)
        frac = (s - idx)[..., None]
        lo = self._total[idx]
        return lo + frac * (self._total[idx + 1] - lo)

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (np.array(self._steady), self._gusts))

    def __repr__(self) -> str:
        g = self._gusts
        if g is None:
            gust = "no gusts"
        else:
            gust = f"{g.turbulence.value} gusts seed={g.seed} to {g.duration_s:.2f} s"
        return f"WindField(steady_enu_m_s={self._steady.tolist()}, {gust})"

    def _range_message(self, t: float) -> str:
        return (
            f"wind queried at t={t!r} s, outside [0, {self._t_end}] s; build the WindField with "
            "duration_s >= the last time you will query (e.g. the episode timeout)"
        )


class WindBank:
    """The winds of N vehicles, looked up in one call (the learned pilot's batched environment).

    Vehicle i flies a steady wind plus one of a few shared gust series, started `start` samples
    in, so thousands of episodes reuse a handful of tabulated JSBSim series. Vehicle i's wind is
    exactly (bit for bit) that of `field(i)`, the `WindField` the comparison runner flies: the same
    pre-added rows and the same interpolation.

    Args:
        series: the shared gust series (all with the same dt_s); empty for steady wind only.
        n: number of vehicles.
    """

    def __init__(self, series: Sequence[GustSeries], n: int) -> None:
        self.series = list(series)
        if self.series and len({s.dt_s for s in self.series}) != 1:
            raise ValueError("the gust series of a WindBank must share one dt_s")
        self._gusts = np.stack([s.gust_enu_m_s for s in self.series]) if self.series else np.zeros((1, 2, 3))
        self._dt = self.series[0].dt_s if self.series else math.inf
        self.steady = np.zeros((n, 3))
        self.series_index = np.zeros(n, dtype=np.int64)
        self.start = np.zeros(n, dtype=np.int64)

    @property
    def samples(self) -> int:
        """Samples per gust series."""
        return self._gusts.shape[1]

    @property
    def dt_s(self) -> float:
        """Gust sample spacing, seconds (inf without gusts)."""
        return self._dt

    def assign(self, i: int, steady_enu_m_s: ArrayLike, series_index: int = 0, start: int = 0) -> None:
        """Give vehicle i a steady wind [m/s, ENU] and gust series `series_index` from sample `start` on."""
        self.steady[i] = _checked_vector3("steady_enu_m_s", steady_enu_m_s)
        self.series_index[i] = int(series_index)
        self.start[i] = int(start)

    def wind_enu_m_s(self, t_s: ArrayLike, idx: ArrayLike | None = None) -> NDArray[np.float64]:
        """Wind (M, 3) [m/s, ENU] of vehicles `idx` (default all) at their times t_s (M,) [s]."""
        sel = slice(None) if idx is None else np.asarray(idx, dtype=np.int64)
        steady = self.steady[sel]
        if not self.series:
            return steady.copy()
        t = np.asarray(t_s, dtype=np.float64)
        start, series = self.start[sel], self.series_index[sel]
        s = t / self._dt
        # WindField's clamp: the last interval of the series as seen from `start`
        i = np.minimum(s.astype(np.int64), self._gusts.shape[1] - start - 2)
        f = (s - i)[:, None]
        lo = self._gusts[series, start + i] + steady
        hi = self._gusts[series, start + i + 1] + steady
        return lo + f * (hi - lo)

    def _wind_one(self, i: int, t_s: float) -> tuple[float, float, float]:
        """`wind_enu_m_s` of vehicle i at one time, in plain Python (a single vehicle's environment
        calls this every control period, where NumPy's per-call overhead on one row dominated): the
        same operations in the same order on the same doubles, so the same numbers (tested)."""
        steady = self.steady[i].tolist()
        if not self.series:
            return steady[0], steady[1], steady[2]
        start, series = int(self.start[i]), int(self.series_index[i])
        s = t_s / self._dt
        k = min(int(s), self._gusts.shape[1] - start - 2)
        f = s - k
        g0 = self._gusts[series, start + k].tolist()
        g1 = self._gusts[series, start + k + 1].tolist()
        lo = [a + b for a, b in zip(g0, steady)]
        hi = [a + b for a, b in zip(g1, steady)]
        return lo[0] + f * (hi[0] - lo[0]), lo[1] + f * (hi[1] - lo[1]), lo[2] + f * (hi[2] - lo[2])

    def field(self, i: int) -> WindField:
        """Vehicle i's wind as a `WindField` (the same numbers), for flying its episode elsewhere."""
        if not self.series:
            return WindField(self.steady[i])
        s, k0 = self.series[int(self.series_index[i])], int(self.start[i])
        g = GustSeries(s.t_s[: len(s.t_s) - k0], s.gust_enu_m_s[k0:], s.dt_s, s.turbulence, s.seed,
                       s.airspeed_m_s, s.height_agl_m)
        return WindField(self.steady[i], g)


# ------------------------------------------------------------------------------------ checks
def _checked_vector3(name: str, value: Any) -> tuple[float, float, float]:
    try:
        items = [float(v) for v in value] if not isinstance(value, (str, bytes)) else None
    except (TypeError, ValueError):
        items = None
    if items is None or len(items) != 3 or not all(math.isfinite(v) for v in items):
        raise ValueError(f"{name} must be three finite numbers [east, north, up] in m/s, got {value!r}")
    return (items[0], items[1], items[2])


def _checked_seed(seed: Any) -> int:
    if isinstance(seed, bool):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    try:
        s = operator.index(seed)
    except TypeError:
        raise ValueError(f"seed must be an integer, got {seed!r}") from None
    if not 0 <= s <= MAX_SEED:
        raise ValueError(f"seed must be in [0, {MAX_SEED}] (JSBSim's randomseed is a C int), got {s}")
    return int(s)
