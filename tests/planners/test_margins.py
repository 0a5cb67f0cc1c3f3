"""Clearance margins from the tracking-error table: the rule on a fixed table, the loader, the shipped table."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest

from planners.margins import (
    DEFAULT_TABLE_PATH,
    MarginRule,
    TrackingErrorRow,
    TrackingErrorTable,
    load_tracking_table,
    margins_for,
    write_tracking_table,
)
from uam_fdm.air.wind import TurbulenceLevel as T
from uam_fdm.vehicle.params import load_vehicle

QUAD = load_vehicle("small_quad")
UAM = load_vehicle("uam_multicopter")
RULE = MarginRule(floor_m=1.0, k=2.0, mpc_fraction=0.5)


def _row(turbulence: T, sigma: float, p99: float, vehicle=QUAD) -> TrackingErrorRow:
    return TrackingErrorRow(vehicle.name, vehicle.fingerprint(), turbulence, sigma, 4, 1000, p99 / 4, p99 / 2, p99,
                            2 * p99)


TABLE = TrackingErrorTable((_row(T.NONE, 1.0, 0.2), _row(T.MODERATE, 1.0, 0.8), _row(T.MODERATE, 0.7, 1.4)), {})


@pytest.mark.parametrize(("turbulence", "sigma", "planner_m", "mpc_m", "p99_m"), [
    (T.NONE, 1.0, 1.0, 0.5, 0.2),          # calm: 2 x 0.2 = 0.4 is under the 1 m floor
    (T.MODERATE, 1.0, 1.6, 0.8, 0.8),      # 2 x 0.8
    (T.MODERATE, 0.85, 2.2, 1.1, 1.1),     # p99 halfway between the densities: 1.1 m
    (T.MODERATE, 0.6, 2.8, 1.4, 1.4),      # thinner than measured: the thinnest measured, not extrapolated
    (T.MODERATE, 1.2, 1.6, 0.8, 0.8),      # denser than measured: the densest measured
    (T.SEVERE, 1.0, 1.6, 0.8, 0.8),        # not measured: the largest of the measured levels at this density
    (T.LIGHT, 0.7, 2.8, 1.4, 1.4),         # not measured either: moderate at 0.7 is the largest
])
def test_margins_from_a_fixed_table(turbulence, sigma, planner_m, mpc_m, p99_m):
    m = margins_for(TABLE, RULE, QUAD, turbulence, sigma, fixed_planner_m=1.0, fixed_mpc_m=0.5)
    assert m.planner_m == pytest.approx(planner_m, abs=1e-12)
    assert m.mpc_m == pytest.approx(mpc_m, abs=1e-12)
    assert m.tracking_p99_m == pytest.approx(p99_m, abs=1e-12)
    assert QUAD.name in m.source


def test_the_rule_constants_move_the_margins():
    rule = MarginRule(floor_m=0.5, k=3.0, mpc_fraction=0.25)
    m = margins_for(TABLE, rule, QUAD, "none", 1.0, 1.0, 0.5)
    assert (m.planner_m, m.mpc_m) == pytest.approx((0.6, 0.15))
    with pytest.raises(ValueError, match="mpc_fraction"):
        MarginRule(mpc_fraction=1.5)
    with pytest.raises(ValueError, match="k must be"):
        MarginRule(k=-1.0)


def test_an_unknown_vehicle_flies_the_fixed_margins():
    m = margins_for(TABLE, RULE, UAM, "moderate", 1.0, fixed_planner_m=1.25, fixed_mpc_m=0.75)
    assert (m.planner_m, m.mpc_m) == (1.25, 0.75) and math.isnan(m.tracking_p99_m)
    assert "fixed" in m.source
    # the preset's name with other physics is another vehicle
    heavier = dataclasses.replace(QUAD, mass_kg=QUAD.mass_kg * 1.5)
    assert margins_for(TABLE, RULE, heavier, "moderate", 1.0, 1.25, 0.75).planner_m == 1.25
    assert margins_for(None, RULE, QUAD, "moderate", 1.0, 1.25, 0.75).planner_m == 1.25


def test_table_file_round_trip_and_clear_errors(tmp_path):
    path = write_tracking_table(TABLE.rows, {"pool": "validation", "seed": 0}, tmp_path / "t.json")
    back = load_tracking_table(path)
    assert back.rows == TABLE.rows and back.provenance == {"pool": "validation", "seed": 0}
    data = json.loads(path.read_text())
    del data["rows"][1]["p99_m"]
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"t\.json: rows\[1\]: missing key 'p99_m'"):
        load_tracking_table(path)
    data["rows"][1]["p99_m"] = -1.0
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"t\.json: rows\[1\]: p99_m must be finite and >= 0"):
        load_tracking_table(path)
    data["rows"][1].update(p99_m=1.0, turbulence="gusty")
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"t\.json: rows\[1\]: turbulence must be one of"):
        load_tracking_table(path)
    path.write_text("{}")
    with pytest.raises(ValueError, match=r"t\.json: format_version must be 1"):
        load_tracking_table(path)


def test_the_shipped_table_covers_both_presets_and_says_where_it_came_from():
    """A preset whose physics changed needs the table measured again (perf/tracking_error.py)."""
    table = load_tracking_table(DEFAULT_TABLE_PATH)
    for vehicle in (QUAD, UAM):
        assert table.measured_levels(vehicle) == [T.NONE, T.LIGHT, T.MODERATE], vehicle.name
        for level in (T.NONE, T.LIGHT, T.MODERATE):
            for row in table.rows_for(vehicle, level):
                assert row.episodes >= 4 and row.samples > 1000
                assert 0 < row.p50_m <= row.p95_m <= row.p99_m <= row.max_m
    prov = table.provenance
    assert "validation" in str(prov["pool"]) and "perf/tracking_error.py" in str(prov["command"])
    assert isinstance(prov["seed"], int) and prov["episodes"]


def test_forecast_gust_allowance():
    """2 sigma_u of MIL-F-8785C's low-altitude model: sigma_w = 0.1 W20,
    sigma_u / sigma_w = 1 / (0.177 + 0.000823 h)^0.4."""
    from planners.margins import forecast_gust_m_s

    assert forecast_gust_m_s("none", 15.0) == 0.0
    h_ft = 15.0 / 0.3048
    moderate = 2.0 * 0.1 * 30.0 * 0.514444 / (0.177 + 0.000823 * h_ft) ** 0.4
    assert forecast_gust_m_s("moderate", 15.0) == pytest.approx(moderate, rel=1e-4)
    assert forecast_gust_m_s("light", 15.0) == pytest.approx(moderate / 2, rel=1e-4)
    assert forecast_gust_m_s("moderate", 100.0) < forecast_gust_m_s("moderate", 15.0)
