"""No-fly volumes are respected by the classical pilot: the planner, the
time-parameterisation and the MPC's clearance constraints treat them as obstacles at the same margin
(`BuildingMap.planning_map`), while the comparison's clearance metric stays on the buildings."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from compare.flying.episode_loop import run_episode
from planners.classical_pilot import ClassicalPilot
from planners.rrt_star import PlannerConfig, densify, plan_path
from planners.timing import TimingLimits, time_parameterize
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import WindField
from uam_fdm.city.buildings import Building, BuildingMap, NoFlyZone
from uam_fdm.pilot import Task, World

# A wall of airspace across the direct line (ground to above the volume's top), open at both ends;
# no building at all, so only the no-fly volume can make the path bend.
WALL = NoFlyZone((40.0, 0.0), (6.0, 50.0), (0.0, 70.0))
START, GOAL = (5.0, 0.0, 15.0), (75.0, 0.0, 15.0)


def _open_field(zones: tuple[NoFlyZone, ...] = (WALL,)) -> BuildingMap:
    return BuildingMap([], (0.0, -60.0, 0.0), (80.0, 60.0, 60.0), zones, name="no-fly wall")


def _zone_clearance(zone: NoFlyZone, points: np.ndarray, radius_m: float) -> np.ndarray:
    """Distance (N,) from the zone's box minus a radius [m], via a one-obstacle map (exact; not the ground)."""
    box = Building(0, zone.center_xy_m, zone.size_xy_m, zone.z_range_m[1], zone.yaw_rad, base_m=zone.z_range_m[0])
    lo, hi = np.minimum(points.min(0), -100.0) - 1.0, np.maximum(points.max(0), 100.0) + 1.0
    only = BuildingMap([box], (lo[0], lo[1], 0.0), (hi[0], hi[1], hi[2] + 100.0))
    return only.nearest_obstacles_batch(points, 1, radius_m)[1][:, 0]


def test_planning_map_has_the_zones_as_obstacles_at_their_height() -> None:
    floating = NoFlyZone((40.0, 0.0), (10.0, 10.0), (20.0, 40.0))
    city = BuildingMap([Building(0, (10.0, 30.0), (8.0, 8.0), 25.0)], (0.0, -60.0, 0.0), (80.0, 60.0, 60.0),
                       (floating,))
    plan_map = city.planning_map()
    assert city.planning_map() is plan_map and _open_field(()).planning_map().no_fly == ()
    assert city.clearance_one(40.0, 0.0, 30.0) > 5.0 and plan_map.clearance_one(40.0, 0.0, 30.0) < 0.0
    assert plan_map.clearance_one(40.0, 0.0, 10.0) == pytest.approx(10.0)  # under it: ground and zone 10 m away
    assert plan_map.segment_free((20.0, 0.0, 10.0), (60.0, 0.0, 10.0), 1.0)      # below it
    assert not plan_map.segment_free((20.0, 0.0, 30.0), (60.0, 0.0, 30.0), 1.0)  # through it
    assert pickle.loads(pickle.dumps(plan_map)).clearance_one(40.0, 0.0, 30.0) < 0.0


def test_the_path_goes_around_a_no_fly_volume_that_blocks_the_direct_line() -> None:
    city = _open_field()
    radius, cfg = 0.42, PlannerConfig()
    assert city.segment_free(START, GOAL, radius + cfg.safety_margin_m)  # only airspace in the way
    plan = plan_path(city, START, GOAL, radius, cfg, seed=3)
    assert plan.ok, plan.message
    along = densify(plan.path_m, 0.05)
    assert _zone_clearance(WALL, along, radius).min() >= cfg.safety_margin_m - 1e-6
    ref = time_parameterize(plan.path_m, TimingLimits(8.0, 2.0, 3.0, 2.0), city, radius,
                            cfg.safety_margin_m)
    assert ref.ok, ref.status
    assert _zone_clearance(WALL, ref.pos_m, radius).min() >= cfg.safety_margin_m - 1e-6


def test_the_classical_pilot_flies_around_it(vehicles, compiled_dynamics) -> None:
    p = vehicles["small_quad"]
    city = _open_field()
    world = World(p, compiled_dynamics["small_quad"], city,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0))
    task = Task(start_m=START, goal_m=GOAL, goal_radius_m=2.5, timeout_s=60.0)
    traj = run_episode(world, ClassicalPilot(), task, WindField.calm(), seed=4)
    assert traj.outcome == "success", traj.detail
    assert _zone_clearance(WALL, traj.states[:, 0:3], p.collision_radius_m).min() > 0.0  # never entered it
