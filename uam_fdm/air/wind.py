"""Wind from JSBSim: a steady wind sheared with height plus Dryden gusts tabulated in time and height.

The wind at time t and height z above the field is ``steady(z) + gust(t, z)``, world ENU [m/s], the same at
every horizontal point of the map. The steady part is the scenario's (``wind_mps: [e, n, u]`` at a reference
height, 10 m by default) shaped by its shear law (`uam_fdm.air.shear`; horizontal components only). The gust
part is a :class:`GustStack`: JSBSim's own turbulence model (``FGWinds``, turb-type 3, "Milspec": the
MIL-F-8785C Dryden spectra), run once per episode at each height of a ladder of probes (`PROBE_HEIGHTS_M`,
trimmed to the flight volume by `probe_heights_up_to`) and tabulated, so that the gusts are the standard's
and the physics loop only interpolates in NumPy: linearly in time and in log height, clamped to the
ladder's lowest and highest rung.

What the gusts are, and are not:

* Heights are above the field, not above sea level: a city at 1500 m elevation gets the low-altitude
  turbulence MIL-F-8785C prescribes above its rooftops (intensities and scale lengths by height:
  `milspec_low_altitude`).
* A gust series is what a probe sees flying level at one reference airspeed per episode, chosen by the
  caller (`turbulence_airspeed_m_s`); the gusts do not vary across the map or with the vehicle's own
  airspeed.
* The longitudinal gust lies along the steady horizontal wind, the lateral one 90 degrees to its right
  (north and east in calm air). Translational components only (no p, q, r).
* Levels (`TurbulenceLevel`): W20, the wind 20 ft above ground, is 15 / 30 / 45 kt for light / moderate /
  severe (MIL-F-8785C 3.7.2.3; low-altitude sigma_w = 0.1 W20), the level's and not the scenario's wind.
* One integer seed gives bit-identical stacks, in the same or another process.

The ladder's spacing, the probe model, the orientation, the cost and the measured statistics:
docs/design_notes.md, "uam_fdm.air.wind".
"""

from __future__ import annotations

import bisect
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

from uam_fdm.air.atmosphere import FT_TO_M, jsbsim_exec, load_probe_model
from uam_fdm.air.shear import ShearLaw, WindShear
from uam_fdm.files.strict import checked_number

__all__ = [
    "PROBE_HEIGHTS_M",
    "ShearLaw",
    "TurbulenceLevel",
    "WindConditions",
    "WindShear",
    "GustSeries",
    "GustStack",
    "WindBank",
    "WindField",
    "gust_series",
    "gust_stack",
    "milspec_low_altitude",
    "probe_heights_up_to",
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

#: Probe heights above the field [m] of a gust stack: doublings from 5 m, then the top of
#: MIL-F-8785C's low-altitude model (1000 ft = 305 m). See the module docstring for why.
PROBE_HEIGHTS_M = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 300.0)
LOW_ALTITUDE_TOP_M = 1000.0 * FT_TO_M


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
            Given at ``shear.reference_height_m`` above the field.
        turbulence: Intensity of JSBSim's Dryden turbulence; a string is accepted and parsed.
        shear: How the steady wind's horizontal part varies with height (default: uniform).

    Raises:
        ValueError: If the wind is not three finite numbers, exceeds 60 m/s, or the turbulence
            level is unknown.
    """

    steady_enu_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence: TurbulenceLevel = TurbulenceLevel.NONE
    shear: WindShear = WindShear()

    def __post_init__(self) -> None:
        object.__setattr__(self, "steady_enu_m_s", _checked_vector3("steady_enu_m_s", self.steady_enu_m_s))
        speed = math.hypot(*self.steady_enu_m_s)
        if speed > MAX_STEADY_WIND_M_S:
            raise ValueError(
                f"steady wind speed {speed:.1f} m/s exceeds {MAX_STEADY_WIND_M_S} m/s "
                "(wind_mps is in metres per second, [east, north, up])"
            )
        object.__setattr__(self, "turbulence", TurbulenceLevel.parse(self.turbulence))
        if not isinstance(self.shear, WindShear):
            raise ValueError(f"shear must be a WindShear, got {self.shear!r}")


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
    t_s = dt_s * np.arange(n_samples, dtype=np.float64)
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
        # the property node, not fdm[name]: the same double set, without a name lookup per step (-20 %)
        pin = fdm.get_property_manager().get_node("position/h-sl-ft").set_double_value
        for _ in range(n_spinup):
            pin(h_ft)  # pin the height: removes the tiny residual drift
            fdm.run()
        for k in range(n_samples):
            pin(h_ft)
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


def milspec_low_altitude(height_agl_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                            NDArray[np.float64]]:
    """MIL-F-8785C's low-altitude Dryden parameters (3.7.2.1, 3.7.2.3) at heights above ground.

    Args:
        height_agl_m: Heights above the field [m], any shape; clamped to [10 ft, 1000 ft] as FGWinds does.

    Returns:
        (sigma_u / sigma_w (= sigma_v / sigma_w), L_u = L_v [m], L_w [m]), each of the input's shape:
        sigma_u / sigma_w = 1 / (0.177 + 0.000823 h)^0.4, L_u = h / (0.177 + 0.000823 h)^1.2, L_w = h
        (h in feet); sigma_w = 0.1 W20 at every height.
    """
    h_ft = np.clip(np.asarray(height_agl_m, dtype=np.float64) / FT_TO_M, 10.0, 1000.0)
    d = 0.177 + 0.000823 * h_ft
    return d ** -0.4, h_ft / d**1.2 * FT_TO_M, h_ft * FT_TO_M


def probe_heights_up_to(ceiling_m: float, ladder: Sequence[float] = PROBE_HEIGHTS_M) -> tuple[float, ...]:
    """The rungs of `ladder` a flight below `ceiling_m` [m above the field] needs: every rung up to
    the first at or above the ceiling (at least two; all of them if the ceiling is above the top)."""
    ladder = tuple(float(h) for h in ladder)
    k = next((i for i, h in enumerate(ladder) if h >= ceiling_m), len(ladder) - 1)
    return ladder[: max(k, 1) + 1]


def turbulence_airspeed_m_s(max_speed_m_s: float, steady_wind_m_s: float = 0.0) -> float:
    """The reference airspeed of a flight's turbulence model [m/s] (one per flight, see `gust_stack`): the
    vehicle's top speed, or the steady wind's speed when that is stronger (holding station against it is
    flying at that airspeed), within [1, 100] m/s. The comparison's runner and the learned pilot's
    environment both take it from here."""
    return float(np.clip(max(max_speed_m_s, steady_wind_m_s), 1.0, 100.0))


@dataclass(frozen=True, eq=False)
class GustStack:
    """Gust series at a ladder of probe heights, filters of the same white noise (one seed, one spin-up).

    Attributes:
        t_s: (M,) sample times, seconds from the start of the episode, ``k * dt_s``.
        heights_m: (H,) probe heights above the field, metres, strictly increasing.
        gust_enu_m_s: (M, H, 3) gust velocity, m/s, world ENU (time x height x axis).
        dt_s: Sample spacing, seconds.
        turbulence: Level the stack was generated for.
        seed: Seed every rung was generated from.
        airspeed_m_s: Probe airspeed that set the Dryden time scales, m/s.
    """

    t_s: NDArray[np.float64]
    heights_m: tuple[float, ...]
    gust_enu_m_s: NDArray[np.float64]
    dt_s: float
    turbulence: TurbulenceLevel
    seed: int
    airspeed_m_s: float

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=np.float64)
        g = np.array(self.gust_enu_m_s, dtype=np.float64)
        heights = tuple(float(h) for h in self.heights_m)
        if t.ndim != 1 or t.size < 2 or g.shape != (t.size, len(heights), 3) or not heights:
            raise ValueError(f"GustStack needs t_s (M>=2,), heights_m (H>=1,) and gust_enu_m_s (M, H, 3); "
                             f"got {t.shape}, {len(heights)} heights, {g.shape}")
        if heights[0] <= 0.0 or any(b <= a for a, b in zip(heights, heights[1:])):
            raise ValueError(f"heights_m must be positive and strictly increasing, got {heights}")
        t.setflags(write=False)
        g.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "gust_enu_m_s", g)
        object.__setattr__(self, "heights_m", heights)

    @property
    def duration_s(self) -> float:
        """Time of the last sample, seconds."""
        return float(self.t_s[-1])

    def from_sample(self, k0: int) -> GustStack:
        """The same stack started `k0` samples in (times from 0 again); shares the arrays' memory."""
        m = self.t_s.shape[0]
        return GustStack(self.t_s[: m - k0], self.heights_m, self.gust_enu_m_s[k0:], self.dt_s, self.turbulence,
                         self.seed, self.airspeed_m_s)


def gust_stack(
    conditions: WindConditions,
    seed: int,
    duration_s: float,
    airspeed_m_s: float,
    heights_m: Sequence[float] = PROBE_HEIGHTS_M,
    dt_s: float = 1.0 / 120.0,
    spinup_s: float | None = None,
) -> GustStack:
    """JSBSim's Dryden turbulence at each probe height, all with the same seed and spin-up.

    FGWinds draws the same Gaussian numbers per step whatever the height, so with one seed and one
    spin-up the rungs are different filters (intensities, scale lengths) of the same white noise,
    and interpolating between them in height is smooth.

    Args:
        conditions: Steady wind (sets the longitudinal axis) and turbulence level.
        seed: Integer seed in [0, 2**31 - 1].
        duration_s: Length to cover, seconds (at least the last time the caller will query).
        airspeed_m_s: Reference airspeed of the probe, m/s, the same at every height.
        heights_m: Probe heights above the field [m], strictly increasing (default `PROBE_HEIGHTS_M`;
            `probe_heights_up_to(ceiling)` for a flight volume's rungs).
        dt_s: Sample spacing, seconds.
        spinup_s: Filter run-in before recording, seconds; default three times the largest
            MIL-F-8785C scale length on the ladder (L_u at the top rung; 1750 ft above 1000 ft)
            over the airspeed.

    Returns:
        The stack (exactly zero, without running JSBSim, for ``TurbulenceLevel.NONE``).

    Raises:
        ValueError: If an argument is out of range.
        RuntimeError: If JSBSim fails.
    """
    heights = tuple(checked_number("heights_m", h, HEIGHT_RANGE_M, "m above the field", open_low=True)
                    for h in heights_m)
    airspeed_m_s = checked_number("airspeed_m_s", airspeed_m_s, AIRSPEED_RANGE_M_S, "m/s")
    if not heights:
        raise ValueError("heights_m must name at least one probe height")
    if spinup_s is None:
        top = heights[-1]
        largest = float(milspec_low_altitude(top)[1]) if top <= LOW_ALTITUDE_TOP_M else MAX_SCALE_LENGTH_M
        spinup_s = SPINUP_SCALE_LENGTHS * largest / airspeed_m_s
    rungs = [gust_series(conditions, seed, duration_s, h, airspeed_m_s, dt_s, spinup_s) for h in heights]
    gusts = np.stack([r.gust_enu_m_s for r in rungs], axis=1)
    return GustStack(rungs[0].t_s, heights, gusts, rungs[0].dt_s, conditions.turbulence, rungs[0].seed, airspeed_m_s)


class _Ladder:
    """Where a height falls among a stack's probe heights: rung j and weight g, linear in log height,
    clamped to the ladder's ends. `cell` (one height, plain Python) and `cells` (an array) give the
    same numbers: both take NumPy's log (Python's math.log differs in the last bit for a few inputs)."""

    def __init__(self, heights_m: Sequence[float]) -> None:
        h = np.array(heights_m, dtype=np.float64)
        self.single = h.size == 1
        self.lo, self.hi = float(h[0]), float(h[-1])
        self.log_h = np.log(h)
        self.step = np.diff(self.log_h) if h.size > 1 else np.ones(1)
        self.top = max(h.size - 2, 0)
        self._log_h, self._step = self.log_h.tolist(), self.step.tolist()

    def cell(self, z_m: float) -> tuple[int, float]:
        """(rung j, weight g in [0, 1]) of one height [m above the field]."""
        lz = float(np.log(min(max(z_m, self.lo), self.hi)))
        j = min(max(bisect.bisect_right(self._log_h, lz) - 1, 0), self.top)
        return j, (lz - self._log_h[j]) / self._step[j]

    def cells(self, z_m: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """`cell` of each height of an array, any shape."""
        lz = np.log(np.minimum(np.maximum(z_m, self.lo), self.hi))
        j = np.minimum(np.maximum(np.searchsorted(self.log_h, lz, side="right") - 1, 0), self.top)
        return j, (lz - self.log_h[j]) / self.step[j]


def _steady_rows(steady: NDArray[np.float64], shear: WindShear, z_m: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3) steady wind at heights z_m (...): horizontal rows of `steady` (3,) or (..., 3) scaled by
    the shear factor, the vertical one kept. The one formula of WindField and WindBank."""
    k = shear.factor(z_m)
    out = np.empty(np.shape(z_m) + (3,))
    out[..., 0] = steady[..., 0] * k
    out[..., 1] = steady[..., 1] * k
    out[..., 2] = steady[..., 2]
    return out


class WindField:
    """Wind seen by the vehicle: steady (sheared with height) + gusts tabulated in time and height.

    The gusts are interpolated linearly in time and linearly in log height between the stack's
    probe heights (clamped to its lowest and highest rung); the steady wind follows the shear law
    (`uam_fdm.air.shear`). NumPy only. Queries before t = 0 or after the end of the gust stack raise
    ``ValueError``: holding the last value would silently freeze the turbulence, and the caller
    knows its episode length. :meth:`calm` and a field without gusts have no time limit.
    """

    def __init__(self, steady_enu_m_s: ArrayLike = (0.0, 0.0, 0.0), gusts: GustStack | None = None,
                 shear: WindShear | None = None) -> None:
        """Combine a steady wind with an optional gust stack.

        Args:
            steady_enu_m_s: Steady wind (east, north, up) at the shear's reference height, m/s, world ENU.
            gusts: Tabulated gusts, or None for a steady wind only.
            shear: Steady wind profile over height (None: uniform).
        """
        steady = np.array(_checked_vector3("steady_enu_m_s", steady_enu_m_s), dtype=np.float64)
        steady.setflags(write=False)
        self._steady = steady
        self._shear = shear if shear is not None else WindShear()
        self._sheared = self._shear.law is not ShearLaw.UNIFORM
        self._gusts = gusts
        if gusts is None:
            self._dt = math.inf
            self._t_end = math.inf
        else:
            self._table = gusts.gust_enu_m_s
            self._ladder = _Ladder(gusts.heights_m)
            self._dt = gusts.dt_s
            self._t_end = gusts.duration_s
            self._last = self._table.shape[0] - 2

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
        airspeed_m_s: float,
        heights_m: Sequence[float] = PROBE_HEIGHTS_M,
        dt_s: float = 1.0 / 120.0,
    ) -> WindField:
        """Steady wind and shear of `conditions` plus a gust stack from :func:`gust_stack` (same arguments).

        Returns:
            The wind field; with ``TurbulenceLevel.NONE`` its gusts are exactly zero.
        """
        gusts = gust_stack(conditions, seed, duration_s, airspeed_m_s, heights_m, dt_s)
        return cls(conditions.steady_enu_m_s, gusts, conditions.shear)

    @property
    def steady_enu_m_s(self) -> NDArray[np.float64]:
        """(3,) read-only steady wind at the shear's reference height, m/s, ENU."""
        return self._steady

    @property
    def shear(self) -> WindShear:
        """The steady wind's profile over height."""
        return self._shear

    @property
    def gusts(self) -> GustStack | None:
        """The gust stack, or None."""
        return self._gusts

    @property
    def duration_s(self) -> float:
        """Last time that may be queried, seconds (inf without gusts)."""
        return self._t_end

    def wind_enu_m_s(self, t_s: float, z_m: float) -> NDArray[np.float64]:
        """Wind velocity at one time and height.

        Args:
            t_s: Time since the start of the episode, seconds, in ``[0, duration_s]``.
            z_m: Height above the field (ENU z), metres.

        Returns:
            (3,) new array, wind (east, north, up), m/s, world ENU; the same numbers as
            :meth:`wind_enu_m_s_batch` at (t_s, z_m).

        Raises:
            ValueError: If ``t_s`` is outside the series (or not finite).
        """
        t, z = float(t_s), float(z_m)
        if not 0.0 <= t <= self._t_end:
            raise ValueError(self._range_message(t))
        if self._sheared:
            k = float(self._shear.factor(z))
            steady = np.array([self._steady[0] * k, self._steady[1] * k, self._steady[2]])
        else:
            steady = self._steady
        if self._gusts is None:
            return steady.copy()
        s = t / self._dt
        i = min(int(s), self._last)
        f = s - i
        j, g = self._ladder.cell(z)
        lo = self._table[i, j:j + 2]
        ab = lo + f * (self._table[i + 1, j:j + 2] - lo)  # (2, 3): in time at rungs j and j + 1
        gust = ab[0] if self._ladder.single else ab[0] + g * (ab[1] - ab[0])
        return steady + gust

    def wind_enu_m_s_batch(self, t_s: ArrayLike, z_m: ArrayLike) -> NDArray[np.float64]:
        """Wind velocity at many times and heights.

        Args:
            t_s: Times since the start of the episode, seconds, any shape (...).
            z_m: Heights above the field, metres, broadcastable with t_s.

        Returns:
            (..., 3) wind (east, north, up), m/s, world ENU.

        Raises:
            ValueError: If any time is outside the series (or not finite).
        """
        t, z = np.broadcast_arrays(np.asarray(t_s, dtype=np.float64), np.asarray(z_m, dtype=np.float64))
        z = np.ascontiguousarray(z)
        bad = ~((t >= 0.0) & (t <= self._t_end))
        if np.any(bad):
            raise ValueError(self._range_message(float(t[bad].flat[0])))
        if self._sheared:
            steady = _steady_rows(self._steady, self._shear, z)
        else:
            steady = np.broadcast_to(self._steady, t.shape + (3,))
        if self._gusts is None:
            return steady.copy()
        s = t / self._dt
        i = np.minimum(s.astype(np.intp), self._last)
        f = (s - i)[..., None]
        j, g = self._ladder.cells(z)
        return steady + _bilinear(self._table, i, f, j, g[..., None], self._ladder.single)

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (np.array(self._steady), self._gusts, self._shear))

    def __repr__(self) -> str:
        g = self._gusts
        if g is None:
            gust = "no gusts"
        else:
            gust = f"{g.turbulence.value} gusts seed={g.seed} at {len(g.heights_m)} heights to {g.duration_s:.2f} s"
        return f"WindField(steady_enu_m_s={self._steady.tolist()}, {self._shear.describe()}, {gust})"

    def _range_message(self, t: float) -> str:
        return (
            f"wind queried at t={t!r} s, outside [0, {self._t_end}] s; build the WindField with "
            "duration_s >= the last time you will query (e.g. the episode timeout)"
        )


def _bilinear(table: NDArray[np.float64], i: NDArray[np.intp], f: NDArray[np.float64], j: NDArray[np.intp],
              g: NDArray[np.float64], single: bool) -> NDArray[np.float64]:
    """Gusts (..., 3) from `table` (M, H, 3): linear in time between rows i, i + 1 (weight f (..., 1)),
    then between rungs j, j + 1 (weight g (..., 1)); `single`: one rung, no height interpolation."""
    lo = table[i, j]
    a = lo + f * (table[i + 1, j] - lo)
    if single:
        return a
    lo = table[i, j + 1]
    b = lo + f * (table[i + 1, j + 1] - lo)
    return a + g * (b - a)


class WindBank:
    """The winds of N vehicles, looked up in one call (the learned pilot's batched environment).

    Vehicle i flies a steady wind (sheared with height by one law shared by the bank) plus one of
    a few shared gust stacks, started `start` samples in, so thousands of episodes reuse a handful
    of tabulated JSBSim stacks. Vehicle i's wind is exactly (bit for bit) that of `field(i)`, the
    `WindField` the comparison runner flies: the same operations in the same order.

    Args:
        stacks: the shared gust stacks (one dt_s and one ladder of heights); empty for steady wind only.
        n: number of vehicles.
        shear: the steady wind's profile over height (None: uniform).
    """

    def __init__(self, stacks: Sequence[GustStack], n: int, shear: WindShear | None = None) -> None:
        self.stacks = list(stacks)
        if self.stacks and len({(s.dt_s, s.heights_m) for s in self.stacks}) != 1:
            raise ValueError("the gust stacks of a WindBank must share one dt_s and one ladder of heights")
        self.shear = shear if shear is not None else WindShear()
        self._sheared = self.shear.law is not ShearLaw.UNIFORM
        self._gusts = np.stack([s.gust_enu_m_s for s in self.stacks]) if self.stacks else np.zeros((1, 2, 1, 3))
        self._dt = self.stacks[0].dt_s if self.stacks else math.inf
        self._ladder = _Ladder(self.stacks[0].heights_m if self.stacks else (1.0,))
        self.steady = np.zeros((n, 3))
        self.series_index = np.zeros(n, dtype=np.int64)
        self.start = np.zeros(n, dtype=np.int64)

    @property
    def samples(self) -> int:
        """Samples per gust stack."""
        return self._gusts.shape[1]

    @property
    def dt_s(self) -> float:
        """Gust sample spacing, seconds (inf without gusts)."""
        return self._dt

    def assign(self, i: int, steady_enu_m_s: ArrayLike, series_index: int = 0, start: int = 0) -> None:
        """Give vehicle i a steady wind [m/s, ENU, at the reference height] and gust stack `series_index`
        from sample `start` on."""
        self.steady[i] = _checked_vector3("steady_enu_m_s", steady_enu_m_s)
        self.series_index[i] = int(series_index)
        self.start[i] = int(start)

    def wind_enu_m_s(self, t_s: ArrayLike, z_m: ArrayLike, idx: ArrayLike | None = None) -> NDArray[np.float64]:
        """Wind (M, 3) [m/s, ENU] of vehicles `idx` (default all) at their times t_s (M,) [s] and
        heights z_m (M,) [m above the field]."""
        sel = slice(None) if idx is None else np.asarray(idx, dtype=np.int64)
        z = np.array(z_m, dtype=np.float64).reshape(-1)  # a contiguous copy: see _Ladder
        steady = _steady_rows(self.steady[sel], self.shear, z) if self._sheared else self.steady[sel]
        if not self.stacks:
            return steady.copy()
        t = np.asarray(t_s, dtype=np.float64)
        start, series = self.start[sel], self.series_index[sel]
        s = t / self._dt
        # WindField's clamp: the last interval of the stack as seen from `start`
        i = np.minimum(s.astype(np.int64), self._gusts.shape[1] - start - 2)
        f = (s - i)[:, None]
        j, g = self._ladder.cells(z)
        lo = self._gusts[series, start + i, j]
        a = lo + f * (self._gusts[series, start + i + 1, j] - lo)
        if self._ladder.single:
            return steady + a
        lo = self._gusts[series, start + i, j + 1]
        b = lo + f * (self._gusts[series, start + i + 1, j + 1] - lo)
        return steady + (a + g[:, None] * (b - a))

    def _wind_one(self, i: int, t_s: float, z_m: float) -> tuple[float, float, float]:
        """`wind_enu_m_s` of vehicle i at one time and height, in plain Python (a single vehicle's
        environment calls this every control period, where NumPy's per-call overhead on one row
        dominated): the same operations in the same order on the same doubles (tested)."""
        se, sn, su = self.steady[i].tolist()
        if self._sheared:
            k = float(self.shear.factor(z_m))
            se, sn = se * k, sn * k
        if not self.stacks:
            return se, sn, su
        start, series = int(self.start[i]), int(self.series_index[i])
        s = t_s / self._dt
        k = min(int(s), self._gusts.shape[1] - start - 2)
        f = s - k
        j, g = self._ladder.cell(z_m)
        rows = self._gusts[series, start + k:start + k + 2, j:j + 2].tolist()  # [time][rung][axis]
        out = []
        for c in range(3):
            lo = rows[0][0][c]
            a = lo + f * (rows[1][0][c] - lo)
            if not self._ladder.single:
                lo = rows[0][1][c]
                a = a + g * ((lo + f * (rows[1][1][c] - lo)) - a)
            out.append(a)
        return se + out[0], sn + out[1], su + out[2]

    def field(self, i: int) -> WindField:
        """Vehicle i's wind as a `WindField` (the same numbers), for flying its episode elsewhere."""
        if not self.stacks:
            return WindField(self.steady[i], None, self.shear)
        stack = self.stacks[int(self.series_index[i])].from_sample(int(self.start[i]))
        return WindField(self.steady[i], stack, self.shear)


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
