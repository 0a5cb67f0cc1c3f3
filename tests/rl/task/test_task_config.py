"""The task definition (`rl.task`): a policy's config.json round trip, strict reading, rates, per-vehicle tasks
and the disjoint city pools."""
from __future__ import annotations

import json

import pytest

from rl.task.air import AIR_LEVELS, AirDistribution
from rl.task.cities import EVAL_SEEDS, TRAIN_SEEDS
from rl.task.config import NavConfig
from rl.task.vehicles import TASKS, task_for
from rl.training.evaluation import eval_config
from uam_fdm.air.atmosphere import AtmosphereConditions


@pytest.mark.parametrize("vehicle", sorted(TASKS))
def test_a_task_survives_its_config_file(vehicle: str) -> None:
    nav = task_for(vehicle)
    again = NavConfig.from_dict(json.loads(json.dumps(nav.to_dict())))
    assert again == nav and again.vehicle == vehicle


def test_unknown_settings_are_named() -> None:
    d = NavConfig().to_dict()
    with pytest.raises(ValueError, match=r"unknown navigation settings \['wings'\]"):
        NavConfig.from_dict({**d, "wings": 2})
    with pytest.raises(ValueError, match=r"unknown reward settings \['bonus'\]"):
        NavConfig.from_dict({**d, "reward": {**d["reward"], "bonus": 1.0}})


def test_the_decision_rate_must_divide_the_control_rate() -> None:
    assert NavConfig(control_hz=50.0, decision_hz=10.0).action_repeat == 5
    with pytest.raises(ValueError, match="decision_hz 15.0 must divide control_hz 50.0"):
        NavConfig(decision_hz=15.0)
    with pytest.raises(ValueError, match="city_split"):
        NavConfig(city_split="test")


def test_a_vehicle_without_a_task_is_named() -> None:
    with pytest.raises(ValueError, match=r"no learned-pilot task for vehicle 'glider'; tasks exist for"):
        task_for("glider")


def test_training_validation_and_test_cities_are_disjoint() -> None:
    train = set(NavConfig(city_pool_size=len(TRAIN_SEEDS)).city_seeds())
    test = set(eval_config(NavConfig(), 1000, pool="test").city_seeds())
    validation = set(eval_config(NavConfig(), 1000, pool="validation").city_seeds())
    assert len(test) == len(validation) == 1000
    assert not (train & test) and not (train & validation) and not (test & validation)
    assert test <= set(EVAL_SEEDS) and validation <= set(EVAL_SEEDS)
    with pytest.raises(ValueError, match="exceeds the train range"):
        NavConfig(city_pool_size=len(TRAIN_SEEDS) + 1).city_seeds()


def test_a_policy_written_before_the_air_reads_with_its_one_level_and_wind() -> None:
    d = NavConfig().to_dict()
    d.pop("air")
    old = NavConfig.from_dict({**d, "turbulence": "moderate", "steady_wind_max_m_s": 5.0})
    assert old.air == AirDistribution(turbulence=("moderate",), steady_wind_max_m_s=5.0)
    with pytest.raises(ValueError, match=r"\['turbulence'\] and 'air' both given"):
        NavConfig.from_dict({**NavConfig().to_dict(), "turbulence": "light"})


def test_the_air_pool_is_drawn_in_its_ranges_at_fixed_seeds() -> None:
    air = AirDistribution.at_level("hot-and-high", pool_size=8)
    fields = air.fields()
    assert len(fields) == 8 and fields == air.fields()  # the same pool for every world of this air
    assert all(1800.0 <= f.elevation_m <= 2600.0 and 20.0 <= f.isa_offset_k <= 30.0 for f in fields)
    assert len({f.elevation_m for f in fields}) == 8
    assert AirDistribution(pool_size=8).fields() == [AtmosphereConditions(0.0, 0.0)]  # one field: one table
    assert set(AIR_LEVELS) == {"sea-level", "warm-and-raised", "hot-and-high"}
    with pytest.raises(ValueError, match="unknown air level 'everest'; choose from sea-level"):
        AirDistribution.at_level("everest")


@pytest.mark.parametrize("vehicle", sorted(TASKS))
def test_the_envelope_spans_a_cold_sea_level_day_to_past_the_benchmarks_thinnest_air(vehicle: str) -> None:
    """`train --envelope`: fields from density altitude below sea level to at least 4 km (the benchmark's
    hot-and-high reaches 3.4 km), none to moderate turbulence, wind past the benchmark's."""
    from uam_fdm.air.atmosphere import Atmosphere, density_altitude_m

    nav = task_for(vehicle, envelope=True)
    fields = nav.air.fields()
    altitudes = [density_altitude_m(Atmosphere.from_jsbsim(c, z_max_m=1.0, z_min_m=0.0).density_kg_m3(0.0))
                 for c in fields[:2]]  # the densest and the thinnest corner come first
    assert altitudes[0] < 0.0 and altitudes[1] >= 4000.0 and len(fields) == 64
    assert nav.air.turbulence == ("none", "light", "moderate")
    assert nav.air.steady_wind_max_m_s >= {"small_quad": 8.0, "uam_multicopter": 12.0}[vehicle]
