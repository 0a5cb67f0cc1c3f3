"""The plan-and-track pilot flies a small three-building map to the goal without collision."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from alley import alley_city
from compare.flying.episode_loop import run_episode
from compare.flying.promise import scored_report
from planners.classical_pilot import ClassicalConfig, ClassicalPilot
from planners.ladder import LADDER
from planners.margins import SpeedBin, TrackingErrorRow, write_tracking_table
from planners.mpc import MPCSolution
from planners.rrt_star import PlannerConfig, plan_path
from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.air.wind import TurbulenceLevel, WindConditions, WindField
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Observation, Pilot, Task, World
from uam_fdm.vehicle.model import hover_state


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
    pilot = ClassicalPilot()
    assert isinstance(pilot, Pilot)
    traj = run_episode(world, pilot, task, wind, seed=5)
    assert traj.outcome == "success", traj.detail
    assert traj.clearance_m.min() > 0.0
    assert traj.plan_time_s > 0.0 and pilot.plan.ok and pilot.reference.ok
    assert pilot.stats.mpc_failures <= 0.02 * pilot.stats.mpc_solves
    # The planned path really goes around the first tower (a straight line would hit it).
    assert not city.segment_free(task.start_m, task.goal_m, p.collision_radius_m)


def test_unreachable_goal_is_a_planner_failure_not_an_exception(vehicles, compiled_dynamics):
    p = vehicles["small_quad"]
    city = BuildingMap([Building(0, (50.0, 0.0), (20.0, 20.0), 40.0)], (0, -30, 0), (100, 30, 60))
    world = World(p, compiled_dynamics["small_quad"], city,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0))
    task = Task(start_m=(5.0, 0.0, 10.0), goal_m=(50.0, 0.0, 20.0), timeout_s=10.0)   # goal inside the building
    traj = run_episode(world, ClassicalPilot(), task, WindField.calm(), seed=1)
    assert traj.outcome == "planner_failure" and "invalid_goal" in traj.detail
    assert len(traj.t_s) == 1 and np.isfinite(traj.plan_time_s)


def _wall_world(p, dynamics) -> World:
    """A 40 m wall whose face runs along y = 3 m, beside a straight 60 m flight along y = 0 at 10 m."""
    city = BuildingMap([Building(0, (30.0, 4.0), (40.0, 2.0), 40.0)], (-10.0, -30.0, 0.0), (80.0, 30.0, 50.0))
    return World(p, dynamics, city, Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "none")


def _fake_prediction(pilot: ClassicalPilot, start: np.ndarray, end: np.ndarray) -> MPCSolution:
    """A last MPC solution whose predicted positions run in a straight line from `start` to `end`."""
    n = pilot._tracker.config.horizon_steps
    pred = np.zeros((n + 1, 13))
    pred[:, 0:3] = np.linspace(start, end, n + 1)
    pred[:, 6] = 1.0
    return MPCSolution(np.zeros(4), True, "fake", 1, 1e-3, False, pred, 0.0)


def test_a_predicted_clearance_violation_replans_from_the_current_state(vehicles, compiled_dynamics):
    p = vehicles["small_quad"]
    world = _wall_world(p, compiled_dynamics["small_quad"])
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=30.0)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, max_clearance_replans=2, replan_cooldown_s=1.0)
    pilot = ClassicalPilot(cfg)
    assert pilot.reset(world, task, seed=3).ok
    assert (pilot.margins.planner_m, pilot.margins.mpc_m) == (1.0, 0.5)

    def obs_at(t: float) -> Observation:
        pos = pilot.reference.sample(t - pilot._t_ref0)[0]
        return Observation(t, hover_state(p, pos))

    # a prediction that stays 3 m from the wall: tracked, no replan
    o = obs_at(1.0)
    pilot.last_solution = _fake_prediction(pilot, o.x[0:3], o.x[0:3] + (8.0, 0.0, 0.0))
    pilot.act(o)
    assert pilot.stats.replans_by_cause == {"tracking": 0, "clearance": 0, "blocked": 0, "uncertainty": 0}
    # a prediction bending to 0.2 m from the wall's face (sphere clearance 0.2 - 0.42 < the MPC's 0.5 m)
    plan_before, reference_before = pilot.stats.plan_time_s, pilot.reference
    o = obs_at(1.2)
    o.x[3:6] = (3.0, 0.0, 0.0)                          # moving east at 3 m/s
    pilot.last_solution = _fake_prediction(pilot, o.x[0:3], o.x[0:3] + (8.0, 2.8, 0.0))
    assert pilot.predicted_clearance_m(pilot.last_solution.predicted_states[1:, 0:3]) < 0.0
    pilot.act(o)
    assert pilot.stats.replans_by_cause == {"tracking": 0, "clearance": 1, "blocked": 0, "uncertainty": 0}
    assert pilot.reference is not reference_before and pilot._t_ref0 == 1.2          # from the current state
    assert np.allclose(pilot.plan.path_m[0], o.x[0:3])
    assert np.linalg.norm(pilot.reference.vel_m_s[0]) == pytest.approx(3.0, abs=0.3)  # no stop to replan
    assert pilot.stats.plan_time_s > plan_before and pilot.stats.replan_time_s > 0.0  # counted as planning
    # within the cooldown: no second replan; after it: one more, then the budget (2) is spent
    for t, expected in ((1.7, 1), (2.3, 2), (3.5, 2)):
        o = obs_at(t)
        pilot.last_solution = _fake_prediction(pilot, o.x[0:3], o.x[0:3] + (8.0, 2.8, 0.0))
        pilot.act(o)
        assert pilot.stats.replans_by_cause["clearance"] == expected, t
    report = pilot.episode_report()
    assert (report.replans_clearance, report.replans_tracking, report.replans) == (2, 0, 2)
    assert report.plan_time_s == pilot.stats.plan_time_s and report.replan_time_s < report.plan_time_s
    assert report.mpc_solves == 5 and report.planner_margin_m == 1.0 and report.mpc_margin_m == 0.5
    assert np.isfinite(report.mpc_solve_ms_median) and report.tracking_max_m >= report.tracking_rms_m >= 0.0


@pytest.mark.parametrize("rate, sensing", [(1.0, True), (math.inf, True), (1.0, False)])
def test_a_vehicle_inside_the_mpc_margin_is_asked_out_at_the_recovery_rate(rate, sensing, vehicles,
                                                                           compiled_dynamics):
    """On sensors, the half-space of a wall the vehicle is inside the margin of starts where the vehicle is and moves
    out at `margin_recovery_m_s` until it reaches the margin; half-spaces it keeps are as they were (inf: all at once,
    as at `perfect` sensing, the privileged reference)."""
    p = vehicles["small_quad"]
    world = _wall_world(p, compiled_dynamics["small_quad"])
    if sensing:
        world = _sensing_world(p, compiled_dynamics["small_quad"], world.city)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=30.0)
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, margin_recovery_m_s=rate))
    assert pilot.reset(world, task, seed=3).ok
    required = p.collision_radius_m + pilot._stage_mpc_margins  # at rest: the same at every stage
    y = 3.0 - required[0] + 0.4  # 0.4 m inside radius + the MPC's margin from the face at y = 3
    x = hover_state(p, (30.0, y, 10.0))
    n = pilot._tracker.horizon_steps
    normals, offsets = pilot._halfspaces(Observation(0.0, x), np.tile(x[0:3], (n + 1, 1)))
    wall = int(np.argmax(normals[0, :, 1] < -0.99))  # facing away from the wall: -y
    margin_offset = -(3.0 - required)  # -y >= -(3 - required): y <= 3 - required
    t_k = pilot._tracker.step_s * np.arange(1, n + 1)
    want = np.minimum(margin_offset, -y + rate * t_k) if sensing else margin_offset
    np.testing.assert_allclose(offsets[:, wall], want, atol=1e-9)
    if sensing and math.isfinite(rate):
        assert offsets[0, wall] < margin_offset[0]  # relaxed at first...
    assert np.any(np.isclose(offsets[:, wall], margin_offset))  # ...the margin itself within the horizon (or at once)
    np.testing.assert_allclose(offsets[:, -1], required)  # the ground, kept: as it was
    with pytest.raises(ValueError, match="margin_recovery_m_s"):
        ClassicalConfig(margin_recovery_m_s=0.0)


def test_margins_follow_the_forecast_turbulence_and_density(vehicles, compiled_dynamics):
    """The pilot asks the shipped table for its vehicle, the world's forecast level and the field's density."""
    from planners.margins import MarginRule, load_tracking_table, margins_for

    p = vehicles["small_quad"]
    table, rule = load_tracking_table(), MarginRule()
    city = _wall_world(p, compiled_dynamics["small_quad"]).city
    for level in ("none", "light", "moderate"):
        for cond in (AtmosphereConditions(), AtmosphereConditions(2500.0, 25.0)):
            atm = Atmosphere.from_jsbsim(cond, z_max_m=100.0)
            world = World(p, compiled_dynamics["small_quad"], city, atm, level)
            task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0))
            got = ClassicalPilot().margins_for(world, task)
            want = margins_for(table, rule, p, level, atm.density_ratio(0.0), 1.0, 0.5)
            assert (got.planner_m, got.mpc_m) == (want.planner_m, want.mpc_m) and got.planner_m >= rule.floor_m


def _speed_table(tmp_path, p) -> Path:
    """A tracking-error table for `p` in calm sea-level air: the margin is 1 m up to 2 m/s, 2 m up to
    6 m/s and 4 m faster (p99 0.3 / 1.0 / 2.0 m, k = 2)."""
    bins = tuple(SpeedBin(lo, hi, 600, e / 3, e / 2, e, 1.2 * e)
                 for lo, hi, e in ((0.0, 2.0, 0.3), (2.05, 6.0, 1.0), (6.05, 30.0, 2.0)))
    row = TrackingErrorRow(p.name, p.fingerprint(), TurbulenceLevel.NONE, 1.0, 3, 1800, 0.3, 1.0, 2.0, 2.4, bins)
    return write_tracking_table([row], {"pool": "test"}, tmp_path / "speed_table.json")


@pytest.mark.parametrize("name, z", [("small_quad", 10.0), ("uam_multicopter", 20.0)])
def test_a_goal_inside_the_cruise_margin_but_reachable_is_reached(name, z, vehicles, compiled_dynamics, tmp_path):
    """The goal lies deep in an alley 3 m narrower than the cruise margin asks: the old single margin could
    not plan there; the ladder plans at the floor margin and the reference slows to what the clearance allows."""
    p = vehicles[name]
    city, start, goal = alley_city(p.collision_radius_m, z_m=z)
    world = World(p, compiled_dynamics[name], city, Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0),
                  "none")
    task = Task(start_m=start, goal_m=goal, goal_radius_m=1.0 + 0.2 * p.collision_radius_m, timeout_s=90.0)
    pilot = ClassicalPilot(ClassicalConfig(tracking_table=_speed_table(tmp_path, p)))
    margins = pilot.margins_for(world, task)
    assert (margins.floor_m, margins.planner_m) == (1.0, 4.0)
    # the old rule, one margin everywhere: no path into the alley
    old = plan_path(city, start, goal, p.collision_radius_m, PlannerConfig(safety_margin_m=margins.planner_m))
    assert not old.ok
    traj = run_episode(world, pilot, task, WindField.calm(), seed=4)
    report = scored_report(pilot, traj)
    assert traj.outcome == "success", traj.detail
    assert math.isnan(pilot.episode_report().clearance_over_margin_min)  # the pilot does not see the truth
    assert report.planner_attempts == 3 and report.planner_step == LADDER[2].name and report.planner_wall_caps == 0
    assert report.planner_margin_floor_m == 1.0 and report.planner_margin_m == 4.0
    assert traj.clearance_m.min() >= 0.5 and report.clearance_over_margin_min >= 0.5
    # in the alley (3 m beyond the sphere) the reference keeps to the speed whose margin fits: 6 m/s
    in_alley = pilot.reference.pos_m[:, 0] > 2.0
    assert np.linalg.norm(pilot.reference.vel_m_s[in_alley], axis=1).max() <= 6.0 + 1e-6
    # the MPC's margin per stage follows the stage's reference speed: at the last decision, slowing into the
    # goal, half of 2 m (<= 6 m/s) on the first stages, then half the margin at rest
    stages = pilot._stage_mpc_margins
    assert set(stages) <= {0.5, 1.0} and stages[-1] == 0.5 and np.all(np.diff(stages) <= 0)


def test_a_walled_in_goal_is_a_planner_failure_with_its_reason(vehicles, compiled_dynamics, tmp_path):
    p = vehicles["small_quad"]
    city, start, goal = alley_city(p.collision_radius_m, closed=True)
    world = World(p, compiled_dynamics["small_quad"], city,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "none")
    cfg = ClassicalConfig(tracking_table=_speed_table(tmp_path, p), planner=PlannerConfig(max_iterations=2000))
    pilot = ClassicalPilot(cfg)
    traj = run_episode(world, pilot, Task(start_m=start, goal_m=goal, timeout_s=10.0), WindField.calm(), seed=1)
    assert traj.outcome == "planner_failure" and "no path at the floor margin 1.00 m in 4 attempts" in traj.detail
    assert "unreachable: no connected free space joins start and goal at margin 1.00 m" in traj.detail
    assert len(traj.t_s) == 1 and pilot.episode_report().planner_attempts == 4


def test_the_fastest_candidate_plan_is_flown_and_a_late_one_climbs_the_ladder(vehicles, compiled_dynamics):
    """Each step's further seeds are timed as the pilot would fly them; the fastest is flown. A task whose time
    even the fastest does not fit makes the ladder try every step, and the fastest path of all is flown."""
    import dataclasses

    p = vehicles["small_quad"]
    city = _three_buildings(1.0)
    world = World(p, compiled_dynamics["small_quad"], city,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "light")
    steps = (dataclasses.replace(LADDER[0], candidates=3), *LADDER[1:])
    task = Task(start_m=(0.0, 0.0, 15.0), goal_m=(110.0, 0.0, 20.0), goal_radius_m=2.5, timeout_s=90.0)
    pilot = ClassicalPilot(ClassicalConfig(ladder=steps))
    assert pilot.reset(world, task, seed=5).ok
    found = pilot.ladder_result
    assert found is not None and found.step == 1 and len(found.candidates) == 3
    assert pilot.plan is found.plan and pilot.stats.planner_candidates == 3
    assert pilot.reference.duration_s == found.duration_s == min(found.durations_s)
    assert max(found.durations_s) > min(found.durations_s)  # the seeds found different paths
    # each is judged by the pilot's own timing: the first candidate (a third of the budget) flown alone
    alone = (dataclasses.replace(LADDER[0], candidates=1, max_iterations=-(-10_000 // 3)), *LADDER[1:])
    single = ClassicalPilot(ClassicalConfig(ladder=alone))
    assert single.reset(world, task, seed=5).ok
    assert single.reference.duration_s == found.durations_s[0] >= pilot.reference.duration_s
    # no time for any path (80 % of 5 s): every step is tried (3: at sea level in light turbulence the floor is
    # the cruise margin, so step 3 would repeat step 1), the fastest path of all flown
    late = dataclasses.replace(task, timeout_s=5.0)
    assert pilot.reset(world, late, seed=5).ok
    tried = pilot.ladder_result
    assert pilot.margins.floor_m == pilot.margins.planner_m
    assert [a.algorithm for a in tried.attempts] == ["informed_rrtstar", "rrtconnect", "rrtconnect"]
    assert tried.duration_s == min(tried.durations_s) > 4.0 and len(tried.candidates) == sum(
        s.candidates for i, s in enumerate(steps) if i != 2)


def _sensed_obs(pilot: ClassicalPilot, p, t: float, lidar, pos: np.ndarray) -> Observation:
    """An observation on the true hover state at `pos` with one lidar scan and a 0.1 m position σ."""
    from uam_fdm.pilot import SensorData

    scan, _ = lidar.scan(t, pos, np.eye(3))
    return Observation(t, hover_state(p, pos), covariance=np.eye(16) * 0.01, sensors=SensorData(lidar=(scan,)),
                       estimate_t_s=t)


def test_a_wall_the_prior_lacks_blocks_the_path_and_the_pilot_flies_round_it(vehicles, compiled_dynamics):
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster
    from uam_fdm.sensing.specs import sensing_preset

    p = vehicles["small_quad"]
    bounds = ((-10.0, -30.0, 0.0), (80.0, 30.0, 50.0))
    prior = BuildingMap([], *bounds)
    # across the straight line, low enough for the lidar's highest beam to see its top from the start (unseen space
    # above a wall is free to the planner, as all unseen space is)
    truth = BuildingMap([Building(7, (30.0, -2.0), (2.0, 20.0), 15.0)], *bounds)
    world = World(p, compiled_dynamics["small_quad"], prior,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "none",
                  sensing=sensing_preset("nominal", p.mass_kg))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False)
    pilot = ClassicalPilot(cfg)
    assert pilot.reset(world, task, seed=3).ok
    assert pilot.margins.planner_m > cfg.planner.safety_margin_m  # widened by k σ of the pad's survey
    lidar = Lidar(world.sensing.lidar, RayCaster(truth), np.random.default_rng(0))
    straight = pilot.reference
    pilot.act(_sensed_obs(pilot, p, 0.0, lidar, np.array(task.start_m)))
    assert pilot.stats.replans_by_cause["blocked"] == 1
    # 30 m ahead of a vehicle at rest: it flies on while the replan's budget runs, and could still stop short after
    assert pilot._pending is not None and pilot.reference is straight
    new_plan_t0 = pilot._pending[2]
    assert new_plan_t0 == pytest.approx(cfg.replan_budget_s)
    pilot.act(_sensed_obs(pilot, p, cfg.replan_budget_s, lidar, np.array(task.start_m)))
    assert pilot._pending is None and pilot._t_ref0 == pytest.approx(cfg.replan_budget_s)
    # the new reference keeps clear of the wall it never had on its map
    assert truth.clearance(pilot.reference.pos_m, p.collision_radius_m).distance_m.min() > 0.5
    report = pilot.episode_report()
    assert report.replans_blocked == 1 and report.replans == 1 and report.hover_holds == 0
    assert report.sensed_obstacles >= 1 and report.map_update_ms_median > 0.0
    assert report.replan_ms_median > 0.0


def test_no_path_in_what_it_knows_makes_the_pilot_hold(vehicles, compiled_dynamics):
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster
    from uam_fdm.sensing.specs import sensing_preset

    p = vehicles["small_quad"]
    bounds = ((-10.0, -30.0, 0.0), (80.0, 30.0, 20.0))
    prior = BuildingMap([], *bounds)
    # a wall across the whole flight volume, taller than its top (its face seen up to 18 m of the volume's 20 m: no
    # room left above it for the sphere and its margin)
    truth = BuildingMap([Building(7, (30.0, 0.0), (2.0, 60.0), 60.0)], *bounds)
    world = World(p, compiled_dynamics["small_quad"], prior,
                  Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "none",
                  sensing=sensing_preset("nominal", p.mass_kg))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False))
    assert pilot.reset(world, task, seed=3).ok
    lidar = Lidar(world.sensing.lidar, RayCaster(truth), np.random.default_rng(0))
    pilot.act(_sensed_obs(pilot, p, 0.0, lidar, np.array(task.start_m)))
    assert pilot.stats.hover_holds == 1 and pilot._pending is None and pilot.stats.hold_moves == 0
    hold = pilot.reference
    assert np.allclose(hold.sample(100.0)[1], 0.0)  # at rest: a hover where the braking ends
    pilot.act(_sensed_obs(pilot, p, 0.5, lidar, np.array(task.start_m)))
    assert pilot.stats.hover_holds == 1  # still the same hold; the retry waits for hold_retry_s
    pilot.act(_sensed_obs(pilot, p, 1.0, lidar, np.array(task.start_m)))
    assert pilot.stats.hover_holds == 1 and len(pilot.stats.in_flight_replan_s) == 2  # retried, still no path


def test_a_hold_in_a_gap_narrower_than_the_margin_moves_to_the_nearest_point_where_it_fits(vehicles,
                                                                                          compiled_dynamics):
    """A hold where the braking ends in a slot narrower than twice the MPC's margin at rest (no hover keeps it there)
    moves straight to the nearest point that keeps the margin: up, out of a long slot; along it, out of a short one
    under a roof; and nowhere out of a closed one, or in open space."""
    from planners.timing import braking_reference

    p = vehicles["small_quad"]
    r = p.collision_radius_m
    bounds = ((-10.0, -40.0, 0.0), (100.0, 40.0, 40.0))
    half = r + 1.3  # the walls' centres: faces r + 0.3 m from the slot's middle

    def slot(x: float, y: float, length: float) -> list[Building]:
        return [Building(1, (x, y + side), (length, 2.0), 15.0) for side in (-half, half)]

    long_slot = slot(40.0, 20.0, 30.0)
    roofed = [*slot(80.0, 20.0, 4.0), Building(2, (80.0, 20.0), (6.0, 8.0), 18.0, base_m=16.0)]
    closed = [*slot(80.0, -20.0, 4.0), Building(3, (80.0, -20.0), (6.0, 8.0), 18.0, base_m=16.0),
              *[Building(4, (80.0 + side, -20.0), (2.0, 8.0), 18.0) for side in (-3.0, 3.0)]]
    city = BuildingMap([*long_slot, *roofed, *closed], *bounds)
    world = _sensing_world(p, compiled_dynamics["small_quad"], city)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False))
    assert pilot.reset(world, task, seed=3).ok
    need = pilot._rest_margin_m()
    assert need > 0.3  # a slot leaves a hover at its middle 0.3 m

    def moved(at: tuple[float, float, float]) -> np.ndarray:
        brake = braking_reference(np.array([at[0] - 1.0, at[1], at[2] - 1.0]), np.array([1.0, 0.0, 1.0]), 0.5 ** 0.5)
        assert np.allclose(brake.pos_m[-1], at)
        hold = pilot._hold_reference(brake)
        end, v_end, _ = hold.sample(100.0)
        assert np.allclose(v_end, 0.0) and np.allclose(hold.sample(brake.duration_s)[0], at)  # the braking first
        assert np.abs(hold.vel_m_s[brake.pos_m.shape[0]:]).max(initial=0.0) <= \
            pilot._limits.max_vertical_speed_m_s + 1e-9
        # a straight move, clear of the city; the margin kept where it ends
        assert city.clearance(np.asarray(hold.pos_m), r).distance_m.min() > 0.0
        assert float(city.clearance(end[None, :], r).distance_m[0]) >= need
        return end - np.asarray(at)

    up = moved((39.0, 20.0, 9.0))
    assert np.allclose(up[0:2], 0.0) and 15.0 + r + need - 9.0 <= up[2] <= 15.0 + r + need - 9.0 + 1.0
    out = moved((80.0, 20.0, 10.0))  # the roof 6 m up blocks the climb; 2 m along the slot its end
    assert abs(out[0]) > 2.0 and np.linalg.norm(out) <= pilot.config.hold_search_m
    assert pilot.stats.hold_moves == 2
    for at in ((20.0, 0.0, 10.0), (80.0, -20.0, 10.0)):  # open space; a closed slot
        brake = braking_reference(np.array(at), np.zeros(3), 1.0)
        assert pilot._hold_reference(brake) is brake
    assert pilot.stats.hold_moves == 2


def test_a_failed_solve_with_no_plan_left_hands_the_vehicle_to_its_velocity_autopilot(vehicles, compiled_dynamics,
                                                                                     monkeypatch):
    """Hover trim holds no vertical speed: when the MPC falls back to it, the pilot commands the vehicle's velocity
    autopilot back onto the reference instead."""
    from uam_fdm.pilot import RotorCommand, VelocityCommand

    p = vehicles["small_quad"]
    world = _wall_world(p, compiled_dynamics["small_quad"])
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(60.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=30.0)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False, autopilot_gain_1_s=0.5)
    pilot = ClassicalPilot(cfg)
    assert pilot.reset(world, task, seed=3).ok
    x = hover_state(p, (0.0, 0.0, 12.0))
    x[3:6] = (0.0, 0.0, -6.0)  # 2 m above the reference, falling
    assert isinstance(pilot.act(Observation(0.0, x)), RotorCommand)
    solved = pilot.last_solution
    monkeypatch.setattr(pilot._tracker, "solve", lambda *a, **k: dataclasses.replace(
        solved, success=False, fallback=True, status="fallback_hover(test)", hover_trim=True))
    act = pilot.act(Observation(0.02, x))
    assert isinstance(act, VelocityCommand) and pilot.stats.autopilot_decisions == 1
    ref_pos, ref_vel, _ = pilot.reference.sample(0.02 - pilot._t_ref0)
    assert np.allclose(act.velocity_enu_m_s, ref_vel + 0.5 * (ref_pos - x[0:3]))
    assert act.velocity_enu_m_s[2] == pytest.approx(-1.0, abs=0.05) and act.yaw_rad == task.start_yaw_rad
    # hover trim predicts nothing (its states are zeros): the next half-spaces are built around the reference, as
    # with no solution at all, not around the map's origin
    assert pilot._predicted_positions() is None
    horizon = pilot.reference.sample_horizon(0.04 - pilot._t_ref0, pilot._tracker.step_s,
                                             pilot._tracker.horizon_steps + 1)[0]
    after_trim = pilot._halfspaces(Observation(0.04, x), horizon)
    pilot.last_solution = None
    for got, want in zip(after_trim, pilot._halfspaces(Observation(0.04, x), horizon), strict=True):
        np.testing.assert_allclose(got, want)
    monkeypatch.setattr(pilot._tracker, "solve", lambda *a, **k: dataclasses.replace(
        solved, success=False, fallback=True, status="fallback_shifted(test)", hover_trim=False))
    assert isinstance(pilot.act(Observation(0.04, x)), RotorCommand)  # the previous plan's input still covers now
    with pytest.raises(ValueError, match="autopilot_gain_1_s"):
        ClassicalConfig(autopilot_gain_1_s=0.0)
    with pytest.raises(ValueError, match="see_reaction_s"):
        ClassicalConfig(see_reaction_s=-0.1)


def _sensing_world(p, dynamics, prior: BuildingMap) -> World:
    from uam_fdm.sensing.specs import sensing_preset

    return World(p, dynamics, prior, Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=100.0), "none",
                 sensing=sensing_preset("nominal", p.mass_kg))


@pytest.mark.parametrize("see", [True, False])
def test_the_reference_clock_slows_to_stop_short_of_the_path_hidden_round_a_corner(see, vehicles, compiled_dynamics):
    """Flying a plan east at 8 m/s past a block's corner, beyond which it turns north out of sight: 5 m before the
    corner the reference's clock slows so that the vehicle, reacting and braking, stops short of the first point it
    cannot see with its margin at rest; 25 m before it, it runs at full rate; the clock advances at its rate."""
    from planners.timing import Reference
    from planners.visibility import stopping_speed_m_s

    p = vehicles["small_quad"]
    block = Building(0, (24.0, 11.0), (8.0, 18.0), 30.0)  # its south-east corner at (28, 2)
    world = _sensing_world(p, compiled_dynamics["small_quad"],
                           BuildingMap([block], (-10.0, -30.0, 0.0), (80.0, 60.0, 50.0)))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(30.0, 20.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, see_to_stop=see))
    assert pilot.reset(world, task, seed=3).ok
    speed = 8.0
    east = np.column_stack([np.arange(0.0, 30.0, 0.1), np.zeros(300), np.full(300, 10.0)])
    north = np.column_stack([np.full(200, 30.0), np.arange(0.0, 20.0, 0.1), np.full(200, 10.0)])
    path = np.vstack([east, north[1:]])
    t = np.arange(len(path)) * 0.1 / speed
    vel = np.vstack([np.tile([speed, 0.0, 0.0], (300, 1)), np.tile([0.0, speed, 0.0], (199, 1))])
    pilot.reference = Reference(t_s=t, pos_m=path, vel_m_s=vel, acc_m_s2=np.zeros_like(path), duration_s=float(t[-1]),
                                status="ok", length_m=49.9, min_clearance_m=1.0, required_clearance_m=1.0,
                                refinements=0, stops=0)
    by_speed = pilot._base_margins.by_speed
    keep = p.collision_radius_m + float(by_speed.mpc_fraction * by_speed.margin_m(0.0))
    decel, reaction = pilot._limits.max_accel_m_s2, pilot.config.see_reaction_s

    def run_at(x: float, dt: float = 10.0) -> float:  # long enough since the last decision to reach the target
        at = x / speed
        pilot._t_ref0, pilot._clock_t, pilot._scale = 0.0, at - dt, 1.0  # at rate 1 the clock stands at `at`
        state = hover_state(p, (x, 0.0, 10.0))
        state[3:6] = (speed, 0.0, 0.0)
        pilot._run_clock(Observation(at, state, covariance=np.eye(16) * 0.01))
        return pilot._scale

    assert run_at(5.0) == 1.0  # 25 m before the corner: the stop fits in what it sees
    near = run_at(25.0)
    if not see:
        assert near == 1.0
        return
    # from (25, 0) the line of sight grazing the corner (28, 2) shows the north leg's centre up to y = 2 * 5 / 3; the
    # tube around it (`keep` across) is hidden sooner, but not before the corner's own side of it (x = 30 - keep)
    seen = 5.0 + 2.0 * 5.0 / 3.0
    assert 0.0 < near * speed <= stopping_speed_m_s(seen - keep, decel, reaction) < speed
    assert stopping_speed_m_s(5.0 - keep - 0.8 - keep, decel, reaction) <= near * speed
    # the clock ran at that rate for the 0.02 s before the next decision, and its rate changes no faster than the
    # acceleration limit: from 1, 0.02 s after the last decision, by at most 0.02 a / v
    pilot._run_clock(Observation(25.0 / speed + 0.02, hover_state(p, (25.0 + 0.02 * near * speed, 0.0, 10.0)),
                                 covariance=np.eye(16) * 0.01))
    assert 25.0 / speed + 0.02 - pilot._t_ref0 == pytest.approx(25.0 / speed + 0.02 * near)
    assert pilot.stats.clock_scale_min <= near
    pilot._scale, pilot._clock_t = 1.0, pilot._clock_t - 0.02
    pilot._run_clock(Observation(pilot._clock_t + 0.02, hover_state(p, (25.0, 0.0, 10.0)),
                                 covariance=np.eye(16) * 0.01))
    assert pilot._scale == pytest.approx(1.0 - 0.02 * decel / speed)


def test_what_was_in_sight_of_the_reference_stays_seen_while_the_tilted_lidar_looks_down(vehicles, compiled_dynamics):
    """Tilted 30 degrees nose down at 8 m/s, the quad's +-15 degree lidar does not look at the level path ahead: a
    pilot that has not seen it slows right down; one that saw it while level, 5 m before, flies on at full rate."""
    from planners.timing import Reference

    p = vehicles["small_quad"]
    open_city = BuildingMap([], (-10.0, -30.0, 0.0), (120.0, 30.0, 50.0))
    world = _sensing_world(p, compiled_dynamics["small_quad"], open_city)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(100.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    speed = 8.0
    path = np.column_stack([np.arange(0.0, 100.0, 0.1), np.zeros(1000), np.full(1000, 10.0)])
    t = np.arange(1000) * 0.1 / speed
    reference = Reference(t_s=t, pos_m=path, vel_m_s=np.tile([speed, 0.0, 0.0], (1000, 1)),
                          acc_m_s2=np.zeros_like(path), duration_s=float(t[-1]), status="ok", length_m=99.9,
                          min_clearance_m=10.0, required_clearance_m=1.0, refinements=0, stops=0)
    tilt = math.radians(30.0)
    nose_down = np.array([math.cos(tilt / 2.0), 0.0, math.sin(tilt / 2.0), 0.0])

    def scale_at(pilot: ClassicalPilot, x: float, attitude: np.ndarray) -> float:
        pilot._t_ref0 = 0.0
        state = hover_state(p, (x, 0.0, 10.0))
        state[3:6], state[6:10] = (speed, 0.0, 0.0), attitude
        target = pilot._clock_target(Observation(x / speed, state, covariance=np.eye(16) * 0.01))
        assert target is not None
        return target

    fresh = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None))
    assert fresh.reset(world, task, seed=3).ok
    fresh.reference = reference
    assert scale_at(fresh, 10.0, nose_down) < 0.5
    looked = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None))
    assert looked.reset(world, task, seed=3).ok
    looked.reference = reference
    assert scale_at(looked, 5.0, np.array([1.0, 0.0, 0.0, 0.0])) == 1.0  # level: the path ahead in sight
    assert scale_at(looked, 10.0, nose_down) == 1.0  # remembered
    looked.reference = dataclasses.replace(reference)  # a new reference: nothing of it seen yet
    assert scale_at(looked, 10.0, nose_down) < 0.5


def _sensing_a_wall_under_way(vehicles, compiled_dynamics, wall_x_m: float):
    """A small quad 4 s into a straight 140 m leg (at speed by then) senses a wall the prior lacks across its line at
    x = `wall_x_m`: (params, truth, config, pilot after that decision, the reference it flew, t, its velocity)."""
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster

    p = vehicles["small_quad"]
    bounds = ((-10.0, -40.0, 0.0), (160.0, 40.0, 50.0))
    truth = BuildingMap([Building(7, (wall_x_m, -2.0), (2.0, 20.0), 25.0)], *bounds)
    world = _sensing_world(p, compiled_dynamics["small_quad"], BuildingMap([], *bounds))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(140.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=90.0)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False)
    pilot = ClassicalPilot(cfg)
    assert pilot.reset(world, task, seed=3).ok
    lidar = Lidar(world.sensing.lidar, RayCaster(truth), np.random.default_rng(0))
    straight = pilot.reference
    t = 4.0
    pos, vel, _ = straight.sample(t)
    pilot.act(_sensed_obs(pilot, p, t, lidar, pos))
    return p, truth, cfg, pilot, straight, t, vel


def test_a_wall_sensed_beyond_where_it_could_stop_lets_the_pilot_fly_on_while_it_replans(vehicles,
                                                                                      compiled_dynamics):
    """The wall lies 70 m down the path: flying on through the replan's budget and braking after it would still stop
    short of it, so the vehicle keeps to its reference meanwhile, and the new plan starts along its velocity there."""
    p, truth, cfg, pilot, straight, t, vel = _sensing_a_wall_under_way(vehicles, compiled_dynamics, 100.0)
    assert pilot.stats.replans_by_cause["blocked"] == 1 and pilot._pending is not None
    assert pilot.reference is straight  # flying on, no braking
    plan = pilot._pending[0]
    at_switch, v_switch, _ = straight.sample(t + cfg.replan_budget_s)
    assert np.allclose(plan.path_m[0], at_switch)  # the new path leaves from where the reference will be
    lead = plan.path_m[1] - plan.path_m[0]
    assert float(lead @ v_switch) / (np.linalg.norm(lead) * np.linalg.norm(v_switch)) > 0.999  # along the velocity
    assert np.linalg.norm(pilot._pending[1].sample(0.0)[1]) > 0.9 * np.linalg.norm(v_switch)  # at its speed
    assert truth.clearance(pilot._pending[1].pos_m, p.collision_radius_m).distance_m.min() > 0.5


@pytest.mark.parametrize("slack_m, replans", [(0.3, 1), (8.0, 0)])
def test_a_grown_uncertainty_replans_only_when_the_path_lacks_the_room(slack_m, replans, vehicles,
                                                                       compiled_dynamics):
    """k σ grows by 0.9 m (past the 0.5 m that prompts a look): between walls 0.3 m wider than the margin needs the
    path is replanned for the uncertainty; with 8 m to spare it is kept."""
    from planners.classical_pilot import position_sigma_m
    from uam_fdm.pilot import SensorData
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.onboard import initial_covariance
    from uam_fdm.sensing.raycast import RayCaster

    p = vehicles["small_quad"]
    bounds = ((-10.0, -40.0, 0.0), (90.0, 40.0, 50.0))
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False)
    world = _sensing_world(p, compiled_dynamics["small_quad"], BuildingMap([], *bounds))
    pilot = ClassicalPilot(cfg)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(80.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=60.0)
    assert pilot.reset(world, task, seed=3).ok  # only to learn the margin in force
    gap = p.collision_radius_m + pilot.margins.planner_m + slack_m  # from the line to each wall
    walls = [Building(7 + i, (40.0, s * (gap + 5.0)), (20.0, 10.0), 40.0) for i, s in enumerate((-1, 1))]
    city = BuildingMap(walls, *bounds)
    world = _sensing_world(p, compiled_dynamics["small_quad"], city)
    assert pilot.reset(world, task, seed=3).ok
    lidar = Lidar(world.sensing.lidar, RayCaster(city), np.random.default_rng(0))
    sigma0 = position_sigma_m(initial_covariance(world.sensing))  # what the plan was widened for
    grown = (sigma0 + 0.3) ** 2  # k σ (k = 3) up by 0.9 m
    for t in (0.0, 0.1):
        pos = pilot.reference.sample(t)[0]
        scan, _ = lidar.scan(t, pos, np.eye(3))
        pilot.act(Observation(t, hover_state(p, pos), covariance=np.eye(16) * grown, sensors=SensorData(lidar=(scan,)),
                              estimate_t_s=t))
    assert pilot.stats.replans_by_cause["uncertainty"] == replans
    assert pilot.stats.replans_by_cause["blocked"] == 0


def test_a_plan_found_at_the_floor_margin_looks_for_a_faster_one_while_flying_on(vehicles, compiled_dynamics):
    """Every `improve_period_s` the pilot on a floor-margin plan searches for a faster one from where its reference
    will be; in open air the straight line it flies is the fastest, so it keeps it and never stops."""
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster

    p = vehicles["small_quad"]
    bounds = ((-10.0, -40.0, 0.0), (160.0, 40.0, 50.0))
    city = BuildingMap([], *bounds)
    world = _sensing_world(p, compiled_dynamics["small_quad"], city)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(140.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=90.0)
    pilot = ClassicalPilot(cfg)
    assert pilot.reset(world, task, seed=3).ok
    pilot._on_floor = True  # as if the speed margins had not fitted
    lidar = Lidar(world.sensing.lidar, RayCaster(city), np.random.default_rng(0))
    flown = pilot.reference
    for t in (cfg.improve_period_s - 0.1, cfg.improve_period_s):
        pilot.act(_sensed_obs(pilot, p, t, lidar, flown.sample(t)[0]))
    assert pilot.stats.improvements_tried == 1 and pilot.stats.improvements_taken == 0
    assert pilot.reference is flown and pilot._pending is None and pilot._on_floor
    assert sum(pilot.stats.replans_by_cause.values()) == 0


def test_a_plan_made_for_a_wider_uncertainty_looks_for_a_faster_one_once_it_has_eased(vehicles, compiled_dynamics):
    """A plan made while k σ was wide (a GNSS outage: the margin closed streets) is flown on once k σ has fallen
    `uncertainty_replan_m` below what it took, and every `improve_period_s` the pilot searches for a faster one, as on
    a plan found at the floor margin; in open air the straight line it flies is the fastest, so it keeps it."""
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster

    p = vehicles["small_quad"]
    city = BuildingMap([], (-10.0, -40.0, 0.0), (160.0, 40.0, 50.0))
    world = _sensing_world(p, compiled_dynamics["small_quad"], city)
    cfg = ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False)
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(140.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=90.0)
    lidar = Lidar(world.sensing.lidar, RayCaster(city), np.random.default_rng(0))
    for wider_m, tries in ((cfg.uncertainty_replan_m + 1.0, 1), (0.0, 0)):
        pilot = ClassicalPilot(cfg)
        assert pilot.reset(world, task, seed=3).ok and not pilot._on_floor
        # as if planned during an outage (k σ then) that has ended since; the observations' σ is 0.1 m
        pilot._planned_extra_m = cfg.uncertainty_k * 0.1 + wider_m
        flown = pilot.reference
        for t in (cfg.improve_period_s - 0.1, cfg.improve_period_s):
            pilot.act(_sensed_obs(pilot, p, t, lidar, flown.sample(t)[0]))
        assert pilot.stats.improvements_tried == tries and pilot.stats.improvements_taken == 0
        assert pilot.reference is flown and pilot._pending is None
        assert sum(pilot.stats.replans_by_cause.values()) == 0


def test_a_replan_in_flight_asks_the_ladder_for_a_path_that_arrives_in_time(vehicles, compiled_dynamics,
                                                                           monkeypatch):
    """In flight the ladder climbs on past a step whose path cannot arrive within `time_fraction` of the time left
    (from the new plan's start), as at reset; before, it flew the first path found, however slow (a UAM climbing over
    towers at 2 m/s until its time ran out while a street path at the floor margin fitted)."""
    import planners.classical_pilot as cp

    asked = []
    ladder = cp.plan_with_escalation

    def spy(*args, **kwargs):
        asked.append(kwargs["time_available_s"])
        return ladder(*args, **kwargs)

    monkeypatch.setattr(cp, "plan_with_escalation", spy)
    _, _, cfg, pilot, _, _, _ = _sensing_a_wall_under_way(vehicles, compiled_dynamics, 60.0)
    task = pilot._task
    assert pilot.stats.replans_by_cause["blocked"] == 1 and pilot._pending is not None
    t_switch = pilot._pending[2]
    assert asked[0] == pytest.approx(cfg.time_fraction * task.timeout_s)  # at reset
    assert asked[-1] == pytest.approx(cfg.time_fraction * (task.timeout_s - t_switch))


def test_a_wall_sensed_too_near_to_fly_on_makes_the_pilot_brake_and_plan_from_where_it_stops(vehicles,
                                                                                           compiled_dynamics):
    """The wall lies 30 m ahead of a vehicle at 9.6 m/s: it brakes along its path, and the new plan starts at rest
    where the braking ends (after the budget when stopping takes longer), never across a velocity it still has."""
    p, truth, cfg, pilot, straight, t, vel = _sensing_a_wall_under_way(vehicles, compiled_dynamics, 60.0)
    assert pilot.stats.replans_by_cause["blocked"] == 1 and pilot._pending is not None
    brake = pilot.reference
    assert brake is not straight and brake.stops == 1
    stop_s = float(np.linalg.norm(vel)) / pilot._limits.max_accel_m_s2
    assert stop_s > cfg.replan_budget_s
    assert pilot._pending[2] == pytest.approx(t + brake.duration_s) and brake.duration_s == pytest.approx(stop_s, 0.02)
    plan, new = pilot._pending[0], pilot._pending[1]
    assert np.allclose(plan.path_m[0], brake.pos_m[-1]) and np.linalg.norm(new.sample(0.0)[1]) < 1e-9  # from rest
    assert truth.clearance(new.pos_m, p.collision_radius_m).distance_m.min() > 0.5


def test_a_stop_that_would_end_in_a_wall_sensed_since_plans_from_where_the_vehicle_is(vehicles, compiled_dynamics):
    """A wall sensed within the stopping distance: the stop along the path ends inside the wall (behind the thin face
    the pilot senses of it). The plan starts from a stop from where the vehicle is (here at rest, as the MPC would have
    it, short of the wall), not from inside or behind the wall: before, every plan and retry started there, found no
    valid start and the pilot held until its time ran out (tuning leg 3200004/2 at nominal, wrong map)."""
    _, _, _, probe, straight, t, vel = _sensing_a_wall_under_way(vehicles, compiled_dynamics, 60.0)
    x_now = float(straight.sample(t)[0][0])
    stop_m = float(np.dot(vel, vel)) / (2.0 * probe._limits.max_accel_m_s2)
    wall_x = x_now + stop_m  # the stop along the path ends in the middle of the 2 m wall
    p, truth, cfg, pilot, _, t, _ = _sensing_a_wall_under_way(vehicles, compiled_dynamics, wall_x)
    assert pilot.stats.replans_by_cause["blocked"] == 1
    assert pilot.stats.hover_holds == 0 and pilot._pending is not None
    plan, new = pilot._pending[0], pilot._pending[1]
    assert abs(plan.path_m[0][0] - x_now) < 0.5  # from where the observation has the vehicle (hovering), 9 m short
    # clear of what the pilot knows (the wall's unseen top is free to it: a path over it is replanned as the
    # climb brings the rest of the face into view)
    assert pilot._known.clearance(new.pos_m, p.collision_radius_m).distance_m.min() > 0.0


def test_a_goal_swallowed_by_what_the_pilot_knows_is_replaced_by_a_clear_point_of_the_goal_region():
    """Arrival counts anywhere within the goal radius; a sensed wall standing proud of the real one (quantised to
    voxels and columns) can cover the goal itself (validation leg quad-016/8 held 5 m from it for 42 s). The pilot
    plans to the clearest point within 0.6 of the radius; a goal clear in its map is kept as it is."""
    from planners.classical_pilot import GOAL_REGION_FRACTION, goal_region_points

    points = goal_region_points(np.array([10.0, 20.0, 30.0]), 1.8)
    distances = np.linalg.norm(points - [10.0, 20.0, 30.0], axis=1)
    assert points.shape == (104, 3) and np.allclose(distances[:26], 0.45) and np.allclose(distances[-26:], 1.8)
    pilot = ClassicalPilot()
    wall = Building(1, (52.0, 40.0), (4.0, 20.0), 30.0)  # its face at x = 50
    pilot._known = BuildingMap([wall], np.zeros(3), np.array([100.0, 80.0, 40.0]))
    for goal, kept in (((50.5, 40.0, 10.0), False), ((45.0, 40.0, 10.0), True)):
        pilot._task = Task(start_m=(10.0, 40.0, 10.0), goal_m=goal, goal_radius_m=3.0)
        chosen = pilot._goal_in_known(0.42)
        assert np.array_equal(chosen, goal) == kept
        assert pilot._known.clearance_one(*chosen, 0.42) > 0.0
        assert np.linalg.norm(chosen - np.asarray(goal)) <= GOAL_REGION_FRACTION * 3.0 + 1e-9


@pytest.mark.parametrize("climb_weight, over", [(4.0, False), (1.0, True)])
def test_in_flight_a_climb_costs_more_than_its_length_so_the_replan_goes_round_a_wall(climb_weight, over,
                                                                                       vehicles, compiled_dynamics):
    """A wall the prior lacks, 60 m wide and 22 m tall, across a leg flown at 10 m: planned for length (weight 1) the
    replan goes over it; with the in-flight climb weight (a metre climbed costs 4 flown level) it goes round."""
    from uam_fdm.sensing.lidar import Lidar
    from uam_fdm.sensing.raycast import RayCaster

    p = vehicles["small_quad"]
    bounds = ((-10.0, -45.0, 0.0), (160.0, 45.0, 50.0))
    wall_m = 22.0
    truth = BuildingMap([Building(7, (70.0, 0.0), (2.0, 60.0), wall_m)], *bounds)
    world = _sensing_world(p, compiled_dynamics["small_quad"], BuildingMap([], *bounds))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(140.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=90.0)
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False,
                                           in_flight_climb_weight=climb_weight))
    assert pilot.reset(world, task, seed=3).ok
    lidar = Lidar(world.sensing.lidar, RayCaster(truth), np.random.default_rng(0))
    t = 3.0
    pilot.act(_sensed_obs(pilot, p, t, lidar, pilot.reference.sample(t)[0]))
    assert pilot.stats.replans_by_cause["blocked"] == 1
    plan = pilot._pending[0] if pilot._pending is not None else pilot.plan
    assert (float(plan.path_m[:, 2].max()) > wall_m) is over
    assert (float(np.abs(plan.path_m[:, 1]).max()) > 30.0) is not over


def test_the_in_flight_climb_weight_is_checked():
    with pytest.raises(ValueError, match="in_flight_climb_weight"):
        ClassicalConfig(in_flight_climb_weight=0.0)


def test_an_overhang_sensed_above_the_path_blocks_it_as_the_fused_map_closes_it(vehicles, compiled_dynamics):
    """The fused map stands a sensed voxel as a column from the ground: a jib seen 20 m above the path closes the path
    there, so it blocks it (before, its voxels were 20 m from the path, and the vehicle was held short of the goal by
    its MPC until the time ran out: validation leg quad-016/8); one as high 15 m to the side does not."""
    p = vehicles["small_quad"]
    bounds = ((-10.0, -40.0, 0.0), (160.0, 40.0, 50.0))
    world = _sensing_world(p, compiled_dynamics["small_quad"], BuildingMap([], *bounds))
    pilot = ClassicalPilot(ClassicalConfig(margin_rule=None, replan_error_m=None, replan_on_clearance=False))
    task = Task(start_m=(0.0, 0.0, 10.0), goal_m=(140.0, 0.0, 10.0), goal_radius_m=2.0, timeout_s=90.0)
    assert pilot.reset(world, task, seed=3).ok
    obs = Observation(0.0, hover_state(p, np.array(task.start_m)))
    jib = np.array([[70.5, y + 0.5, 30.5] for y in range(-3, 3)])
    assert pilot._path_blocked(obs, jib)
    assert not pilot._path_blocked(obs, jib + (0.0, 15.0, 0.0))
    assert not pilot._path_blocked(obs, jib * (1.0, 1.0, 0.0) + (0.0, 15.0, 5.0))  # low, to the side
