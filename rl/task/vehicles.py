"""The learned pilot's task per vehicle: cities, legs, sensing, decision rate and reward at the vehicle's scale.

`task_for(vehicle)` is the `NavConfig` a policy for that vehicle is trained on (`uam-compare train
--vehicle NAME`). A policy folder records its task (config.json), so evaluation and the comparison
runner always fly a policy in the task it learned. Distances in metres, speeds in m/s, rates in Hz.

**small_quad** (the `NavConfig` defaults): 0.42 m collision radius, 12 m/s. Cities 260-420 m across with
12-28 m streets, legs 40-250 m at 5-30 m above the ground, rays to 40 m, decisions at 10 Hz.

**uam_multicopter** (`UAM_TASK`; 900 kg, 6 m collision radius, 30.5 m/s, 25 deg tilt, 2.5 m/s climb,
0.12 s motor lag): every number follows from its stopping distance (about 140 m from cruise) and its slow
velocity loop. Rays to 200 m, decisions at 5 Hz, districts 1.0-1.6 km across with 35-70 m streets
(`UAM_DISTRICTS`), legs 0.3-1.5 km between points 30-90 m above the ground and a 10 m goal radius, a time
limit that adds 2 x the climb time to 2.5 x the cruise time, and the reward per unit of its own motion,
with the braking term of `rl.task.reward` on.

**The envelope** (`task_for(vehicle, envelope=True)`, `uam-compare train --envelope`): the air a pilot
will meet (`ENVELOPE_AIR`) and, for the UAM, the space of the `full` task set too: half its cities at the
shipped maps' scale (`SHIPPED_SCALE_CITIES`), starts and goals down to 15 m from the flight volume's side,
which the policy observes (`ObservedContext(geofence=True)`), and time limits down to 15 s shorter than its
own (a scenario's default rule gives the UAM 11-14 s less). The small quad's envelope keeps its shipped task's
space (a scenario's default time limit is its own).

How each number was derived, and the runs that set them: docs/design_notes.md, "rl.task.vehicles".
"""
from __future__ import annotations

from dataclasses import replace

from rl.sensing.observation import ObservationScales, ObservedContext
from rl.sensing.perception import PerceptionConfig
from rl.sensing.route import RouteConfig
from rl.task.air import AirDistribution
from rl.task.cities import CityDistribution, CityMixture, TaskDistribution
from rl.task.config import NavConfig
from rl.task.reward import RewardConfig

UAM_DISTRICTS = CityDistribution(
    extent_m=(1000.0, 1600.0), ceiling_m=250.0, margin_m=60.0, block_size_m=(80.0, 200.0),
    street_width_m=(35.0, 70.0), lots_per_block=(1, 3), density=(0.4, 0.85), fill_low=(0.45, 0.75),
    height_median_m=(15.0, 45.0), height_sigma=(0.3, 0.6), height_range_m=(8.0, 230.0),
    core_probability=0.5, core_height_factor=(2.0, 5.0), merge_prob=(0.0, 0.3))
"""The UAM's own districts (the shipped UAM policy's cities)."""

UAM_TASK = NavConfig(
    vehicle="uam_multicopter",
    decision_hz=5.0,
    perception=PerceptionConfig(n_rays=16, ray_range_m=200.0, grid_cells=9, cell_m=30.0, raster_m=5.0),
    route=RouteConfig(cell_m=10.0, margin_m=8.0, climb_weight=3.0, level_step_m=60.0),
    scales=ObservationScales(goal_m=1000.0, height_m=50.0, altitude_m=100.0, clearance_m=120.0),
    city_pool_size=256,
    cities=UAM_DISTRICTS,
    tasks=TaskDistribution(distance_m=(300.0, 1500.0), altitude_m=(30.0, 90.0), min_clearance_m=10.0,
                           bounds_margin_m=80.0, goal_radius_m=10.0, timeout_base_s=30.0, timeout_per_speed=2.5,
                           timeout_per_climb=2.0),
    air=AirDistribution(steady_wind_max_m_s=5.0),
    reward=RewardConfig(progress_per_m=0.15, time_per_s=0.2, danger_per_s=4.0, ttc_horizon_s=4.0,
                        proximity_per_s=5.0, proximity_m=15.0, proximity_speed_m_s=15.0,
                        braking_per_s=20.0, braking_margin=1.5),
)

TASKS: dict[str, NavConfig] = {"small_quad": NavConfig(), "uam_multicopter": UAM_TASK}


# The air a pilot meets: fields from a cold day at sea level (density altitude about -0.6 km) to a hot day at
# 3,000 m (about 4.1 km, past the benchmark's hot-and-high 3.4 km), no to moderate turbulence, and steady wind
# well past the benchmark's (3 and 5 m/s). 64 fields: about 70 m of density altitude apart.
ENVELOPE_AIR: dict[str, AirDistribution] = {
    "small_quad": AirDistribution(elevation_m=(0.0, 3000.0), isa_offset_k=(-15.0, 30.0),
                                  turbulence=("none", "light", "moderate"), steady_wind_max_m_s=8.0, pool_size=64),
    "uam_multicopter": AirDistribution(elevation_m=(0.0, 3000.0), isa_offset_k=(-15.0, 30.0),
                                       turbulence=("none", "light", "moderate"), steady_wind_max_m_s=12.0,
                                       pool_size=64),
}


# The space a pilot meets beyond its own districts: the shipped maps' scale (uam_fdm/city/generator.py
# SHIPPED_MAPS, which the `full` set flies): 700-1000 m across, 16-24 m streets, 40-150 m blocks, 35-50 m
# building-free borders, median heights from 12 m (suburb) to 110 m (canyon), roofs to 250 m under a 150-300 m
# ceiling. These ranges hold all three with room on each side.
SHIPPED_SCALE_CITIES = CityDistribution(
    extent_m=(600.0, 1100.0), ceiling_m=300.0, margin_m=35.0, block_size_m=(40.0, 160.0),
    street_width_m=(15.0, 30.0), lots_per_block=(1, 3), density=(0.5, 0.95), fill_low=(0.4, 0.85),
    height_median_m=(10.0, 120.0), height_sigma=(0.2, 0.5), height_range_m=(8.0, 250.0),
    core_probability=0.5, core_height_factor=(1.5, 4.0), merge_prob=(0.0, 0.2))

ENVELOPE_TASKS: dict[str, NavConfig] = {
    # the small quad's space stays its shipped task's (a policy is being trained on it)
    "small_quad": replace(NavConfig(), air=ENVELOPE_AIR["small_quad"]),
    # half the cities the UAM's own districts, half at the shipped maps' scale (the UAM in 15-30 m streets): the
    # benchmark flies the first, the full set the second, and neither is favoured before validation says so;
    # start and goal down to 15 m from the flight volume's side (the full set's 16.8 m), which it observes
    # (a geofence every operation has); legs from 250 m (the full set's 265 m) and 8 m of clearance beyond the
    # 6 m sphere (the full set's 9.1 m); time limits down to 15 s shorter than its own rule's (a scenario's
    # default rule gives the full set's legs 11-14 s less)
    "uam_multicopter": replace(
        UAM_TASK, air=ENVELOPE_AIR["uam_multicopter"],
        cities=CityMixture((UAM_DISTRICTS, SHIPPED_SCALE_CITIES), (0.5, 0.5)),
        tasks=replace(UAM_TASK.tasks, distance_m=(250.0, 1500.0), min_clearance_m=8.0, bounds_margin_m=15.0,
                      timeout_cut_s=15.0),
        observe=ObservedContext(geofence=True)),
}


def task_for(vehicle: str, envelope: bool = False) -> NavConfig:
    """The training task of a vehicle preset: the shipped policy's (sea level, light turbulence), or with
    `envelope` the task across the air and space it will meet (`ENVELOPE_TASKS`).

    Raises:
        ValueError: no task is defined for `vehicle` (naming the ones that are).
    """
    if vehicle not in TASKS:
        raise ValueError(f"no learned-pilot task for vehicle {vehicle!r}; tasks exist for {sorted(TASKS)}")
    return ENVELOPE_TASKS[vehicle] if envelope else TASKS[vehicle]


def in_task_space(policy_task: NavConfig, space: NavConfig) -> NavConfig:
    """`policy_task` flown in `space`'s cities, legs and air (e.g. an older policy on the envelope's legs, to
    compare it with an envelope policy on the same tasks). What the network reads stays the policy's: its
    vehicle, decision rate, perception, route, observation scales and observed context, and its reward.

    Raises:
        ValueError: the two tasks are for different vehicles.
    """
    if policy_task.vehicle != space.vehicle:
        raise ValueError(f"a {policy_task.vehicle} policy cannot fly the {space.vehicle} task's space")
    return replace(policy_task, cities=space.cities, tasks=space.tasks, air=space.air)
