"""The time-parameterisation: limits, rest at both ends, end points, clearance and corner refinement."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planners.timing import Reference, TimingConfig, TimingLimits, time_parameterize
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.vehicle.params import GRAVITY_M_S2, load_vehicle

R_QUAD = 0.42
MARGIN = 1.0
LIMITS = TimingLimits(max_speed_m_s=8.0, max_vertical_speed_m_s=2.0, max_accel_m_s2=4.0, max_vertical_accel_m_s2=3.0)
# Tolerances: speeds are capped exactly at the samples; accelerations are exact per profile interval
# and the curvature is evaluated on a <= 5 cm grid, so the sampled acceleration may exceed a limit
# by interpolation error only.
SPEED_TOL = 1e-6
ACCEL_TOL = 0.01  # relative (measured <= 0.11 %, at a 0.5 m jog; ~1e-4 at ordinary corners)


def empty_city() -> BuildingMap:
    return BuildingMap([], (0, 0, 0), (400, 400, 150))


def corner_city() -> BuildingMap:
    """One 20 m square tower with its south-east corner at (20, 0)."""
    return BuildingMap([Building(0, (10.0, 10.0), (20.0, 20.0), 50.0)], (-50, -50, 0), (100, 100, 100))


ZIGZAG = np.array([[10, 10, 5], [120, 30, 5], [140, 150, 40], [60, 200, 40], [61, 200.5, 40], [300, 300, 12]],
                  dtype=float)


def check_limits(ref: Reference, limits: TimingLimits) -> None:
    vh = np.linalg.norm(ref.vel_m_s[:, :2], axis=1)
    ah = np.linalg.norm(ref.acc_m_s2[:, :2], axis=1)
    assert np.max(vh) <= limits.max_speed_m_s * (1 + SPEED_TOL)
    assert np.max(np.abs(ref.vel_m_s[:, 2])) <= limits.max_vertical_speed_m_s * (1 + SPEED_TOL)
    assert np.max(ah) <= limits.max_accel_m_s2 * (1 + ACCEL_TOL)
    assert np.max(np.abs(ref.acc_m_s2[:, 2])) <= limits.max_vertical_accel_m_s2 * (1 + ACCEL_TOL)


def check_consistent(ref: Reference) -> None:
    """Velocity is the derivative of position, acceleration that of velocity (finite differences of the table)."""
    dt = np.diff(ref.t_s)[:, None]
    v_err = np.linalg.norm(np.diff(ref.pos_m, axis=0) / dt - 0.5 * (ref.vel_m_s[1:] + ref.vel_m_s[:-1]), axis=1)
    assert np.max(v_err) < 0.05  # m/s
    a_err = np.linalg.norm(np.diff(ref.vel_m_s, axis=0) / dt - 0.5 * (ref.acc_m_s2[1:] + ref.acc_m_s2[:-1]), axis=1)
    # The tangential acceleration is piecewise constant: only samples straddling a switch differ.
    assert np.median(a_err) < 1e-6 and np.percentile(a_err, 90) < 0.05


def test_limits_rest_and_end_points_on_a_3d_zigzag():
    ref = time_parameterize(ZIGZAG, LIMITS, empty_city(), R_QUAD, MARGIN)
    assert ref.ok and ref.duration_s > 0
    check_limits(ref, LIMITS)
    check_consistent(ref)
    assert np.array_equal(ref.pos_m[0], ZIGZAG[0]) and np.allclose(ref.pos_m[-1], ZIGZAG[-1], atol=1e-12)
    assert np.all(ref.vel_m_s[0] == 0) and np.all(ref.vel_m_s[-1] == 0)
    assert np.all(np.diff(ref.t_s) > 0) and ref.t_s[0] == 0 and ref.t_s[-1] == ref.duration_s
    # The tight 0.5 m jog (a near reversal) is handled: it stops or rounds, never cusps.
    assert np.all(np.isfinite(ref.acc_m_s2))


def test_straight_line_is_the_trapezoid():
    """Rest to rest over L with speed v and acceleration a: T = L / v + v / a (when L > v^2 / a)."""
    length = 200.0
    ref = time_parameterize(np.array([[10, 10, 20], [10 + length, 10, 20]]), LIMITS, empty_city(), R_QUAD, MARGIN)
    v, a = LIMITS.max_speed_m_s, LIMITS.max_accel_m_s2
    assert ref.duration_s == pytest.approx(length / v + v / a, rel=1e-3)
    vertical = time_parameterize(np.array([[10, 10, 10], [10, 10, 110]]), LIMITS, empty_city(), R_QUAD, MARGIN)
    v, a = LIMITS.max_vertical_speed_m_s, LIMITS.max_vertical_accel_m_s2
    assert vertical.duration_s == pytest.approx(100 / v + v / a, rel=1e-3)


def test_a_reference_can_start_moving():
    """A replan from a moving vehicle: the reference starts at its speed along the path, within the limits."""
    path = np.array([[10, 10, 20], [210, 10, 20]])
    ref = time_parameterize(path, LIMITS, empty_city(), R_QUAD, MARGIN, start_speed_m_s=5.0)
    assert ref.vel_m_s[0] == pytest.approx([5.0, 0.0, 0.0], abs=1e-9) and np.all(ref.vel_m_s[-1] == 0)
    check_limits(ref, LIMITS)
    v, a, v0 = LIMITS.max_speed_m_s, LIMITS.max_accel_m_s2, 5.0   # trapezoid from v0: L/v + (2v² - 2v v0 + v0²)/(2av)
    assert ref.duration_s == pytest.approx(200 / v + (2 * v * v - 2 * v * v0 + v0 * v0) / (2 * a * v), rel=1e-3)
    fast = time_parameterize(path, LIMITS, empty_city(), R_QUAD, MARGIN, start_speed_m_s=50.0)
    assert np.linalg.norm(fast.vel_m_s[0]) == pytest.approx(v)   # capped at the limit
    short = time_parameterize(np.array([[10, 10, 20], [14, 10, 20]]), LIMITS, empty_city(), R_QUAD, MARGIN,
                              start_speed_m_s=8.0)          # cannot stop in 4 m from 8 m/s at 4 m/s^2
    assert np.linalg.norm(short.vel_m_s[0]) == pytest.approx(math.sqrt(2 * a * 4.0), rel=1e-3)
    with pytest.raises(ValueError, match="start_speed_m_s"):
        time_parameterize(path, LIMITS, empty_city(), R_QUAD, MARGIN, start_speed_m_s=-1.0)


def test_sample_clamps_and_horizon():
    ref = time_parameterize(ZIGZAG[:3], LIMITS, empty_city(), R_QUAD, MARGIN)
    p, v, a = ref.sample(ref.duration_s + 5.0)
    assert np.allclose(p, ZIGZAG[2]) and not v.any() and not a.any()
    p, v, a = ref.sample(-1.0)
    assert np.array_equal(p, ZIGZAG[0]) and not v.any() and not a.any()
    P, V, A = ref.sample_horizon(3.0, 0.1, 20)
    assert P.shape == V.shape == A.shape == (20, 3)
    p7, v7, a7 = ref.sample(3.0 + 7 * 0.1)
    assert np.allclose(P[7], p7) and np.allclose(V[7], v7) and np.allclose(A[7], a7)
    P, V, _ = ref.sample_horizon(ref.duration_s - 0.05, 0.1, 3)  # runs past the end: goal at rest
    assert np.allclose(P[1:], ZIGZAG[2]) and not V[1:].any()


def test_deviation_is_the_distance_to_the_curve_not_the_lag():
    ref = time_parameterize(np.array([[10, 10, 20], [210, 10, 20]]), LIMITS, empty_city(), R_QUAD, MARGIN)
    on_path = ref.sample(10.0)[0]
    behind = ref.sample(9.0)[0]                      # 1 s late along the path: no deviation
    assert ref.deviation_m(behind, 10.0) == pytest.approx(0.0, abs=1e-9)
    assert np.linalg.norm(behind - on_path) > 5.0    # ... although the error at t is metres
    assert ref.deviation_m(on_path + (0.0, 0.3, -0.4), 10.0) == pytest.approx(0.5, abs=1e-9)
    # the window: a point near the far end is measured to the curve within 5 s of t, not to the end
    end = ref.pos_m[-1]
    assert ref.deviation_m(end, 1.0) == pytest.approx(np.linalg.norm(end - ref.sample(6.0)[0]), rel=1e-6)


def test_from_vehicle():
    p = load_vehicle("small_quad")
    lim = TimingLimits.from_vehicle(p, speed_fraction=0.8, accel_fraction=0.5)
    assert lim.max_speed_m_s == pytest.approx(0.8 * p.controller.max_speed_m_s)
    assert lim.max_vertical_speed_m_s == pytest.approx(0.8 * p.controller.max_vertical_speed_m_s)
    assert lim.max_accel_m_s2 == pytest.approx(0.5 * GRAVITY_M_S2 * math.tan(math.radians(p.controller.max_tilt_deg)))
    assert lim.max_vertical_accel_m_s2 == pytest.approx(0.5 * GRAVITY_M_S2 * (p.max_thrust_N() / p.weight_N - 1))
    with pytest.raises(ValueError):
        TimingLimits(1.0, 1.0, 0.0, 1.0)


def test_from_vehicle_in_thin_air():
    """Hot and high (density ratio 0.714): the climb and the level-flight tilt are what the thrust gives."""
    p = load_vehicle("small_quad")
    tw = p.max_thrust_N() / p.weight_N                       # 1.92 at sea level
    thin = TimingLimits.from_vehicle(p, 0.8, 0.5, density_ratio=0.714)
    assert thin.max_vertical_accel_m_s2 == pytest.approx(0.5 * GRAVITY_M_S2 * (0.714 * tw - 1))
    # sigma T/W = 1.37 < 1 / cos 45 deg: holding altitude caps the horizontal acceleration below g tan 45
    assert thin.max_accel_m_s2 == pytest.approx(0.5 * GRAVITY_M_S2 * math.sqrt((0.714 * tw) ** 2 - 1))
    assert thin.max_accel_m_s2 < TimingLimits.from_vehicle(p).max_accel_m_s2
    assert thin.max_speed_m_s == TimingLimits.from_vehicle(p).max_speed_m_s
    # gusts: level flight at cruise plus the allowance may use 85 % of the thrust; binding only in thin air
    sea, hot = (TimingLimits.from_vehicle(p, density_ratio=s, gust_m_s=5.7) for s in (1.0, 0.714))
    assert sea.max_speed_m_s == pytest.approx(0.8 * p.controller.max_speed_m_s)
    airspeed = hot.max_speed_m_s + 5.7
    drag = p.drag_linear_N_s_m[0] * airspeed + p.drag_quadratic_N_s2_m2[0] * airspeed ** 2
    assert math.hypot(p.weight_N, drag) == pytest.approx(0.85 * 0.714 * p.max_thrust_N(), rel=1e-9)
    assert 5.0 < hot.max_speed_m_s < 7.0
    with pytest.raises(ValueError, match="cannot hover at density ratio 0.400"):
        TimingLimits.from_vehicle(p, density_ratio=0.4)


def _dense_clearance(ref: Reference, city: BuildingMap) -> float:
    """Clearance of the vehicle sphere along the reference, sampled <= 5 cm apart."""
    dt = 0.05 / max(LIMITS.max_speed_m_s, LIMITS.max_vertical_speed_m_s) / 1.5
    p, _, _ = ref.sample_horizon(0.0, dt, int(ref.duration_s / dt) + 2)
    assert np.max(np.linalg.norm(np.diff(p, axis=0), axis=1)) <= 0.05
    return float(np.min(city.clearance(p, R_QUAD).distance_m))


# The path hugs the tower's south face 2 m out, turns north 2 m east of its east face: corner (22, -2).
# Rounding it with the default d = 0.24 * 42 m would cut ~3 m into the corner region.
CORNER_PATH = np.array([[-30.0, -2.0, 10.0], [22.0, -2.0, 10.0], [22.0, 40.0, 10.0]])


def test_refinement_triggers_on_a_tight_corner_and_fixes_it():
    city = corner_city()
    ref = time_parameterize(CORNER_PATH, LIMITS, city, R_QUAD, MARGIN)
    assert ref.ok and ref.refinements >= 1 and ref.stops == 0  # rounded, but less
    assert ref.min_clearance_m >= MARGIN
    assert _dense_clearance(ref, city) >= MARGIN - 1e-3  # interpolation of the 50 Hz table
    check_limits(ref, LIMITS)
    # Without refinement the same corner is unsafe to round: it becomes a stop.
    blunt = time_parameterize(CORNER_PATH, LIMITS, city, R_QUAD, MARGIN, TimingConfig(max_refinements=0))
    assert blunt.ok and blunt.stops == 1 and blunt.min_clearance_m >= MARGIN
    v_corner = np.linalg.norm(blunt.vel_m_s[np.argmin(np.linalg.norm(blunt.pos_m - CORNER_PATH[1], axis=1))])
    assert v_corner == 0.0
    # And in open space the same corner is rounded at full size, never refined.
    free = time_parameterize(CORNER_PATH, LIMITS, empty_corner_city(), R_QUAD, MARGIN)
    assert free.refinements == 0 and free.duration_s < ref.duration_s


def empty_corner_city() -> BuildingMap:
    return BuildingMap([], (-50, -50, 0), (100, 100, 100))


def test_clearance_of_a_planned_path_is_kept():
    from planners.rrt_star import PlannerConfig, plan_path

    city = BuildingMap([Building(0, (50.0, 22.5), (2.0, 45.0), 60.0), Building(1, (50.0, 77.5), (2.0, 45.0), 60.0),
                        Building(2, (75.0, 60.0), (10.0, 10.0), 60.0)], (0, 0, 0), (100, 100, 40))
    plan = plan_path(city, (20, 20, 10), (90, 90, 30), R_QUAD, PlannerConfig(max_iterations=1500), seed=2)
    assert plan.ok
    ref = time_parameterize(plan.path_m, LIMITS, city, R_QUAD, MARGIN)
    assert ref.ok and ref.min_clearance_m >= MARGIN
    assert _dense_clearance(ref, city) >= MARGIN - 1e-3
    check_limits(ref, LIMITS)
    assert np.allclose(ref.pos_m[0], plan.path_m[0]) and np.allclose(ref.pos_m[-1], plan.path_m[-1])


def test_a_path_through_a_building_is_reported():
    city = corner_city()
    ref = time_parameterize(np.array([[-20.0, 10.0, 10.0], [40.0, 10.0, 10.0]]), LIMITS, city, R_QUAD, MARGIN)
    assert ref.status == "clearance_violation" and not ref.ok and ref.min_clearance_m < 0


def test_degenerate_paths():
    ref = time_parameterize(np.array([[5.0, 5.0, 5.0]]), LIMITS, empty_city(), R_QUAD, MARGIN)
    assert ref.duration_s == 0 and ref.ok
    p, v, _ = ref.sample(1.0)
    assert np.array_equal(p, [5, 5, 5]) and not v.any()
    with pytest.raises(ValueError):
        time_parameterize(np.zeros((0, 3)), LIMITS, empty_city(), R_QUAD, MARGIN)
    with pytest.raises(ValueError):
        time_parameterize(np.array([[0, 0, np.nan], [1, 1, 1]]), LIMITS, empty_city(), R_QUAD, MARGIN)


def test_start_inside_the_margin_uses_the_planners_allowance():
    from planners.rrt_star import PlannerConfig, plan_path

    city = corner_city()
    start = (20.0 + R_QUAD + 0.5, 5.0, 10.0)  # 0.5 m from the tower's east face: inside the 1 m margin
    plan = plan_path(city, start, (60.0, 60.0, 20.0), R_QUAD, PlannerConfig(max_iterations=1500), seed=1)
    assert plan.ok
    ref = time_parameterize(plan.path_m, LIMITS, city, R_QUAD, MARGIN)
    assert ref.ok and ref.min_clearance_m >= 0.5 - 0.05 - 1e-9
    assert np.array_equal(ref.pos_m[0], start)


def test_a_braking_reference_stops_along_the_velocity_and_holds():
    from planners.timing import braking_reference

    ref = braking_reference(np.array([1.0, 2.0, 3.0]), np.array([3.0, 4.0, 0.0]), 2.5)
    assert ref.duration_s == pytest.approx(2.0)
    p_end, v_end, _ = ref.sample(10.0)
    assert np.allclose(p_end, [1.0 + 0.6 * 5.0, 2.0 + 0.8 * 5.0, 3.0])  # v² / 2a = 5 m along (0.6, 0.8, 0)
    assert np.allclose(v_end, 0.0)
    p_1, v_1, _ = ref.sample(1.0)
    assert np.allclose(v_1, [1.5, 2.0, 0.0]) and np.allclose(p_1, [1.0 + 0.6 * 3.75, 2.0 + 0.8 * 3.75, 3.0])
    at_rest = braking_reference(np.zeros(3), np.zeros(3), 1.0)
    assert at_rest.duration_s == 0.0 and np.allclose(at_rest.sample(1.0)[0], 0.0)
    with pytest.raises(ValueError, match="decel_m_s2"):
        braking_reference(np.zeros(3), np.ones(3), 0.0)


def test_a_descent_stops_on_the_floor_not_below_it():
    """A stop whose straight line would end below the floor slows its descent harder, to rest on the floor, while the
    horizontal speed slows as before; already below the floor the descent stops at once."""
    from planners.timing import braking_reference

    p0, v0 = np.array([0.0, 0.0, 15.0]), np.array([3.0, 0.0, -8.0])
    free = braking_reference(p0, v0, 4.0)
    assert free.sample(100.0)[0][2] < 10.0  # 9.1 m along the velocity: below a floor at 10 m
    held = braking_reference(p0, v0, 4.0, floor_z_m=10.0)
    assert held.pos_m[:, 2].min() == pytest.approx(10.0) and held.sample(100.0)[0][2] == pytest.approx(10.0)
    assert np.allclose(held.sample(100.0)[0][0:2], free.sample(100.0)[0][0:2])  # the horizontal stop unchanged
    assert held.duration_s == pytest.approx(free.duration_s)
    assert np.allclose(held.sample(100.0)[1], 0.0) and np.all(np.diff(held.pos_m[:, 2]) <= 1e-12)
    assert held.acc_m_s2[0][2] == pytest.approx(64.0 / 10.0)  # v_z² / 2 (z - floor)
    high = braking_reference(p0, v0, 4.0, floor_z_m=0.0)  # far above the floor: the straight stop
    assert np.allclose(high.pos_m, free.pos_m) and np.allclose(high.vel_m_s, free.vel_m_s)
    below = braking_reference(np.array([0.0, 0.0, 8.0]), v0, 4.0, floor_z_m=10.0)
    assert np.all(below.pos_m[:, 2] == 8.0) and np.all(below.vel_m_s[1:, 2] == 0.0)
    climbing = braking_reference(p0, -v0, 4.0, floor_z_m=20.0)  # moving up: the floor does not bind
    assert np.allclose(climbing.pos_m, braking_reference(p0, -v0, 4.0).pos_m)


def test_then_straight_moves_rest_to_rest_within_the_limits():
    from planners.timing import braking_reference, then_straight

    brake = braking_reference(np.array([0.0, 0.0, 10.0]), np.array([2.0, 0.0, 0.0]), 2.0)
    up = then_straight(brake, brake.pos_m[-1] + (0.0, 0.0, 12.0), 2.0, 1.0)
    # a trapezoid: 2 s to 2 m/s (2 m), 8 m at 2 m/s (4 s), 2 s to rest (2 m)
    assert up.duration_s == pytest.approx(brake.duration_s + 8.0)
    assert np.allclose(up.sample(brake.duration_s)[0], brake.pos_m[-1])  # continuous at the join
    end, v_end, _ = up.sample(100.0)
    assert np.allclose(end, brake.pos_m[-1] + (0.0, 0.0, 12.0)) and np.allclose(v_end, 0.0)
    assert np.abs(up.vel_m_s[:, 2]).max() == pytest.approx(2.0)
    assert np.all(np.diff(up.t_s) > 0.0) and up.length_m == pytest.approx(brake.length_m + 12.0)
    short = then_straight(brake, brake.pos_m[-1] + (0.0, 0.0, 1.0), 2.0, 1.0)  # a triangle: 1 s up, 1 s down
    assert short.duration_s == pytest.approx(brake.duration_s + 2.0)
    assert np.abs(short.vel_m_s[:, 2]).max() == pytest.approx(1.0, abs=0.03)
    assert then_straight(brake, brake.pos_m[-1], 2.0, 1.0) is brake
    with pytest.raises(ValueError, match="max_speed_m_s"):
        then_straight(brake, np.zeros(3), 0.0, 1.0)


def test_braking_along_a_curve_stays_on_it_and_stops():
    """The stop while a replan runs follows the flown curve (an L-turn here), slowing at the given rate from the
    reference's speed at that time, and holds at rest; a stop past the curve's end holds at the end."""
    from planners.timing import Reference, braking_along

    t = np.linspace(0.0, 20.0, 201)
    corner = np.clip(t * 2.0, 0.0, 20.0)  # 2 m/s: 10 s along +x to (20, 0), then 10 s along +y
    pos = np.column_stack([corner, np.clip(t * 2.0 - 20.0, 0.0, 20.0), np.full_like(t, 10.0)])
    vel = np.gradient(pos, t, axis=0)
    ref = Reference(t_s=t, pos_m=pos, vel_m_s=vel, acc_m_s2=np.zeros_like(pos), duration_s=20.0, status="ok",
                    length_m=40.0, min_clearance_m=5.0, required_clearance_m=1.0, refinements=0, stops=0)
    brake = braking_along(ref, 9.5, 1.0)  # 1 m before the corner at 2 m/s: stops 2 m on, 1 m past the corner
    assert brake.duration_s == pytest.approx(2.0)
    end, v_end, _ = brake.sample(brake.duration_s + 1.0)
    assert np.allclose(end, [20.0, 1.0, 10.0], atol=1e-6) and np.allclose(v_end, 0.0)
    # every point on the curve (x = 20 or y = 0), never cutting the corner
    p = np.asarray(brake.pos_m)
    assert np.all(np.minimum(np.abs(p[:, 0] - 20.0), np.abs(p[:, 1])) < 1e-9)
    assert float(np.linalg.norm(brake.sample(0.0)[1])) == pytest.approx(2.0, rel=1e-6)
    late = braking_along(ref, 19.8, 0.5)  # 0.4 m from the end at 2 m/s: held at the end
    assert np.allclose(late.sample(100.0)[0], [20.0, 20.0, 10.0])
