"""The OMPL planner: paths around walls and through gaps, exact collision freedom, determinism, statuses."""
from __future__ import annotations

import hashlib
import itertools
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from planners.rrt_star import ALGORITHMS, PlannerConfig, densify, plan_path
from uam_fdm.city.buildings import Building, BuildingMap

R_QUAD = 0.42  # small_quad collision radius [m]
MARGIN = 1.0
FAST = PlannerConfig(max_iterations=1500)  # small maps need far less than the default budget


def wall_map() -> BuildingMap:
    """A 0.2 m thin wall taller than the ceiling across y in [0, 80] at x = 50: go around its north end."""
    return BuildingMap([Building(0, (50.0, 40.0), (0.2, 80.0), 60.0)], (0, 0, 0), (100, 100, 40))


def gap_map() -> BuildingMap:
    """Two walls at x = 50 leaving a 10 m gap at y in [45, 55]."""
    return BuildingMap([Building(0, (50.0, 22.5), (2.0, 45.0), 60.0), Building(1, (50.0, 77.5), (2.0, 45.0), 60.0)],
                       (0, 0, 0), (100, 100, 40))


def enclosed_map() -> BuildingMap:
    """A closed courtyard (walls taller than the ceiling) around (75, 50)."""
    walls = [Building(0, (75.0, 30.0), (32.0, 1.0), 60.0), Building(1, (75.0, 70.0), (32.0, 1.0), 60.0),
             Building(2, (60.0, 50.0), (1.0, 40.0), 60.0), Building(3, (90.0, 50.0), (1.0, 40.0), 60.0)]
    return BuildingMap(walls, (0, 0, 0), (100, 100, 40))


def crossings_at_x(path: np.ndarray, x: float) -> np.ndarray:
    """(y, z) where the polyline crosses the plane at x."""
    out = []
    for a, b in itertools.pairwise(path):
        if (a[0] - x) * (b[0] - x) < 0:
            t = (x - a[0]) / (b[0] - a[0])
            out.append((a + t * (b - a))[1:])
    return np.array(out)


def assert_clear(city: BuildingMap, path: np.ndarray, required_m: float) -> None:
    """Clearance of the vehicle sphere >= required everywhere, sampled every 5 cm (FCL backend)."""
    pts = densify(path, 0.05)
    d = city.clearance(pts, R_QUAD, backend="fcl").distance_m
    assert np.min(d) >= required_m - 1e-9, f"clearance {np.min(d):.4f} m < {required_m} m"


def test_goes_around_a_thin_wall_without_tunnelling():
    city = wall_map()
    r = plan_path(city, (20, 40, 10), (80, 40, 10), R_QUAD, FAST, seed=1)
    assert r.ok, r.message
    assert_clear(city, r.path_m, MARGIN)
    cross = crossings_at_x(r.path_m, 50.0)
    assert len(cross) >= 1 and np.all(cross[:, 0] > 80.0 + R_QUAD + MARGIN - 1e-9)  # around the north end
    assert np.array_equal(r.path_m[0], [20, 40, 10]) and np.array_equal(r.path_m[-1], [80, 40, 10])
    assert r.length_m > 2 * math.hypot(30, 40) - 1e-6  # at least the taut path around the end
    assert r.min_clearance_m >= MARGIN


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_every_algorithm_goes_through_the_gap(algorithm):
    city = gap_map()
    cfg = PlannerConfig(algorithm=algorithm, max_iterations=1500 if algorithm != "bitstar" else 4000)
    r = plan_path(city, (20, 50, 10), (80, 50, 10), R_QUAD, cfg, seed=3)
    assert r.ok, r.message
    assert_clear(city, r.path_m, MARGIN)
    cross = crossings_at_x(r.path_m, 50.0)
    assert len(cross) == 1 and 45 + R_QUAD + MARGIN < cross[0, 0] < 55 - R_QUAD - MARGIN
    assert 0 < r.first_solution_time_s <= r.solve_time_s <= r.plan_time_s
    assert 1 <= r.first_solution_iterations <= r.iterations
    assert r.first_solution_length_m >= r.length_m - 1e-9  # simplification never lengthens
    # OMPL's clearance (the validity checker's hook, at OMPL's waypoints) is the vehicle sphere's.
    ompl_states = r.path_m[:-1] if r.extra["goal_appended"] else r.path_m
    expected = min(city.clearance_one(*p, R_QUAD) for p in ompl_states)
    assert r.ompl_clearance_m == pytest.approx(expected, abs=1e-9)
    assert r.ompl_clearance_m >= r.min_clearance_m - 1e-9


def test_climb_weight_trades_a_climb_for_a_detour():
    """A 20 m high block across the way, 70 m wide: over it is shorter (about 87 m against 109 m around its end),
    but a climb is slow. With climb_weight 4 (the small quad's 9.6 over 2.4 m/s) the cost of going over is about
    158 m, and the planner goes round; with 1 it goes over. Both paths are clear and end at the goal."""
    city = BuildingMap([Building(0, (50.0, 50.0), (10.0, 70.0), 20.0)], (0, 0, 0), (100, 100, 60))
    start, goal = (10.0, 50.0, 5.0), (90.0, 50.0, 5.0)
    over = plan_path(city, start, goal, R_QUAD, PlannerConfig(), seed=1)
    around = plan_path(city, start, goal, R_QUAD, PlannerConfig(climb_weight=4.0), seed=1)
    assert over.ok and around.ok
    assert over.path_m[:, 2].max() > 20.0 and over.length_m < 100.0
    assert around.path_m[:, 2].max() < 20.0 and np.abs(around.path_m[:, 1] - 50.0).max() > 35.0
    for plan in (over, around):
        assert_clear(city, plan.path_m, MARGIN)
        np.testing.assert_allclose(plan.path_m[-1], goal)
    with pytest.raises(ValueError, match="climb_weight"):
        PlannerConfig(climb_weight=0.0)


def test_random_queries_on_a_generated_city_are_collision_free():
    from uam_fdm.city.generator import CityGenConfig, generate_city

    city = generate_city(CityGenConfig(extent_m=(300.0, 300.0), ceiling_m=80.0, margin_m=20.0, block_size_m=(50, 40),
                                       street_width_m=12.0, height_median_m=40.0, height_range_m=(20.0, 100.0)), 5)
    rng = np.random.default_rng(0)
    done = 0
    while done < 4:
        p, q = (np.r_[rng.uniform(10, 290, 2), rng.uniform(5, 30)] for _ in range(2))
        if min(city.clearance_one(*p, 2.0), city.clearance_one(*q, 2.0)) <= 0:
            continue
        r = plan_path(city, p, q, R_QUAD, PlannerConfig(max_iterations=2000), seed=done)
        assert r.status in ("exact", "approximate", "no_solution")
        if r.ok:
            assert_clear(city, r.path_m, MARGIN)
            assert r.min_clearance_m >= MARGIN
        done += 1


def _digest(r) -> str:
    return hashlib.sha256(np.ascontiguousarray(r.path_m).tobytes()).hexdigest()


def test_same_seed_same_path_different_seed_different_path():
    city = gap_map()
    cfg = PlannerConfig(algorithm="rrtstar", max_iterations=800, simplify=False)
    a = plan_path(city, (20, 20, 10), (80, 80, 30), R_QUAD, cfg, seed=11)
    others = [plan_path(city, (20, 20, 10), (80, 80, 30), R_QUAD, cfg, seed=s) for s in (12, 13)]
    b = plan_path(city, (20, 20, 10), (80, 80, 30), R_QUAD, cfg, seed=11)  # after other seeds in this process
    assert a.ok and b.ok
    assert np.array_equal(a.path_m, b.path_m) and a.iterations == b.iterations
    assert any(not np.array_equal(a.path_m, o.path_m) for o in others)


def test_same_seed_same_path_in_a_fresh_process():
    city = gap_map()
    cfg = PlannerConfig(max_iterations=800)
    here = _digest(plan_path(city, (20, 20, 10), (80, 80, 30), R_QUAD, cfg, seed=5))
    code = textwrap.dedent("""
        import hashlib, numpy as np
        from planners.rrt_star import PlannerConfig, plan_path
        from uam_fdm.city.buildings import Building, BuildingMap
        city = BuildingMap([Building(0, (50.0, 22.5), (2.0, 45.0), 60.0), Building(1, (50.0, 77.5), (2.0, 45.0), 60.0)],
                           (0, 0, 0), (100, 100, 40))
        r = plan_path(city, (20, 20, 10), (80, 80, 30), 0.42, PlannerConfig(max_iterations=800), seed=5)
        print(hashlib.sha256(np.ascontiguousarray(r.path_m).tobytes()).hexdigest())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == here
    assert "leaked" not in out.stderr  # OMPL objects never outlive plan_path


@pytest.mark.parametrize("start, goal, status", [
    ((50.0, 40.0, 10.0), (80.0, 40.0, 10.0), "invalid_start"),   # inside the wall
    ((-5.0, 40.0, 10.0), (80.0, 40.0, 10.0), "invalid_start"),   # out of bounds
    ((20.0, 40.0, 0.2), (80.0, 40.0, 10.0), "invalid_start"),    # sphere through the ground
    ((20.0, 40.0, 10.0), (80.0, 40.0, 39.9), "invalid_goal"),    # sphere through the ceiling
])
def test_invalid_endpoints_are_statuses(start, goal, status):
    r = plan_path(wall_map(), start, goal, R_QUAD, FAST, seed=0)
    assert r.status == status and not r.ok
    assert r.path_m.shape == (0, 3) and math.isnan(r.length_m) and r.message


def test_unreachable_goal_and_wall_cap_are_statuses():
    city = enclosed_map()
    r = plan_path(city, (20, 50, 10), (75, 50, 10), R_QUAD, PlannerConfig(max_iterations=500), seed=0)
    assert r.status in ("approximate", "no_solution") and not r.ok and r.iterations == 501
    capped = plan_path(city, (20, 50, 10), (75, 50, 10), R_QUAD,
                       PlannerConfig(max_iterations=10**9, time_budget_s=0.2), seed=0)
    assert capped.status == "timeout" and capped.wall_cap_hit and not capped.ok


def test_an_iteration_budget_plans_the_same_on_a_slower_machine(monkeypatch):
    """The wall-time cap is a safety net: a machine three times slower than this one (a clock that runs on 3 ms per
    termination poll, so the in-flight budget "takes" over 9 s) plans the same path, uncut."""
    import types

    import planners.rrt_star as rrt_star_module
    from planners.ladder import IN_FLIGHT_ITERATIONS

    config = PlannerConfig(max_iterations=IN_FLIGHT_ITERATIONS)
    here = plan_path(gap_map(), (20, 50, 10), (80, 50, 10), R_QUAD, config, seed=4)
    ticks = itertools.count()
    slow = types.SimpleNamespace(perf_counter=lambda: 0.003 * next(ticks))
    monkeypatch.setattr(rrt_star_module, "time", slow)
    there = plan_path(gap_map(), (20, 50, 10), (80, 50, 10), R_QUAD, config, seed=4)
    assert next(ticks) > 3000 and not there.wall_cap_hit  # over 9 s of its clock
    assert here.ok and there.status == here.status and there.iterations == here.iterations
    np.testing.assert_array_equal(there.path_m, here.path_m)


def test_a_plan_from_the_goal_itself_is_the_straight_piece_to_it():
    """A replan from where the vehicle holds on its goal: InformedRRT*'s sampler raised on coinciding foci and ended
    the validation cell quad-003/8 with an error; within the goal tolerance the path is the straight piece."""
    goal = (20.0, 50.0, 10.0)
    for start in (goal, (20.3, 50.0, 10.0)):
        r = plan_path(gap_map(), start, goal, R_QUAD, PlannerConfig(max_iterations=2000), seed=0)
        assert r.ok and r.iterations == 0 and np.array_equal(r.path_m[-1], goal) and r.length_m < 0.31


def test_start_inside_the_margin_is_relaxed_not_rejected():
    city = wall_map()
    start = (50.0 + 0.1 + R_QUAD + 0.4, 40.0, 10.0)  # 0.4 m from the wall: collision-free, inside the 1 m margin
    r = plan_path(city, start, (80, 40, 10), R_QUAD, FAST, seed=0)
    assert r.ok, r.message
    assert r.min_clearance_m >= 0.4 - 0.05 - 1e-9  # never closer than the start itself (less 5 cm)
    far = densify(r.path_m, 0.05)
    far = far[np.linalg.norm(far - np.array(start), axis=1) > 2 * (R_QUAD + MARGIN)]
    assert np.min(city.clearance(far, R_QUAD).distance_m) >= MARGIN - 1e-9  # the full margin further out


def test_time_budget_mode_and_bad_arguments():
    r = plan_path(gap_map(), (20, 50, 10), (80, 50, 10), R_QUAD,
                  PlannerConfig(max_iterations=None, time_budget_s=1.0), seed=0)
    assert r.ok and not r.wall_cap_hit, r.message  # 1 s: enough on a loaded machine (0.1 s was not)
    with pytest.raises(ValueError):
        PlannerConfig(algorithm="aorrtc")
    with pytest.raises(ValueError):
        PlannerConfig(max_iterations=-1)
    with pytest.raises(ValueError):
        PlannerConfig(safety_margin_m=-0.1)
    with pytest.raises(ValueError):
        plan_path(gap_map(), (20, 50, math.nan), (80, 50, 10), R_QUAD, FAST)
    with pytest.raises(ValueError):
        plan_path(gap_map(), (20, 50, 10), (80, 50, 10), R_QUAD, FAST, seed=-1)
    with pytest.raises(ValueError):
        plan_path(gap_map(), (20, 50, 10), (80, 50, 10), 30.0, FAST)  # no room in the bounds
