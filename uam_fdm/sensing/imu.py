"""A strapdown IMU: the true specific force and body rates plus white noise and drifting biases.

Noise model (the usual continuous-time one, e.g. Kalibr's "IMU noise model"): each axis reads truth + bias +
white noise; the white noise of a sample at rate f has σ = density·√f; each bias starts at a draw of σ
`*_bias_initial_*` (what calibration leaves at power-on) and then walks: over Δt it moves by N(0, walk²·Δt).
Every draw comes from the Generator given at construction, in a fixed order, so a seed fixes the readings.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uam_fdm.sensing.specs import ImuSpec


@dataclass(frozen=True)
class ImuSamples:
    """IMU readings (what the flight computer receives; no truth).

    Attributes:
        t_s: (K,) sample times [s]; each sample stands for the interval ending at it.
        accel_m_s2: (K, 3) measured specific force [m/s²], body FLU (at rest level: about +9.81 on z).
        gyro_rad_s: (K, 3) measured body rates [rad/s], body FLU.
    """

    t_s: np.ndarray
    accel_m_s2: np.ndarray
    gyro_rad_s: np.ndarray


class Imu:
    """A simulated IMU (reads the truth; its samples carry none).

    Args:
        spec: the part's noise figures.
        rng: the Generator every draw comes from (the biases at power-on are drawn here).
    """

    def __init__(self, spec: ImuSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self._rng = rng
        self._accel_bias = rng.normal(0.0, spec.accel_bias_initial_m_s2, 3)
        self._gyro_bias = rng.normal(0.0, spec.gyro_bias_initial_rad_s, 3)
        self._t_last: float | None = None

    @property
    def accel_bias_m_s2(self) -> np.ndarray:
        """The accelerometer's current true bias (3,) [m/s²], body (simulator side, for tests and diagnostics)."""
        return self._accel_bias.copy()

    @property
    def gyro_bias_rad_s(self) -> np.ndarray:
        """The gyro's current true bias (3,) [rad/s], body (simulator side)."""
        return self._gyro_bias.copy()

    def measure(self, t_s: np.ndarray, specific_force_body_m_s2: np.ndarray,
                rate_body_rad_s: np.ndarray) -> ImuSamples:
        """Samples at times t_s of the true specific force and body rates.

        Args:
            t_s: (K,) non-decreasing sample times [s], not before the previous call's last one.
            specific_force_body_m_s2: (K, 3) true specific force (acceleration minus gravity) [m/s²], body FLU.
            rate_body_rad_s: (K, 3) true body rates [rad/s], body FLU.

        Returns:
            The K samples.

        Raises:
            ValueError: shapes that do not match, or times that go backwards.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        force = np.asarray(specific_force_body_m_s2, dtype=np.float64).reshape(-1, 3)
        rate = np.asarray(rate_body_rad_s, dtype=np.float64).reshape(-1, 3)
        if t.ndim != 1 or force.shape[0] != t.size or rate.shape[0] != t.size:
            raise ValueError(f"expected t_s (K,), forces and rates (K, 3); got {t.shape}, {force.shape}, "
                             f"{rate.shape}")
        previous = t[0] if self._t_last is None else self._t_last
        dt = np.diff(np.concatenate(([previous], t)))
        if np.any(dt < 0.0):
            raise ValueError("IMU sample times must not go backwards")
        # one draw of (4, K, 3) is the stream four (K, 3) draws would take, in the same order
        normals = self._rng.standard_normal((4, t.size, 3))
        accel, gyro, accel_bias, gyro_bias = imu_readings(self.spec, force, rate, dt, self._accel_bias,
                                                          self._gyro_bias, normals)
        self._accel_bias, self._gyro_bias = accel_bias[-1].copy(), gyro_bias[-1].copy()
        self._t_last = float(t[-1])
        return ImuSamples(t.copy(), accel, gyro)


def imu_readings(spec: ImuSpec, specific_force_body_m_s2: np.ndarray, rate_body_rad_s: np.ndarray, dt_s: np.ndarray,
                 accel_bias_m_s2: np.ndarray, gyro_bias_rad_s: np.ndarray, normals: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The error model of K samples, for one IMU or a batch of them (leading axes `...`): shared by `Imu` and
    `uam_fdm.sensing.batch_sensors.BatchImu`, so both read the same numbers from the same draws.

    Args:
        spec: the part's noise figures.
        specific_force_body_m_s2: (..., K, 3) true specific force [m/s²], body FLU.
        rate_body_rad_s: (..., K, 3) true body rates [rad/s], body FLU.
        dt_s: (..., K) time from each sample's predecessor [s] (0 for an IMU's first sample).
        accel_bias_m_s2, gyro_bias_rad_s: (..., 3) the biases before the first sample [m/s², rad/s], body.
        normals: (..., 4, K, 3) standard normal draws: accelerometer and gyro white noise, then their bias walks.

    Returns:
        measured specific force (..., K, 3) [m/s²] and rates (..., K, 3) [rad/s], body FLU; the accelerometer and
        gyro biases after each sample (..., K, 3).
    """
    rate_hz = spec.rate_hz
    white_accel = normals[..., 0, :, :] * (spec.accel_noise_density_m_s2_rthz * np.sqrt(rate_hz))
    white_gyro = normals[..., 1, :, :] * (spec.gyro_noise_density_rad_s_rthz * np.sqrt(rate_hz))
    root_dt = np.sqrt(dt_s)[..., None]
    accel_bias = accel_bias_m_s2[..., None, :] + np.cumsum(
        normals[..., 2, :, :] * root_dt * spec.accel_bias_walk_m_s3_rthz, axis=-2)
    gyro_bias = gyro_bias_rad_s[..., None, :] + np.cumsum(
        normals[..., 3, :, :] * root_dt * spec.gyro_bias_walk_rad_s2_rthz, axis=-2)
    return (specific_force_body_m_s2 + accel_bias + white_accel, rate_body_rad_s + gyro_bias + white_gyro,
            accel_bias, gyro_bias)
