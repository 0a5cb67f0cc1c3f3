"""The IMU model: white noise from the densities, biases drawn then random-walking, all from the Generator."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.sensing.imu import Imu
from uam_fdm.sensing.specs import BMI088, HG4930

QUIET_BIAS = dict(accel_bias_walk_m_s3_rthz=0.0, gyro_bias_walk_rad_s2_rthz=0.0)


def _still(k: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(1, k + 1) / rate_hz
    return t, np.tile([0.0, 0.0, 9.80665], (k, 1)), np.zeros((k, 3))


@pytest.mark.parametrize("spec", [BMI088, HG4930], ids=lambda s: s.part)
def test_white_noise_sigma_is_density_times_root_rate(spec):
    imu = Imu(dataclasses.replace(spec, **QUIET_BIAS), np.random.default_rng(1))
    t, force, rate = _still(40_000, spec.rate_hz)
    s = imu.measure(t, force, rate)
    accel_err = s.accel_m_s2 - force - imu.accel_bias_m_s2
    gyro_err = s.gyro_rad_s - rate - imu.gyro_bias_rad_s
    np.testing.assert_allclose(accel_err.std(axis=0), spec.accel_noise_density_m_s2_rthz * np.sqrt(spec.rate_hz),
                               rtol=0.02)
    np.testing.assert_allclose(gyro_err.std(axis=0), spec.gyro_noise_density_rad_s_rthz * np.sqrt(spec.rate_hz),
                               rtol=0.02)
    assert np.abs(accel_err.mean(axis=0)).max() < 4 * accel_err.std() / np.sqrt(t.size)  # bias removed exactly


def test_initial_biases_have_the_spec_sigma():
    draws = [Imu(BMI088, np.random.default_rng(i)) for i in range(3000)]
    accel = np.array([d.accel_bias_m_s2 for d in draws])
    gyro = np.array([d.gyro_bias_rad_s for d in draws])
    assert accel.std() == pytest.approx(BMI088.accel_bias_initial_m_s2, rel=0.03)
    assert gyro.std() == pytest.approx(BMI088.gyro_bias_initial_rad_s, rel=0.03)
    assert abs(accel.mean()) < 0.05 * BMI088.accel_bias_initial_m_s2


def test_biases_random_walk_at_the_spec_density():
    spec = dataclasses.replace(BMI088, accel_noise_density_m_s2_rthz=0.0, gyro_noise_density_rad_s_rthz=0.0)
    k, seconds = 100, 20.0
    t = np.linspace(seconds / k, seconds, k)
    steps_a, steps_g = [], []
    for i in range(600):
        imu = Imu(spec, np.random.default_rng(i))
        a0, g0 = imu.accel_bias_m_s2, imu.gyro_bias_rad_s
        imu.measure(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))  # starts the clock at t = 0
        s = imu.measure(t, np.zeros((k, 3)), np.zeros((k, 3)))
        np.testing.assert_array_equal(s.accel_m_s2[-1], imu.accel_bias_m_s2)  # noise-free: reading = bias
        steps_a.append(imu.accel_bias_m_s2 - a0)
        steps_g.append(imu.gyro_bias_rad_s - g0)
    # after 20 s the walk's σ is walk·√20 s
    assert np.std(steps_a) == pytest.approx(spec.accel_bias_walk_m_s3_rthz * np.sqrt(seconds), rel=0.05)
    assert np.std(steps_g) == pytest.approx(spec.gyro_bias_walk_rad_s2_rthz * np.sqrt(seconds), rel=0.05)


def test_same_seed_same_samples_and_no_truth_in_them():
    t, force, rate = _still(500, BMI088.rate_hz)
    a = Imu(BMI088, np.random.default_rng(5)).measure(t, force, rate)
    b = Imu(BMI088, np.random.default_rng(5)).measure(t, force, rate)
    c = Imu(BMI088, np.random.default_rng(6)).measure(t, force, rate)
    np.testing.assert_array_equal(a.accel_m_s2, b.accel_m_s2)
    np.testing.assert_array_equal(a.gyro_rad_s, b.gyro_rad_s)
    assert not np.array_equal(a.accel_m_s2, c.accel_m_s2)
    assert set(vars(a)) == {"t_s", "accel_m_s2", "gyro_rad_s"}


def test_time_must_not_go_backwards():
    imu = Imu(BMI088, np.random.default_rng(0))
    imu.measure(np.array([1.0]), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError):
        imu.measure(np.array([0.5]), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError):
        imu.measure(np.array([2.0, 3.0]), np.zeros((3, 3)), np.zeros((2, 3)))
