"""The barometer: pressure at the true height from the JSBSim atmosphere, read as ISA pressure altitude."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.sensing.baro import Barometer, pressure_altitude_m
from uam_fdm.sensing.specs import BMP388, MS5611

QUIET = dataclasses.replace(MS5611, noise_m=0.0, drift_m_rthz=0.0)


@pytest.fixture(scope="module")
def days() -> dict[str, Atmosphere]:
    def day(elevation_m: float, offset_k: float) -> Atmosphere:
        return Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=elevation_m, isa_offset_k=offset_k),
                                      z_max_m=400.0, z_min_m=-20.0)
    return {"isa": day(0.0, 0.0), "hot": day(0.0, 20.0), "cold": day(0.0, -20.0), "hot_high": day(1500.0, 20.0)}


def test_pressure_altitude_formula_matches_the_isa_table():
    # ICAO standard atmosphere: 89 874.6 Pa at 1 000 m, 79 495.2 Pa at 2 000 m, 101 325 Pa at 0 m
    assert pressure_altitude_m(101325.0) == pytest.approx(0.0, abs=1e-9)
    assert pressure_altitude_m(89874.6) == pytest.approx(1000.0, abs=0.1)
    assert pressure_altitude_m(79495.2) == pytest.approx(2000.0, abs=0.1)


def test_isa_day_reads_the_true_height_gain(days):
    baro = Barometer(QUIET, days["isa"], 0.0, np.random.default_rng(0))
    for z in (0.0, 50.0, 150.0, 300.0):
        assert baro.measure(0.0, z).altitude_m == pytest.approx(z, abs=0.01)
    # and the column is the table's: pressure at 300 m within 0.01 % of JSBSim's standard atmosphere
    assert baro.pressure_pa(300.0) == pytest.approx(days["isa"].sample(300.0).pressure_pa, rel=1e-4)


def test_isa_day_errors_are_the_spec_noise(days):
    baro = Barometer(MS5611, days["isa"], 0.0, np.random.default_rng(1))
    t = np.arange(1, 5001) / MS5611.rate_hz
    z = 100.0 + 50.0 * np.sin(0.05 * t)
    err = np.array([baro.measure(ti, zi).altitude_m - zi for ti, zi in zip(t, z)])
    offset = baro.offset_m
    assert np.std(np.diff(err)) / np.sqrt(2.0) == pytest.approx(MS5611.noise_m, rel=0.05)  # white part
    assert abs(offset) < 5 * MS5611.drift_m_rthz * np.sqrt(t[-1])  # the drift is a slow random walk
    assert np.abs(err).max() < abs(offset) + 5 * MS5611.noise_m + 0.02


@pytest.mark.parametrize("day,elevation", [("hot", 0.0), ("hot_high", 1500.0)])
def test_hot_day_under_reads_the_climb_by_t_std_over_t(days, day, elevation):
    atm = days[day]
    baro = Barometer(QUIET, atm, 0.0, np.random.default_rng(0))
    gain = baro.measure(0.0, 300.0).altitude_m
    # hypsometric: Δh_pressure / Δz = T_std / T_actual at the layer's mean (ISA lapse 6.5 K/km)
    t_std = 288.15 - 0.0065 * (elevation + 150.0)
    ratio = t_std / float(atm.sample(150.0).temperature_k)
    assert ratio == pytest.approx(t_std / (t_std + 20.0), rel=1e-3)
    assert gain == pytest.approx(300.0 * ratio, rel=2e-3)
    assert gain < 300.0 - 15.0  # ~6.5 % low: the aircraft is ~19 m higher than it reads


def test_cold_day_over_reads(days):
    baro = Barometer(QUIET, days["cold"], 0.0, np.random.default_rng(0))
    gain = baro.measure(0.0, 300.0).altitude_m
    assert gain == pytest.approx(300.0 * (288.15 - 0.975) / (288.15 - 0.975 - 20.0), rel=2e-3)
    assert gain > 300.0


def test_zeroed_at_take_off_height(days):
    baro = Barometer(QUIET, days["hot"], 40.0, np.random.default_rng(0))  # a rooftop take-off
    assert baro.measure(0.0, 40.0).altitude_m == pytest.approx(0.0, abs=1e-9)
    assert baro.measure(0.1, 20.0).altitude_m < 0.0


def test_same_seed_same_readings(days):
    def series(seed: int) -> list[float]:
        baro = Barometer(BMP388, days["isa"], 0.0, np.random.default_rng(seed))
        return [baro.measure(0.02 * k, 10.0).altitude_m for k in range(200)]
    assert series(3) == series(3)
    assert series(3) != series(4)


def test_time_must_not_go_backwards(days):
    baro = Barometer(MS5611, days["isa"], 0.0, np.random.default_rng(0))
    baro.measure(1.0, 0.0)
    with pytest.raises(ValueError):
        baro.measure(0.5, 0.0)
