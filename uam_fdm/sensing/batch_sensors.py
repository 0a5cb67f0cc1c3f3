"""The IMU, barometer and heading aid of N vehicles at once, each vehicle (slot) with its own random streams.

Each class here is the batched form of one scalar sensor (`Imu`, `Barometer`, `HeadingSensor`): the same model,
the same draws from the same Generators in the same order, and the same floating-point operations per slot, so a
slot reads exactly (bit for bit) what the scalar sensor of its seed reads, whatever the other slots do
(tests/uam_fdm/sensing/test_batch_onboard.py pins it). The IMU's error model is shared code
(`uam_fdm.sensing.imu.imu_readings`); the barometer's pressure column and the heading aid's Gauss-Markov step are
written here over arrays. Where the scalar sensor calls a libm function on a Python float (`math.exp`, `math.atan2`,
`**`), so do these, element by element: NumPy's vectorised transcendentals (SIMD) can differ from libm in the last
bit, while + - * / and sqrt are exact in both.

Randomness: a `SlotStreams` holds one Generator per slot and hands out its draws in blocks drawn ahead
(one Generator call per slot per block, not per epoch); a Generator's draws of one kind are one sequence however
they are chunked, so the numbers are those the scalar sensor would draw.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.sensing.baro import _ISA_EXPONENT as ISA_EXPONENT
from uam_fdm.sensing.baro import (
    AIR_GAS_CONSTANT_J_KG_K,
    GRAVITY_M_S2,
    ISA_LAPSE_RATE_K_M,
    ISA_SEA_LEVEL_PRESSURE_PA,
    ISA_SEA_LEVEL_TEMPERATURE_K,
)
from uam_fdm.sensing.heading import wrap_angle
from uam_fdm.sensing.imu import imu_readings
from uam_fdm.sensing.specs import BaroSpec, HeadingSpec, ImuSpec

_G_OVER_R = GRAVITY_M_S2 / AIR_GAS_CONSTANT_J_KG_K  # as `Barometer` groups it: (g / R) · ∫dz/T
_ISA_SCALE_M = ISA_SEA_LEVEL_TEMPERATURE_K / ISA_LAPSE_RATE_K_M


class SlotStreams:
    """One random stream per slot, drawn ahead in blocks.

    Args:
        n: slots.
        block: draws kept ahead per slot (the most one `take` may ask for).
        uniform: True: `Generator.random` draws (uniform over [0, 1)); False: `Generator.standard_normal`.
    """

    def __init__(self, n: int, block: int, *, uniform: bool = False) -> None:
        self._gens: list[np.random.Generator | None] = [None] * n
        self._buf = np.zeros((n, block))
        self._pos = np.full(n, block, dtype=np.intp)  # block: nothing left
        self._block = block
        self._uniform = uniform

    def restart(self, i: int, generator: np.random.Generator) -> None:
        """Slot i draws from `generator` from now on (its next draws come first)."""
        self._gens[i] = generator
        self._pos[i] = self._block

    def take(self, slots: np.ndarray, count: int) -> np.ndarray:
        """The next `count` draws of each slot in `slots` (M,): (M, count), in each stream's order."""
        if count > self._block:
            self._grow(2 * count)
        pos = self._pos[slots]
        for i in slots[pos + count > self._block].tolist():
            self._refill(i)
        pos = self._pos[slots]
        if len(pos) and (pos == pos[0]).all():  # streams in step (slots that started together): a slice
            start = int(pos[0])
            out = self._buf[slots, start:start + count]
        else:  # a flat gather: a third of a 2-D fancy index's cost
            out = np.take(self._buf, (slots * self._block + pos)[:, None] + np.arange(count))
        self._pos[slots] = pos + count
        return out

    def _grow(self, block: int) -> None:
        """Hold `block` draws ahead per slot from now on (each slot's draws not yet taken still come first)."""
        left = self._block - self._pos
        buf = np.zeros((len(left), block))
        for i, k in enumerate(left.tolist()):
            if k:
                buf[i, block - k:] = self._buf[i, self._pos[i]:]
        self._buf, self._pos, self._block = buf, block - left, block

    def _refill(self, i: int) -> None:
        gen = self._gens[i]
        if gen is None:
            raise RuntimeError(f"slot {i} has no stream: reset it first")
        left = self._block - self._pos[i]
        self._buf[i, :left] = self._buf[i, self._pos[i]:]
        self._buf[i, left:] = gen.random(self._block - left) if self._uniform else \
            gen.standard_normal(self._block - left)
        self._pos[i] = 0


class BatchImu:
    """N strapdown IMUs (`Imu`'s model); readings carry no truth.

    Args:
        spec: the part (every slot carries the same).
        n: slots.
        block: standard normal draws kept ahead per slot (each sample takes 12).
    """

    def __init__(self, spec: ImuSpec, n: int, block: int = 2400) -> None:
        self.spec = spec
        self.accel_bias_m_s2 = np.zeros((n, 3))  # each slot's true biases (simulator side), body
        self.gyro_bias_rad_s = np.zeros((n, 3))
        self._t_last = np.full(n, np.nan)  # NaN: no sample yet
        self._normals = SlotStreams(n, block)

    def restart(self, i: int, rng: np.random.Generator) -> None:
        """Power slot i's IMU on with `rng` (its biases drawn as `Imu.__init__` draws them)."""
        self.accel_bias_m_s2[i] = rng.normal(0.0, self.spec.accel_bias_initial_m_s2, 3)
        self.gyro_bias_rad_s[i] = rng.normal(0.0, self.spec.gyro_bias_initial_rad_s, 3)
        self._t_last[i] = np.nan
        self._normals.restart(i, rng)

    def measure(self, slots: np.ndarray, t_s: np.ndarray, specific_force_body_m_s2: np.ndarray,
                rate_body_rad_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """K samples of each slot (`Imu.measure`).

        Args:
            slots: (M,) the slots.
            t_s: (M, K) sample times [s], after each slot's previous sample.
            specific_force_body_m_s2: (M, K, 3) true specific force [m/s²], body FLU.
            rate_body_rad_s: (M, K, 3) true body rates [rad/s], body FLU.

        Returns:
            measured specific force (M, K, 3) [m/s²] and rates (M, K, 3) [rad/s], body FLU.
        """
        m, k = t_s.shape
        previous = np.where(np.isnan(self._t_last[slots]), t_s[:, 0], self._t_last[slots])
        dt = np.diff(np.concatenate((previous[:, None], t_s), axis=1), axis=1)
        normals = self._normals.take(slots, 12 * k).reshape(m, 4, k, 3)
        accel, gyro, accel_bias, gyro_bias = imu_readings(self.spec, specific_force_body_m_s2, rate_body_rad_s, dt,
                                                          self.accel_bias_m_s2[slots], self.gyro_bias_rad_s[slots],
                                                          normals)
        self.accel_bias_m_s2[slots], self.gyro_bias_rad_s[slots] = accel_bias[:, -1], gyro_bias[:, -1]
        self._t_last[slots] = t_s[:, -1]
        return accel, gyro


class PressureColumn:
    """The day's static pressure over height in one atmosphere, as `Barometer` integrates it (the hydrostatic
    equation through the table's temperature, anchored at the field's pressure), for many heights at once.

    Args:
        atmosphere: the day's atmosphere above the field.
    """

    def __init__(self, atmosphere: Atmosphere) -> None:
        heights = atmosphere.heights_m
        inv_t = 1.0 / atmosphere.table[:, 1]
        self._z, self._inv_t = heights, inv_t
        self._integral = np.concatenate(([0.0], np.cumsum(0.5 * (inv_t[1:] + inv_t[:-1]) * np.diff(heights))))
        z_ref = min(max(0.0, atmosphere.z_min_m), atmosphere.z_max_m)
        p_ref = float(atmosphere.sample(z_ref).pressure_pa)
        self._log_p0 = math.log(p_ref) + _G_OVER_R * float(self.column(np.array([z_ref]))[0])

    def column(self, z_m: np.ndarray) -> np.ndarray:
        """∫ dz/T [m/K] from the table's first row to each height z_m (M,) [m] (beyond the table: its edge
        temperature held)."""
        z, inv_t, integral = self._z, self._inv_t, self._integral
        below = (z_m - z[0]) * inv_t[0]
        above = integral[-1] + (z_m - z[-1]) * inv_t[-1]
        return np.where(z_m <= z[0], below, np.where(z_m >= z[-1], above, np.interp(z_m, z, integral)))

    def pressure_altitude_m(self, z_m: np.ndarray) -> list[float]:
        """ISA pressure altitude [m] a standard altimeter reads at each true height z_m (M,) [m above the field]."""
        return _pressure_altitude_m(self._log_p0 - _G_OVER_R * self.column(z_m))


def _pressure_altitude_m(log_p: np.ndarray) -> list[float]:
    """ISA pressure altitudes [m] of static pressures given by their logarithms (M,) [ln Pa]: element by element with
    `math`, as `Barometer` (NumPy's vectorised exp may differ in the last bit)."""
    pressure = map(math.exp, log_p.tolist())
    return [_ISA_SCALE_M * (1.0 - (p / ISA_SEA_LEVEL_PRESSURE_PA) ** ISA_EXPONENT) for p in pressure]


class PressureColumns:
    """Many days' `PressureColumn`s read in one call, each height in its own day's: tabulated on one grid of heights
    (as the pool's atmospheres are), the tables are stacked and interpolated at once, bit for bit as `np.interp`
    interpolates one (`column`); on different grids, day by day.

    Args:
        columns: one per day of the pool.
    """

    def __init__(self, columns: Sequence[PressureColumn]) -> None:
        self.columns = list(columns)
        z = self.columns[0]._z if self.columns else np.zeros(0)
        self._stacked = len(z) >= 2 and all(np.array_equal(c._z, z) for c in self.columns)
        if self._stacked:
            self._z = z
            self._inv_t = np.stack([c._inv_t for c in self.columns])
            self._integral = np.stack([c._integral for c in self.columns])
            self._log_p0 = np.array([c._log_p0 for c in self.columns])

    def pressure_altitude_m(self, field: np.ndarray, z_m: np.ndarray) -> np.ndarray:
        """ISA pressure altitude [m] at each true height z_m (M,) [m above the field] in day `field` (M,) (an index
        of `columns`)."""
        if not self._stacked:
            out = np.empty(len(z_m))
            for f in np.unique(field).tolist():
                rows = np.flatnonzero(field == f)
                out[rows] = self.columns[f].pressure_altitude_m(z_m[rows])
            return out
        z, n, inv_t, integral = self._z, len(self._z), self._inv_t, self._integral
        # np.interp's arithmetic (numpy/_core/src/multiarray/compiled_base.c): the interval by binary search, the
        # table's value on a grid point, else slope * (x - x_j) + y_j; only the entries each height reads
        j = np.clip(np.searchsorted(z, z_m, side="right") - 1, 0, n - 2)
        y0, y1 = integral[field, j], integral[field, j + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            inside = np.where(z_m == z[j], y0, (y1 - y0) / (z[j + 1] - z[j]) * (z_m - z[j]) + y0)
        below = (z_m - z[0]) * inv_t[field, 0]
        above = integral[field, -1] + (z_m - z[-1]) * inv_t[field, -1]
        column = np.where(z_m <= z[0], below, np.where(z_m >= z[-1], above, inside))
        return np.asarray(_pressure_altitude_m(self._log_p0[field] - _G_OVER_R * column))


class BatchBarometer:
    """N barometers (`Barometer`'s model), each slot in one of a pool of atmospheres.

    Args:
        spec: the part.
        atmospheres: the pool of days the slots fly in.
        n: slots.
        block: standard normal draws kept ahead per slot (each reading takes 2).
    """

    def __init__(self, spec: BaroSpec, atmospheres: Sequence[Atmosphere], n: int, block: int = 256) -> None:
        self.spec = spec
        self._columns = PressureColumns([PressureColumn(a) for a in atmospheres])
        self._field = np.zeros(n, dtype=np.intp)
        self._home_m = np.zeros(n)  # the pressure altitude read at take-off height [m]
        self.offset_m = np.zeros(n)  # each slot's drift offset [m] (simulator side)
        self._t_last = np.full(n, np.nan)
        self._normals = SlotStreams(n, block)

    @property
    def fields(self) -> int:
        """The number of atmospheres in the pool."""
        return len(self._columns.columns)

    def restart(self, i: int, rng: np.random.Generator, field: int, home_z_m: float) -> None:
        """Slot i's barometer in atmosphere `field` (an index of the pool), zeroed at home_z_m [m above the field]."""
        self._field[i] = field
        self._home_m[i] = self._columns.columns[field].pressure_altitude_m(np.array([float(home_z_m)]))[0]
        self.offset_m[i] = 0.0
        self._t_last[i] = np.nan
        self._normals.restart(i, rng)

    def measure(self, slots: np.ndarray, t_s: np.ndarray, z_m: np.ndarray) -> np.ndarray:
        """Readings (`Barometer.measure`) at times t_s (M,) [s] of slots (M,) at true heights z_m (M,) [m above the
        field]: pressure altitude above take-off (M,) [m]."""
        dt = np.where(np.isnan(self._t_last[slots]), 0.0, t_s - self._t_last[slots])
        w = self._normals.take(slots, 2)
        root = np.sqrt(dt)  # correctly rounded, as math.sqrt
        offset = self.offset_m[slots] + self.spec.drift_m_rthz * root * w[:, 0]
        self.offset_m[slots] = offset
        self._t_last[slots] = t_s
        altitude = self._columns.pressure_altitude_m(self._field[slots], np.asarray(z_m, float))
        return altitude - self._home_m[slots] + offset + self.spec.noise_m * w[:, 1]


class BatchHeading:
    """N heading aids (`HeadingSensor`'s model: true yaw, a Gauss-Markov disturbance, white noise).

    Args:
        spec: the part.
        n: slots.
        block: standard normal draws kept ahead per slot (each reading takes 2).
    """

    def __init__(self, spec: HeadingSpec, n: int, block: int = 256) -> None:
        self.spec = spec
        self.disturbance_rad = np.zeros(n)  # each slot's slowly varying error [rad] (simulator side)
        self._t_last = np.full(n, np.nan)
        self._normals = SlotStreams(n, block)

    def restart(self, i: int, rng: np.random.Generator) -> None:
        """Slot i's heading aid from `rng` (its disturbance drawn stationary, as `HeadingSensor.__init__`)."""
        self.disturbance_rad[i] = float(rng.normal(0.0, self.spec.disturbance_rad))
        self._t_last[i] = np.nan
        self._normals.restart(i, rng)

    def measure(self, slots: np.ndarray, t_s: np.ndarray, true_yaw_rad: np.ndarray) -> np.ndarray:
        """Headings (`HeadingSensor.measure`) at times t_s (M,) [s] of slots (M,) whose true yaw is true_yaw_rad
        (M,) [rad]: (M,) [rad] in (-π, π]."""
        spec = self.spec
        dt = np.where(np.isnan(self._t_last[slots]), 0.0, t_s - self._t_last[slots])
        if spec.correlation_time_s > 0.0:
            phi = [math.exp(-v / spec.correlation_time_s) for v in dt.tolist()]
        else:
            phi = [0.0] * len(slots)
        drive = np.array([spec.disturbance_rad * math.sqrt(1.0 - p * p) for p in phi])
        w = self._normals.take(slots, 2)
        disturbance = np.array(phi) * self.disturbance_rad[slots] + drive * w[:, 0]
        self.disturbance_rad[slots] = disturbance
        self._t_last[slots] = t_s
        return np.asarray(wrap_angle(true_yaw_rad + disturbance + spec.noise_rad * w[:, 1]))


def yaw_rad(q: np.ndarray) -> np.ndarray:
    """Heading [rad] of attitudes q (M, 4) [w, x, y, z], body FLU -> world ENU: the body x axis's angle from east
    (`uam_fdm.sensing.onboard`'s, with libm's atan2 as it has)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    num = (2.0 * (w * z + x * y)).tolist()
    den = (1.0 - 2.0 * (y * y + z * z)).tolist()
    return np.array([math.atan2(a, b) for a, b in zip(num, den)])
