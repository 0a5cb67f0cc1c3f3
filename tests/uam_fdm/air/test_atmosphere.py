"""The JSBSim atmosphere against the ICAO standard atmosphere, and the table's behaviour."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from uam_fdm.air.atmosphere import (
    SEA_LEVEL_DENSITY_KG_M3,
    Atmosphere,
    AtmosphereBank,
    AtmosphereConditions,
    AtmosphereSample,
)

# Independent reference: ICAO Standard Atmosphere (Doc 7488), textbook table values.
# height MSL (m): (density kg/m^3, temperature K, pressure Pa)
ICAO_TABLE = {
    0.0: (1.2250, 288.15, 101325.0),
    1000.0: (1.1117, 281.65, 89876.0),
    2000.0: (1.0066, 275.15, 79501.0),
    3000.0: (0.9093, 268.65, 70121.0),
}
R_AIR = 287.053  # J/(kg K), ICAO specific gas constant of dry air
GAMMA_AIR = 1.4
REL_TOL = 0.005  # the acceptance bound: 0.5 %


@pytest.fixture(scope="module")
def standard_day() -> Atmosphere:
    return Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=3000.0)


@pytest.mark.parametrize("h_m", sorted(ICAO_TABLE))
def test_density_temperature_pressure_match_icao(standard_day: Atmosphere, h_m: float) -> None:
    rho_ref, t_ref, p_ref = ICAO_TABLE[h_m]
    s = standard_day.sample(h_m)
    assert isinstance(s, AtmosphereSample)
    assert s.density_kg_m3 == pytest.approx(rho_ref, rel=REL_TOL)
    assert s.temperature_k == pytest.approx(t_ref, rel=REL_TOL)
    assert s.pressure_pa == pytest.approx(p_ref, rel=REL_TOL)
    # Measured: 4e-5 relative in density; keep a tighter guard so a regression is visible.
    assert abs(s.density_kg_m3 / rho_ref - 1.0) < 2e-4
    assert s.speed_of_sound_m_s == pytest.approx(math.sqrt(GAMMA_AIR * R_AIR * t_ref), rel=1e-3)


def test_field_elevation_shifts_the_profile() -> None:
    atm = Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=1000.0), z_max_m=1000.0)
    rho_ref, t_ref, p_ref = ICAO_TABLE[2000.0]  # 1000 m above a 1000 m field
    s = atm.sample(1000.0)
    assert s.density_kg_m3 == pytest.approx(rho_ref, rel=REL_TOL)
    assert s.temperature_k == pytest.approx(t_ref, rel=REL_TOL)
    assert s.pressure_pa == pytest.approx(p_ref, rel=REL_TOL)
    ground = atm.sample(0.0)
    assert ground.density_kg_m3 == pytest.approx(ICAO_TABLE[1000.0][0], rel=REL_TOL)


def test_isa_offset_keeps_pressure_and_lowers_density(standard_day: Atmosphere) -> None:
    # ISA-deviation convention (performance charts): same pressure at a height, warmer air.
    hot = Atmosphere.from_jsbsim(AtmosphereConditions(isa_offset_k=20.0), z_max_m=3000.0)
    for h_m, (_, t_ref, p_ref) in ICAO_TABLE.items():
        s_hot, s_std = hot.sample(h_m), standard_day.sample(h_m)
        assert s_hot.pressure_pa == pytest.approx(s_std.pressure_pa, rel=1e-9)
        assert s_hot.temperature_k == pytest.approx(s_std.temperature_k + 20.0, abs=1e-6)
        assert s_hot.density_kg_m3 == pytest.approx(p_ref / (R_AIR * (t_ref + 20.0)), rel=REL_TOL)
        assert s_hot.density_kg_m3 < s_std.density_kg_m3


def test_density_ratio_and_array_queries(standard_day: Atmosphere) -> None:
    assert SEA_LEVEL_DENSITY_KG_M3 == 1.225
    assert standard_day.density_ratio(0.0) == pytest.approx(1.0, abs=1e-4)
    z = np.array([[0.0, 12.5], [999.9, 3000.0]])
    rho = standard_day.density_kg_m3(z)
    assert rho.shape == z.shape
    for zi, ri in zip(z.flat, rho.flat):
        assert ri == pytest.approx(standard_day.density_kg_m3(float(zi)), rel=1e-14)
    np.testing.assert_allclose(standard_day.density_ratio(z), rho / SEA_LEVEL_DENSITY_KG_M3, rtol=1e-15)
    s = standard_day.sample(z)
    assert s.temperature_k.shape == s.pressure_pa.shape == s.speed_of_sound_m_s.shape == z.shape
    assert s.density_kg_m3[1, 0] == pytest.approx(standard_day.sample(999.9).density_kg_m3, rel=1e-14)
    heights = standard_day.heights_m
    assert np.all(np.diff(standard_day.density_kg_m3(heights)) < 0.0)  # density falls with height


def test_table_spacing_and_interpolation_error(standard_day: Atmosphere) -> None:
    # A 100 m table interpolated at its midpoints agrees with the 5 m table within ~1e-5
    # (measured 1.0e-5 near 3 km). Linear interpolation error scales with spacing^2, so the
    # default 5 m table's own error is ~(5/100)^2 of that: below 1e-7, negligible.
    coarse = Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=3000.0, z_min_m=0.0, spacing_m=100.0)
    assert coarse.spacing_m == pytest.approx(100.0)
    assert standard_day.spacing_m <= 5.0
    assert standard_day.z_min_m == -50.0 and standard_day.z_max_m == pytest.approx(3000.0)
    mid = np.arange(0.0, 3000.0, 100.0) + 50.0
    np.testing.assert_allclose(coarse.density_kg_m3(mid), standard_day.density_kg_m3(mid), rtol=2e-5)


@pytest.mark.parametrize("z", [-50.01, 3000.5, float("nan"), float("inf")])
def test_out_of_table_heights_raise(standard_day: Atmosphere, z: float) -> None:
    with pytest.raises(ValueError, match="outside the atmosphere table"):
        standard_day.density_ratio(z)
    with pytest.raises(ValueError, match="outside the atmosphere table"):
        standard_day.sample(np.array([0.0, z]))


def test_pickle_round_trip(standard_day: Atmosphere) -> None:
    clone = pickle.loads(pickle.dumps(standard_day))
    assert clone.conditions == standard_day.conditions
    np.testing.assert_array_equal(clone.table, standard_day.table)
    z = np.linspace(-50.0, 3000.0, 777)
    np.testing.assert_array_equal(clone.density_ratio(z), standard_day.density_ratio(z))
    assert clone.sample(123.4) == standard_day.sample(123.4)


def test_building_prints_nothing(capfd: pytest.CaptureFixture[str]) -> None:
    # JSBSim's banner and model summary go to logging, never to stdout/stderr.
    Atmosphere.from_jsbsim(AtmosphereConditions(elevation_m=500.0), z_max_m=100.0)
    out, err = capfd.readouterr()
    assert out == "" and err == ""


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"elevation_m": float("nan")}, "elevation_m must be finite"),
        ({"elevation_m": 20000.0}, "elevation_m=20000.0 is outside"),
        ({"elevation_m": "1000"}, "elevation_m must be a number"),
        ({"isa_offset_k": 300.0}, "isa_offset_k=300.0 is outside"),
        ({"isa_offset_k": None}, "isa_offset_k must be a number"),
    ],
)
def test_bad_conditions_raise_clear_errors(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        AtmosphereConditions(**kwargs)  # type: ignore[arg-type]


def test_conditions_are_normalised_and_hashable() -> None:
    assert AtmosphereConditions(1000, 5) == AtmosphereConditions(1000.0, 5.0)
    assert isinstance(AtmosphereConditions(1000, 5).elevation_m, float)
    assert len({AtmosphereConditions(1000, 5), AtmosphereConditions(1000.0, 5.0)}) == 1


def test_bad_table_span_raises() -> None:
    with pytest.raises(ValueError, match="must be above"):
        Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=-100.0)
    with pytest.raises(ValueError, match="spacing_m"):
        Atmosphere.from_jsbsim(AtmosphereConditions(), spacing_m=0.0)


def test_a_bank_flies_each_vehicle_in_its_own_atmosphere_bit_for_bit() -> None:
    """Each vehicle's density ratio from the bank is its pool entry's, scalar and array lookups alike,
    heights beyond the table held at its edge."""
    pool = [Atmosphere.from_jsbsim(AtmosphereConditions(e, t), z_max_m=200.0)
            for e, t in ((0.0, 0.0), (1500.0, 15.0), (3000.0, 30.0))]
    bank = AtmosphereBank(pool, 5)
    for i, k in enumerate((2, 0, 1, 2, 1)):
        bank.assign(i, k)
    z = np.array([-80.0, 0.0, 33.3, 199.99, 450.0])
    sigma = bank.density_ratio_clamped(z)
    for i in range(5):
        assert bank.atmosphere(i) is pool[bank.which[i]]
        assert sigma[i] == pool[bank.which[i]].density_ratio_clamped(float(z[i]))
        assert sigma[i] == pool[bank.which[i]].density_ratio_clamped(z[i:i + 1])[0]
    assert np.array_equal(bank.density_ratio_clamped(z[[1, 3]], np.array([1, 3])), sigma[[1, 3]])
    assert sigma[0] < sigma[2] < sigma[1]  # 3 km / +30 K is thinner than 1.5 km / +15 K, both than sea level


def test_a_bank_needs_one_grid() -> None:
    with pytest.raises(ValueError, match="one height grid"):
        AtmosphereBank([Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0),
                        Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=200.0)], 2)
    with pytest.raises(ValueError, match="at least one"):
        AtmosphereBank([], 2)
