"""The heading aid: true yaw + Gauss-Markov disturbance + white noise, wrapped to (-π, π]."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.sensing.heading import HeadingSensor, wrap_angle
from uam_fdm.sensing.specs import IST8310, RM3100


def test_wrap_angle_range():
    a = np.array([np.pi, -np.pi, 3 * np.pi, -3 * np.pi + 1e-9, 0.1, 2 * np.pi + 0.1, -0.1])
    w = wrap_angle(a)
    np.testing.assert_allclose(w, [np.pi, np.pi, np.pi, -np.pi + 1e-9, 0.1, 0.1, -0.1], atol=1e-12)
    assert np.all((w > -np.pi) & (w <= np.pi))


def test_white_noise_sigma_and_wrapping_near_pi():
    spec = dataclasses.replace(RM3100, disturbance_rad=0.0)
    sensor = HeadingSensor(spec, np.random.default_rng(0))
    yaw = np.pi - 0.001
    readings = np.array([sensor.measure(0.02 * k, yaw).yaw_rad for k in range(20000)])
    assert np.all((readings > -np.pi) & (readings <= np.pi))
    assert np.any(readings < 0.0)  # noise carries some readings across ±π
    err = wrap_angle(readings - yaw)
    assert err.std() == pytest.approx(spec.noise_rad, rel=0.03)
    assert abs(err.mean()) < 4 * spec.noise_rad / np.sqrt(err.size)


def test_disturbance_is_stationary_gauss_markov():
    spec = dataclasses.replace(IST8310, noise_rad=0.0)
    lag = spec.correlation_time_s
    starts, laters = [], []
    for i in range(3000):
        sensor = HeadingSensor(spec, np.random.default_rng(i))
        starts.append(sensor.measure(0.0, 0.0).yaw_rad)
        for k in range(1, 11):  # ten steps to one correlation time
            later = sensor.measure(k * lag / 10, 0.0).yaw_rad
        laters.append(later)
    starts_a, laters_a = np.array(starts), np.array(laters)
    assert starts_a.std() == pytest.approx(spec.disturbance_rad, rel=0.05)  # stationary from the start
    assert laters_a.std() == pytest.approx(spec.disturbance_rad, rel=0.05)
    assert np.corrcoef(starts_a, laters_a)[0, 1] == pytest.approx(np.exp(-1.0), abs=0.04)  # e^{-Δt/τ}


def test_same_seed_same_readings():
    def series(seed: int) -> list[float]:
        sensor = HeadingSensor(IST8310, np.random.default_rng(seed))
        return [sensor.measure(0.02 * k, 0.3).yaw_rad for k in range(100)]
    assert series(1) == series(1)
    assert series(1) != series(2)
