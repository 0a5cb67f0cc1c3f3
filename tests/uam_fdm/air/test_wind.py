"""Steady wind and JSBSim Dryden gusts: levels, determinism, statistics, interpolation."""

from __future__ import annotations

import hashlib
import pickle
import subprocess
import sys

import numpy as np
import pytest

import uam_fdm.air.wind as wind
from uam_fdm.air.wind import GustSeries, GustStack, TurbulenceLevel, WindConditions, WindField, gust_series

FT = 0.3048
KT = 1852.0 / 3600.0

# Short, cheap series for behaviour tests: a 20 m/s probe keeps JSBSim's spin-up short.
FAST = dict(duration_s=10.0, height_agl_m=100.0, airspeed_m_s=20.0)


def _light(steady: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> WindConditions:
    return WindConditions(steady, TurbulenceLevel.LIGHT)


def _milspec_sigmas(level: TurbulenceLevel, h_m: float) -> np.ndarray:
    """MIL-F-8785C low-altitude intensities (sigma_u, sigma_v, sigma_w), m/s, h below 1000 ft."""
    h_ft = h_m / FT
    sigma_w = 0.1 * level.w20_m_s
    sigma_u = sigma_w / (0.177 + 0.000823 * h_ft) ** 0.4
    return np.array([sigma_u, sigma_u, sigma_w])


# ----------------------------------------------------------------------------- levels and inputs
def test_levels_carry_milspec_parameters() -> None:
    assert [lv.value for lv in TurbulenceLevel] == ["none", "light", "moderate", "severe"]
    assert TurbulenceLevel.LIGHT.w20_m_s == pytest.approx(15 * KT)
    assert TurbulenceLevel.MODERATE.w20_m_s == pytest.approx(30 * KT)
    assert TurbulenceLevel.SEVERE.w20_m_s == pytest.approx(45 * KT)
    assert TurbulenceLevel.NONE.w20_m_s == 0.0
    assert [lv.milspec_severity for lv in TurbulenceLevel] == [0, 3, 4, 6]
    assert [lv.exceedance_probability for lv in TurbulenceLevel] == [0.0, 1e-2, 1e-3, 1e-5]


def test_turbulence_strings_parse_and_unknown_level_is_a_clear_error() -> None:
    parsed = WindConditions(turbulence="Moderate")  # type: ignore[arg-type]
    assert parsed.turbulence is TurbulenceLevel.MODERATE
    assert TurbulenceLevel.parse(" severe ") is TurbulenceLevel.SEVERE
    expected = "turbulence must be one of none, light, moderate, severe; got 'gusty'"
    with pytest.raises(ValueError, match=expected):
        WindConditions(turbulence="gusty")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("steady", "message"),
    [
        ((1.0, float("nan"), 0.0), "three finite numbers"),
        ((1.0, 2.0), "three finite numbers"),
        ("east", "three finite numbers"),
        ((80.0, 0.0, 0.0), "exceeds 60"),
    ],
)
def test_bad_steady_wind_raises(steady: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        WindConditions(steady)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": -1}, "seed must be in"),
        ({"seed": 2**31}, "seed must be in"),
        ({"seed": 1.5}, "seed must be an integer"),
        ({"airspeed_m_s": 0.0}, "airspeed_m_s=0.0 is outside"),
        ({"duration_s": float("nan")}, "duration_s must be finite"),
        ({"height_agl_m": -5.0}, "height_agl_m=-5.0 is outside"),
        ({"height_agl_m": 2.0, "dt_s": 0.1}, "too coarse for the Dryden time scale"),
    ],
)
def test_bad_series_arguments_raise(kwargs: dict[str, object], message: str) -> None:
    args: dict[str, object] = {"seed": 1, **FAST}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        gust_series(_light(), **args)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- series
def test_none_gives_exact_zeros_without_jsbsim(monkeypatch: pytest.MonkeyPatch) -> None:
    def forbidden(*args: object, **kwargs: object) -> None:
        raise AssertionError("JSBSim must not run for TurbulenceLevel.NONE")

    monkeypatch.setattr(wind, "_run_probe", forbidden)
    g = gust_series(WindConditions((3.0, 0.0, 0.0)), seed=5, **FAST)
    assert g.gust_enu_m_s.shape == (1201, 3)
    assert not np.any(g.gust_enu_m_s)
    field = WindField.from_conditions(WindConditions((3.0, 4.0, 0.5)), 5, 10.0, 20.0)
    winds = field.wind_enu_m_s_batch(np.linspace(0.0, 10.0, 50), np.linspace(0.0, 400.0, 50))
    np.testing.assert_array_equal(winds, np.tile([3.0, 4.0, 0.5], (50, 1)))


def test_same_seed_identical_different_seed_differs() -> None:
    a = gust_series(_light(), seed=11, **FAST)
    b = gust_series(_light(), seed=11, **FAST)
    c = gust_series(_light(), seed=12, **FAST)
    np.testing.assert_array_equal(a.gust_enu_m_s, b.gust_enu_m_s)  # exact, every sample
    np.testing.assert_array_equal(a.t_s, b.t_s)
    assert not np.any(np.all(a.gust_enu_m_s == c.gust_enu_m_s, axis=1)[1:])
    assert np.all(np.isfinite(a.gust_enu_m_s)) and np.any(a.gust_enu_m_s)
    assert a.t_s[0] == 0.0 and a.duration_s >= FAST["duration_s"]
    assert a.dt_s == pytest.approx(1.0 / 120.0)
    assert (a.turbulence, a.seed, a.airspeed_m_s, a.height_agl_m) == (TurbulenceLevel.LIGHT, 11, 20.0, 100.0)


def _digest_script(seed: int) -> str:
    return (
        "import hashlib\n"
        "from uam_fdm.air.wind import WindConditions, gust_series\n"
        f"g = gust_series(WindConditions(turbulence='moderate'), {seed}, 10.0, 100.0, 20.0)\n"
        "print(hashlib.sha256(g.gust_enu_m_s.tobytes()).hexdigest())\n"
    )


def test_series_is_identical_in_a_fresh_process() -> None:
    here = gust_series(WindConditions(turbulence=TurbulenceLevel.MODERATE), 21, 10.0, 100.0, 20.0)
    out = subprocess.run(
        [sys.executable, "-c", _digest_script(21)], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == hashlib.sha256(here.gust_enu_m_s.tobytes()).hexdigest()


@pytest.mark.parametrize("level", [TurbulenceLevel.LIGHT, TurbulenceLevel.MODERATE])
def test_rms_matches_milspec_low_altitude_intensity(level: TurbulenceLevel) -> None:
    # 600 s at 20 m/s is ~45 longitudinal correlation times (L_u = 262 m at 100 m): a finite
    # sample, so the band is generous (0.5x..2x). Measured here: 0.96..1.06 of MIL-F-8785C.
    # dt = 0.05 s keeps the test fast; it is still far below the shortest time constant (L_w/V = 5 s).
    g = gust_series(WindConditions(turbulence=level), 3, 600.0, 100.0, 20.0, dt_s=0.05)
    rms = np.sqrt(np.mean(g.gust_enu_m_s**2, axis=0))
    ratio = rms / _milspec_sigmas(level, 100.0)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def test_moderate_is_stronger_than_light_for_the_same_seed() -> None:
    def series(level: TurbulenceLevel) -> GustSeries:
        return gust_series(WindConditions(turbulence=level), 9, 120.0, 100.0, 20.0, dt_s=0.05)

    light, moderate = series(TurbulenceLevel.LIGHT), series(TurbulenceLevel.MODERATE)
    rms_l = np.sqrt(np.mean(light.gust_enu_m_s**2, axis=0))
    rms_m = np.sqrt(np.mean(moderate.gust_enu_m_s**2, axis=0))
    assert np.all(rms_m > rms_l)
    assert np.all(np.isfinite(moderate.gust_enu_m_s))


def test_probe_airspeed_sets_the_correlation_time() -> None:
    # Dryden time scales are L/V: with L_w = 100 m the vertical gust decorrelates ~8x faster at
    # 40 m/s (L_w/V = 2.5 s) than at 5 m/s (20 s). Lag-2 s autocorrelation, ideally 0.90 vs 0.45.
    def autocorr(v: float) -> float:
        w = gust_series(_light(), 4, 600.0, 100.0, v, dt_s=0.05).gust_enu_m_s[:, 2]
        lag = 40
        return float(np.corrcoef(w[:-lag], w[lag:])[0, 1])

    slow, fast = autocorr(5.0), autocorr(40.0)
    assert slow > 0.75 and fast < 0.65 and slow > fast + 0.2


def test_longitudinal_axis_follows_the_steady_wind() -> None:
    calm = gust_series(_light(), seed=2, **FAST).gust_enu_m_s
    easterly = gust_series(_light((6.0, 0.0, 0.0)), seed=2, **FAST).gust_enu_m_s
    # JSBSim's longitudinal component lies north in calm air and east when the wind blows east;
    # the lateral component is 90 degrees to the right (east in calm air, south here).
    np.testing.assert_array_equal(easterly[:, 0], calm[:, 1])  # longitudinal: north -> east
    np.testing.assert_array_equal(easterly[:, 1], -calm[:, 0])  # lateral: east -> south
    np.testing.assert_array_equal(easterly[:, 2], calm[:, 2])  # vertical unchanged
    diagonal = gust_series(_light((3.0, 3.0, 0.0)), seed=2, **FAST).gust_enu_m_s
    # A diagonal wind only rotates the horizontal pair: the horizontal gust magnitude is unchanged.
    np.testing.assert_allclose(
        np.hypot(diagonal[:, 0], diagonal[:, 1]), np.hypot(calm[:, 0], calm[:, 1]), rtol=1e-12
    )


# ----------------------------------------------------------------------------- wind field
@pytest.fixture(scope="module")
def gusty() -> WindField:
    return WindField.from_conditions(_light((2.0, -1.0, 0.0)), 17, 12.0, 20.0, heights_m=(50.0, 100.0))


def test_field_interpolates_steady_plus_gusts(gusty: WindField) -> None:
    g = gusty.gusts
    assert isinstance(g, GustStack) and g.heights_m == (50.0, 100.0)
    steady = np.array([2.0, -1.0, 0.0])
    np.testing.assert_array_equal(gusty.steady_enu_m_s, steady)
    k, top = 600, g.gust_enu_m_s[:, 1]
    np.testing.assert_allclose(gusty.wind_enu_m_s(g.t_s[k], 100.0), steady + top[k], rtol=0, atol=1e-12)
    t_mid = 0.5 * (g.t_s[k] + g.t_s[k + 1])
    expected = steady + 0.5 * (top[k] + top[k + 1])
    np.testing.assert_allclose(gusty.wind_enu_m_s(t_mid, 100.0), expected, rtol=0, atol=1e-12)
    # linear in log height: the geometric mean of two rungs is their midpoint
    mid = steady + 0.5 * (g.gust_enu_m_s[k, 0] + g.gust_enu_m_s[k, 1])
    np.testing.assert_allclose(gusty.wind_enu_m_s(g.t_s[k], np.sqrt(5000.0)), mid, rtol=0, atol=1e-12)
    times = np.array([[0.0, 0.013], [7.77, gusty.duration_s]])
    heights = np.array([[1.0, 50.0], [73.0, 400.0]])
    batch = gusty.wind_enu_m_s_batch(times, heights)
    assert batch.shape == (2, 2, 3)
    for t, z, w in zip(times.flat, heights.flat, batch.reshape(-1, 3)):
        np.testing.assert_array_equal(w, gusty.wind_enu_m_s(float(t), float(z)))
    assert gusty.duration_s >= 12.0


@pytest.mark.parametrize("t", [-0.001, 12.1, float("nan")])
def test_field_outside_its_series_raises(gusty: WindField, t: float) -> None:
    with pytest.raises(ValueError, match="build the WindField with duration_s"):
        gusty.wind_enu_m_s(t, 10.0)
    with pytest.raises(ValueError, match="build the WindField with duration_s"):
        gusty.wind_enu_m_s_batch([1.0, t], 10.0)


def test_calm_field_is_zero_at_any_time() -> None:
    calm = WindField.calm()
    assert calm.gusts is None and calm.duration_s == float("inf")
    np.testing.assert_array_equal(calm.wind_enu_m_s(1e6, 30.0), np.zeros(3))
    np.testing.assert_array_equal(calm.wind_enu_m_s_batch(np.zeros((4, 2)), 5.0), np.zeros((4, 2, 3)))


def test_field_pickle_round_trip(gusty: WindField) -> None:
    clone = pickle.loads(pickle.dumps(gusty))
    t = np.linspace(0.0, 12.0, 1001)
    z = np.linspace(0.0, 150.0, 1001)
    np.testing.assert_array_equal(clone.wind_enu_m_s_batch(t, z), gusty.wind_enu_m_s_batch(t, z))
    assert clone.gusts is not None and clone.gusts.seed == 17
    returned = gusty.wind_enu_m_s(1.0, 70.0)
    returned[:] = 99.0  # callers own the returned array: the field must not change
    assert not np.any(gusty.wind_enu_m_s(1.0, 70.0) == 99.0)
