"""A heading aid: a calibrated magnetometer read as yaw.

Reading = true yaw + a slowly varying disturbance (steel and currents near buildings; a first-order
Gauss-Markov process of σ `disturbance_rad` and correlation time `correlation_time_s`, stationary from the
start) + white noise of σ `noise_rad`, wrapped to (-π, π].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uam_fdm.sensing.specs import HeadingSpec


def wrap_angle(angle_rad: float | np.ndarray) -> float | np.ndarray:
    """An angle [rad] wrapped to (-π, π]."""
    return np.pi - np.mod(np.pi - angle_rad, 2.0 * np.pi)


@dataclass(frozen=True)
class HeadingReading:
    """One heading (no truth).

    Attributes:
        t_s: time [s].
        yaw_rad: measured yaw [rad] in (-π, π]: the body x axis's angle from east (world ENU), counter-clockwise.
    """

    t_s: float
    yaw_rad: float


class HeadingSensor:
    """A simulated heading aid (reads the true yaw; its readings carry none).

    Args:
        spec: the part's noise figures.
        rng: the Generator every draw comes from.
    """

    def __init__(self, spec: HeadingSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self._rng = rng
        self._disturbance = float(rng.normal(0.0, spec.disturbance_rad))
        self._t_last: float | None = None

    @property
    def disturbance_rad(self) -> float:
        """The current slowly varying error [rad] (simulator side, for tests and diagnostics)."""
        return self._disturbance

    def measure(self, t_s: float, true_yaw_rad: float) -> HeadingReading:
        """The heading at time t_s [s] of a vehicle whose true yaw is true_yaw_rad [rad].

        Raises:
            ValueError: a time before the previous reading's.
        """
        dt = 0.0 if self._t_last is None else t_s - self._t_last
        if dt < 0.0:
            raise ValueError("heading reading times must not go backwards")
        spec = self.spec
        phi = math.exp(-dt / spec.correlation_time_s) if spec.correlation_time_s > 0.0 else 0.0
        self._disturbance = phi * self._disturbance + spec.disturbance_rad * math.sqrt(1.0 - phi * phi) * float(
            self._rng.standard_normal())
        self._t_last = float(t_s)
        yaw = true_yaw_rad + self._disturbance + spec.noise_rad * float(self._rng.standard_normal())
        return HeadingReading(float(t_s), float(wrap_angle(yaw)))
