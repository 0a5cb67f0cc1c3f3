"""A static-pressure barometer read as pressure altitude above the take-off point.

The device measures the static pressure at the vehicle's true height and converts it with the ISA standard
atmosphere (troposphere: h = T0/L·(1 - (p/p0)^(R·L/g))), zeroed at take-off. On a non-standard day the true
column's pressure falls with height at a different rate than the standard one, so the altitude read is off: on a
hot day the pressure falls more slowly, the altimeter under-reads the climb (the aircraft is higher than it
reads) by about T_std/T_actual.

The pressure at height z comes from the project's JSBSim atmosphere: its pressure at the field anchors the
column, and the hydrostatic equation of an ideal gas, dp/dz = -p·g/(R·T(z)), carries it up through the table's
temperature of the day. (`Atmosphere.sample(z).pressure_pa` itself is the standard day's pressure at every
height, by that module's density-altitude convention: read directly, an altimeter would be exact on every day.)
On the ISA day the two agree (the standard atmosphere is hydrostatic).

Errors: white noise of σ `noise_m`, plus an offset that random-walks at `drift_m_rthz` (temperature drift of the
sensor) from zero at take-off.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.sensing.specs import BaroSpec

ISA_SEA_LEVEL_PRESSURE_PA = 101325.0
ISA_SEA_LEVEL_TEMPERATURE_K = 288.15
ISA_LAPSE_RATE_K_M = 0.0065
AIR_GAS_CONSTANT_J_KG_K = 287.05287
GRAVITY_M_S2 = 9.80665
_ISA_EXPONENT = AIR_GAS_CONSTANT_J_KG_K * ISA_LAPSE_RATE_K_M / GRAVITY_M_S2  # R·L/g ≈ 0.190263


def pressure_altitude_m(pressure_pa: float | np.ndarray) -> float | np.ndarray:
    """ISA (troposphere) pressure altitude [m] of a static pressure [Pa]: what a standard altimeter reads."""
    return ISA_SEA_LEVEL_TEMPERATURE_K / ISA_LAPSE_RATE_K_M * (
        1.0 - (np.asarray(pressure_pa) / ISA_SEA_LEVEL_PRESSURE_PA) ** _ISA_EXPONENT)


@dataclass(frozen=True)
class BaroReading:
    """One barometric altitude (no truth).

    Attributes:
        t_s: time [s].
        altitude_m: pressure altitude above the take-off point [m].
    """

    t_s: float
    altitude_m: float


class Barometer:
    """A simulated barometer (reads the true height; its readings carry none).

    Args:
        spec: the part's noise figures.
        atmosphere: the day's atmosphere above the field (its temperature profile and field pressure).
        home_z_m: take-off height [m above the field], where the reading is zeroed.
        rng: the Generator every draw comes from.
    """

    def __init__(self, spec: BaroSpec, atmosphere: Atmosphere, home_z_m: float, rng: np.random.Generator) -> None:
        self.spec = spec
        self._rng = rng
        heights = atmosphere.heights_m
        inv_t = 1.0 / atmosphere.table[:, 1]
        # ∫ dz / T(z) from the table's first row, trapezoidal on its grid (T is piecewise linear there)
        self._z = heights
        self._inv_t = inv_t
        self._integral = np.concatenate(([0.0], np.cumsum(0.5 * (inv_t[1:] + inv_t[:-1]) * np.diff(heights))))
        z_ref = min(max(0.0, atmosphere.z_min_m), atmosphere.z_max_m)
        p_ref = float(atmosphere.sample(z_ref).pressure_pa)
        self._log_p0 = math.log(p_ref) + GRAVITY_M_S2 / AIR_GAS_CONSTANT_J_KG_K * self._column(z_ref)
        self._home_altitude_m = float(pressure_altitude_m(self.pressure_pa(home_z_m)))
        self._offset_m = 0.0
        self._t_last: float | None = None

    def _column(self, z_m: float) -> float:
        """∫ dz/T [m/K] from the table's first row to z (beyond the table: its edge temperature held)."""
        z, inv_t, integral = self._z, self._inv_t, self._integral
        if z_m <= z[0]:
            return float((z_m - z[0]) * inv_t[0])
        if z_m >= z[-1]:
            return float(integral[-1] + (z_m - z[-1]) * inv_t[-1])
        return float(np.interp(z_m, z, integral))

    def pressure_pa(self, z_m: float) -> float:
        """The true static pressure [Pa] at height z_m [m above the field] on this day."""
        return math.exp(self._log_p0 - GRAVITY_M_S2 / AIR_GAS_CONSTANT_J_KG_K * self._column(z_m))

    @property
    def offset_m(self) -> float:
        """The current drift offset [m] (simulator side, for tests and diagnostics)."""
        return self._offset_m

    def measure(self, t_s: float, z_m: float) -> BaroReading:
        """The reading at time t_s [s] of a vehicle at true height z_m [m above the field].

        Raises:
            ValueError: a time before the previous reading's.
        """
        dt = 0.0 if self._t_last is None else t_s - self._t_last
        if dt < 0.0:
            raise ValueError("barometer reading times must not go backwards")
        self._offset_m += self.spec.drift_m_rthz * math.sqrt(dt) * float(self._rng.standard_normal())
        self._t_last = float(t_s)
        altitude = float(pressure_altitude_m(self.pressure_pa(z_m))) - self._home_altitude_m
        return BaroReading(float(t_s), altitude + self._offset_m + self.spec.noise_m * float(
            self._rng.standard_normal()))
