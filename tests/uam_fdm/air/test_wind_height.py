"""Wind with height: the steady shear laws, and turbulence tabulated at a ladder of probe heights whose
intensities and scale lengths follow MIL-F-8785C's low-altitude model."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import yaml

from compare.scenarios.fingerprint import scenario_fingerprint
from compare.scenarios.scenario import scenario_from_dict
from scenario_box import BASE
from uam_fdm.air.wind import (
    PROBE_HEIGHTS_M,
    GustStack,
    ShearLaw,
    TurbulenceLevel,
    WindBank,
    WindConditions,
    WindField,
    WindShear,
    gust_stack,
    milspec_low_altitude,
    probe_heights_up_to,
)

FT = 0.3048
HEIGHTS = np.array([0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 25.0, 60.0, 150.0, 300.0])


# ----------------------------------------------------------------------------- steady shear
@pytest.mark.parametrize("alpha", [0.16, 0.3, 0.4])
def test_power_law_against_the_formula(alpha: float) -> None:
    shear = WindShear(ShearLaw.POWER, 10.0, exponent=alpha)
    z = np.maximum(HEIGHTS, 1.0)  # the floor: 1 m
    np.testing.assert_allclose(shear.factor(HEIGHTS), (z / 10.0) ** alpha, rtol=1e-14)
    assert shear.factor(10.0) == 1.0 and shear.floor_m == 1.0


@pytest.mark.parametrize("z0", [0.5, 1.0, 2.0])
def test_log_law_against_the_formula(z0: float) -> None:
    shear = WindShear("log", 20.0, roughness_m=z0)  # type: ignore[arg-type]
    floor = max(1.0, 2.0 * z0)
    z = np.maximum(HEIGHTS, floor)
    np.testing.assert_allclose(shear.factor(HEIGHTS), np.log(z / z0) / math.log(20.0 / z0), rtol=1e-14)
    assert shear.factor(20.0) == 1.0 and shear.floor_m == floor
    assert shear.factor(0.0) == shear.factor(floor) > 0.0  # finite and positive at the ground


def test_shear_scales_the_horizontal_wind_only_and_uniform_is_the_default() -> None:
    steady = (6.0, -3.0, 0.5)
    field = WindField.from_conditions(WindConditions(steady, shear=WindShear("power", 10.0, 0.3)),  # type: ignore[arg-type]
                                      1, 5.0, 10.0)
    for z in HEIGHTS:
        k = (max(z, 1.0) / 10.0) ** 0.3
        np.testing.assert_allclose(field.wind_enu_m_s(2.0, z), [6.0 * k, -3.0 * k, 0.5], rtol=1e-14)
    np.testing.assert_array_equal(field.wind_enu_m_s(2.0, 10.0), steady)  # the reference height: the given wind
    uniform = WindField.from_conditions(WindConditions(steady), 1, 5.0, 10.0)
    assert WindConditions().shear == WindShear() and WindShear().law is ShearLaw.UNIFORM
    np.testing.assert_array_equal(uniform.wind_enu_m_s_batch(np.full(len(HEIGHTS), 2.0), HEIGHTS),
                                  np.tile(steady, (len(HEIGHTS), 1)))  # exactly as before shear existed


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"law": "cubic"}, "law must be one of uniform, power, log, got 'cubic'"),
    ({"law": "power"}, "the power law needs exponent"),
    ({"law": "power", "exponent": 0.7}, "exponent=0.7 is outside the accepted range"),
    ({"law": "log", "roughness_m": 0.0}, "roughness_m=0.0 is outside"),
    ({"law": "log", "roughness_m": 1.0, "exponent": 0.2}, "exponent=0.2 does not apply to the log law"),
    ({"law": "log", "roughness_m": 3.0, "reference_height_m": 5.0}, "below the log law's floor 6.0 m"),
    ({"reference_height_m": 0.5}, "reference_height_m=0.5 is outside"),
])
def test_bad_shear_parameters_raise(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        WindShear(**kwargs)


def test_fingerprints_and_run_data_carry_the_shear(tmp_path: Path) -> None:
    def conditions(atmosphere: dict) -> str:
        sc = scenario_from_dict({**BASE, "atmosphere": atmosphere}, "x.yaml", tmp_path)
        return scenario_fingerprint(sc)["conditions"]

    base = {"wind_mps": [3.0, 0.0, 0.0]}
    prints = {conditions(base), conditions({**base, "wind_shear": {"law": "power", "exponent": 0.3}}),
              conditions({**base, "wind_shear": {"law": "power", "exponent": 0.31}}),
              conditions({**base, "wind_shear": {"law": "log", "roughness_m": 1.0}}),
              conditions({**base, "wind_reference_height_m": 20.0})}
    assert len(prints) == 5
    assert conditions(base) == conditions({**base, "wind_shear": {"law": "uniform"}})  # the default, spelled out
    shear = WindShear("log", 10.0, roughness_m=1.0)  # type: ignore[arg-type]
    assert yaml.safe_load(yaml.safe_dump(shear.to_dict())) == {"law": "log", "reference_height_m": 10.0,
                                                               "exponent": None, "roughness_m": 1.0}


# ----------------------------------------------------------------------------- the ladder
def test_probe_heights_cover_the_flight_volume() -> None:
    assert PROBE_HEIGHTS_M[-1] * 3.281 < 1000.0  # all rungs in MIL-F-8785C's low-altitude model
    assert probe_heights_up_to(60.0) == (5.0, 10.0, 20.0, 40.0, 80.0)
    assert probe_heights_up_to(80.0) == (5.0, 10.0, 20.0, 40.0, 80.0)
    assert probe_heights_up_to(2.0) == (5.0, 10.0)
    assert probe_heights_up_to(5000.0) == PROBE_HEIGHTS_M


@pytest.fixture(scope="module")
def stack() -> GustStack:
    """600 s at 20 m/s and 120 Hz at three rungs (~0.7 s of JSBSim)."""
    return gust_stack(WindConditions(turbulence=TurbulenceLevel.LIGHT), 3, 600.0, 20.0, heights_m=(5.0, 20.0, 80.0))


def test_rms_follows_milspec_low_altitude_intensity_with_height(stack: GustStack) -> None:
    """Each axis' RMS at each rung against sigma_w = 0.1 W20, sigma_u = sigma_v = sigma_w / (0.177 +
    0.000823 h_ft)^0.4. Tolerance: three standard errors of an RMS over T = 600 s of a process with
    correlation time tau = L / V (relative SE ~ sqrt(tau / 2T): 1.4 % for w at 5 m, 10 % for u at
    80 m), plus 3 % for JSBSim's discretisation (measured 0.96-1.06 over 3000 s at 100 m)."""
    ratio, l_u, l_w = milspec_low_altitude(np.array(stack.heights_m))
    sigma_w = 0.1 * TurbulenceLevel.LIGHT.w20_m_s
    expected = np.stack([ratio * sigma_w, ratio * sigma_w, np.full(3, sigma_w)], axis=1)
    rms = np.sqrt(np.mean(stack.gust_enu_m_s**2, axis=0))  # (H, 3)
    tau = np.stack([l_u, l_u, l_w], axis=1) / stack.airspeed_m_s
    tol = 0.03 + 3.0 * np.sqrt(tau / (2.0 * stack.duration_s))
    assert np.all(np.abs(rms / expected - 1.0) < tol), (rms / expected, tol)
    # and the intensity's height dependence: horizontal gusts weaken with height, vertical ones stay
    assert rms[0, 0] > rms[2, 0] and abs(rms[0, 2] / rms[2, 2] - 1.0) < 0.1


def test_scale_lengths_grow_with_height(stack: GustStack) -> None:
    """At a fixed airspeed the correlation time L/V grows with L_w = h and L_u(h): lag-one autocorrelation
    (1/120 s) of every axis rises from rung to rung (ideally exp(-dt V / L): w 0.987, 0.997, 0.999)."""
    g = stack.gust_enu_m_s
    lag1 = np.array([[np.corrcoef(g[:-1, k, a], g[1:, k, a])[0, 1] for a in range(3)] for k in range(3)])
    assert np.all(np.diff(lag1, axis=0) > 0.0), lag1


def test_rungs_filter_the_same_noise_and_the_same_seed_repeats(stack: GustStack) -> None:
    again = gust_stack(WindConditions(turbulence=TurbulenceLevel.LIGHT), 3, 20.0, 20.0, heights_m=(5.0, 20.0, 80.0))
    other = gust_stack(WindConditions(turbulence=TurbulenceLevel.LIGHT), 4, 20.0, 20.0, heights_m=(5.0, 20.0, 80.0))
    n = again.t_s.size
    np.testing.assert_array_equal(again.gust_enu_m_s, stack.gust_enu_m_s[:n])  # same seed: the same numbers
    assert not np.array_equal(other.gust_enu_m_s, again.gust_enu_m_s)
    g = stack.gust_enu_m_s
    w_corr = np.corrcoef(g[:, 0, 2], g[:, 1, 2])[0, 1]  # neighbouring rungs: filters of one noise
    w_other = np.corrcoef(g[:n, 0, 2], other.gust_enu_m_s[:, 0, 2])[0, 1]
    assert w_corr > 0.6 and abs(w_other) < 0.3, (w_corr, w_other)


def test_interpolation_is_continuous_in_height_and_clamped(stack: GustStack) -> None:
    field = WindField((1.0, 2.0, 0.0), stack)
    t = 3.3
    z = np.linspace(0.0, 400.0, 40001)  # 1 cm steps
    w = field.wind_enu_m_s_batch(np.full(z.size, t), z)
    assert np.abs(np.diff(w, axis=0)).max() < 0.02  # no jumps (at the rungs either)
    for k, h in enumerate(stack.heights_m):  # on a rung: its series, interpolated in time only
        i = int(t / stack.dt_s)
        f = t / stack.dt_s - i
        g = stack.gust_enu_m_s
        np.testing.assert_allclose(field.wind_enu_m_s(t, h), (1.0, 2.0, 0.0) + g[i, k] + f * (g[i + 1, k] - g[i, k]),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(field.wind_enu_m_s(t, h * (1 - 1e-12)), field.wind_enu_m_s(t, h * (1 + 1e-12)),
                                   rtol=0, atol=1e-9)
    np.testing.assert_array_equal(field.wind_enu_m_s(t, 0.0), field.wind_enu_m_s(t, 5.0))  # clamped below
    np.testing.assert_array_equal(field.wind_enu_m_s(t, 1e4), field.wind_enu_m_s(t, 80.0))  # and above


@pytest.mark.parametrize("shear", [None, WindShear("power", 10.0, 0.35), WindShear("log", 10.0, roughness_m=1.5)])
def test_bank_equals_field_bit_for_bit_at_many_heights(stack: GustStack, shear: WindShear | None) -> None:
    bank = WindBank([stack], 3, shear)
    for i, (steady, start) in enumerate((((2.0, 1.0, 0.0), 0), ((-3.0, 0.5, 0.2), 1000), ((0.0, 0.0, 0.0), 37))):
        bank.assign(i, steady, 0, start)
    z = np.array([0.0, 3.0, 5.0, 7.5, 20.0, 33.3, 80.0, 200.0])
    for i in range(3):
        field = bank.field(i)
        clone = pickle.loads(pickle.dumps(field))
        for t in (0.0, 1.0 / 240.0, 17.123):
            batch = bank.wind_enu_m_s(np.full(z.size, t), z, np.full(z.size, i))
            np.testing.assert_array_equal(field.wind_enu_m_s_batch(np.full(z.size, t), z), batch)
            np.testing.assert_array_equal(clone.wind_enu_m_s_batch(np.full(z.size, t), z), batch)
            for k, zk in enumerate(z):
                np.testing.assert_array_equal(field.wind_enu_m_s(t, float(zk)), batch[k])
                np.testing.assert_array_equal(np.array(bank._wind_one(i, t, float(zk))), batch[k])
