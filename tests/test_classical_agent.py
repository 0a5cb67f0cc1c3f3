"""The plan-and-track pilot flies a small three-building map to the goal without collision."""
from __future__ import annotations

import numpy as np
import pytest

from compare.runner import run_episode
from planners.agent import ClassicalAgent
from uam_fdm.agent import Agent, Task, World
from uam_fdm.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.city import Building, BuildingMap
from uam_fdm.wind import TurbulenceLevel, WindConditions, WindField


def _three_buildings(scale: float) -> BuildingMap:
    """Three towers between start and goal; `scale` stretches the layout for a bigger vehicle."""
    s = scale
    return BuildingMap([Building(0, (40 * s, 0.0), (12 * s, 30 * s), 60.0 * s),
                        Building(1, (70 * s, 25 * s), (14 * s, 14 * s), 45.0 * s),
                        Building(2, (70 * s, -25 * s), (14 * s, 14 * s), 45.0 * s, yaw_rad=0.4)],
                       (-20 * s, -60 * s, 0.0), (130 * s, 60 * s, 80.0 * s), name="three_buildings")


@pytest.mark.parametrize("name, scale", [("small_quad", 1.0), ("uam_multicopter", 3.0)])
def test_plan_and_track_reaches_goal_without_collision(name, scale, vehicles, compiled_dynamics):
    p = vehicles[name]
    city = _three_buildings(scale)
    world = World(p, compiled_dynamics[name], city, Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=300.0))
    task = Task(start_m=(0.0, 0.0, 15.0 * scale), goal_m=(110.0 * scale, 0.0, 20.0 * scale),
                goal_radius_m=2.0 + p.collision_radius_m, timeout_s=90.0)
    wind = WindField.from_conditions(WindConditions((1.5, 0.5, 0.0), TurbulenceLevel.LIGHT), seed=2,
                                     duration_s=task.timeout_s + 1.0, airspeed_m_s=5.0, heights_m=(20.0 * scale,))
    agent = ClassicalAgent()
    assert isinstance(agent, Agent)
    traj = run_episode(world, agent, task, wind, seed=5)
    assert traj.outcome == "success", traj.detail
    assert traj.clearance_m.min() > 0.0
    assert traj.plan_time_s > 0.0 and agent.plan.ok and agent.reference.ok
    assert agent.stats.mpc_failures <= 0.02 * agent.stats.mpc_solves
    # The planned path really goes around the first tower (a straight line would hit it).
    assert not city.segment_free(task.start_m, task.goal_m, p.collision_radius_m)


def test_unreachable_goal_is_a_planner_failure_not_an_exception(vehicles, compiled_dynamics):
    p = vehicles["small_quad"]
    city = BuildingMap([Building(0, (50.0, 0.0), (20.0, 20.0), 40.0)], (0, -30, 0), (100, 30, 60))
    world = World(p, compiled_dynamics["small_quad"], city, Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0))
    task = Task(start_m=(5.0, 0.0, 10.0), goal_m=(50.0, 0.0, 20.0), timeout_s=10.0)   # goal inside the building
    traj = run_episode(world, ClassicalAgent(), task, WindField.calm(), seed=1)
    assert traj.outcome == "planner_failure" and "invalid_goal" in traj.detail
    assert len(traj.t_s) == 1 and np.isfinite(traj.plan_time_s)
