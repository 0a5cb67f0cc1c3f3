"""Flying on what the vehicle senses: the truth (the city as it stands, the true state) never reaches a pilot, the
pilot gets the filter's estimate and the readings old by the latency, the controller flies on the estimate, one
seed gives the same flight, and the estimation and unmapped-obstacle metrics come from the flight."""
from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compare.flying import pilots
from compare.flying.episode_loop import Trajectory, run_episode
from compare.results.metrics import episode_metrics
from compare.results.trajectory import SavedEpisode
from compare.run.cells import Cell, CellRunner
from compare.scenarios.scenario import Scenario, scenario_from_dict
from run_data import TINY
from uam_fdm.air.wind import WindField
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.files.yamlfile import load_yaml_file
from uam_fdm.pilot import Observation, Pilot, ResetInfo, Task, VelocityCommand, World

UNMAPPED = {"center": [75.0, 20.0], "size": [10.0, 10.0], "height": 40.0}  # south of the leg, not across it


def _scenario(**keys: Any) -> Scenario:
    data = copy.deepcopy(load_yaml_file(TINY))
    data.update(name="sensed", timeout_s=4.0, **keys)
    return scenario_from_dict(data, str(TINY), TINY.parent)


def _runner(sc: Scenario, tmp_path: Path) -> CellRunner:
    return CellRunner([sc], tmp_path, {})


class Spy:
    """A pilot that flies straight at the goal on what it is given and keeps every observation."""

    name = "spy"

    def __init__(self) -> None:
        self.world: World | None = None
        self.task: Task | None = None
        self.seen: list[Observation] = []

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        self.world, self.task, self.seen = world, task, []
        return ResetInfo(True)

    def act(self, obs: Observation) -> VelocityCommand:
        self.seen.append(obs)
        assert self.task is not None
        to_goal = np.asarray(self.task.goal_m) - obs.x[0:3]
        return VelocityCommand(2.0 * to_goal / max(1.0, float(np.linalg.norm(to_goal))))

    def episode_report(self) -> None:
        return None


def _fly(sc: Scenario, tmp_path: Path, pilot: Pilot, seed: int = 0) -> tuple[Trajectory, CellRunner]:
    runner = _runner(sc, tmp_path)
    ep = sc.episodes[0]
    wind = WindField.calm()
    return run_episode(runner.world(0), pilot, ep.task, wind, 0, truth=runner.truth(0, seed)), runner


def _reachable(*roots: object) -> list[object]:
    """Every object reachable from `roots` through attributes, dataclass fields and containers."""
    seen: dict[int, object] = {}
    stack = list(roots)
    while stack:
        o = stack.pop()
        if id(o) in seen or isinstance(o, (str, bytes, int, float, bool, type(None))):
            continue
        seen[id(o)] = o
        if isinstance(o, dict):
            stack += list(o.keys()) + list(o.values())
        elif isinstance(o, (list, tuple, set, frozenset)):
            stack += list(o)
        elif isinstance(o, np.ndarray):
            continue
        else:
            if dataclasses.is_dataclass(o):
                stack += [getattr(o, f.name) for f in dataclasses.fields(o)]
            stack += list(getattr(o, "__dict__", {}).values())
    return list(seen.values())


def test_no_truth_reaches_a_pilot(tmp_path):
    """With a wrong map, an unmapped building and nominal sensing, nothing a pilot is given holds the true city,
    the map of what the prior lacks, or the true state."""
    sc = _scenario(unmapped=[UNMAPPED], map_error="outdated", sensing="nominal")
    assert sc.prior_map is not sc.city and sc.unmapped_ids
    spy = Spy()
    traj, runner = _fly(sc, tmp_path, spy)
    truth = runner.truth(0, 0)
    assert len(spy.seen) > 50
    given = _reachable(spy.world, spy.task, *spy.seen)
    maps = [o for o in given if isinstance(o, BuildingMap)]
    assert maps and all(m is not sc.city and m is not truth.unmapped for m in maps)
    assert all(set(sc.unmapped_ids).isdisjoint(int(i) for i in m.building_ids) for m in maps)
    # the pilot's states are estimates: never the truth at the decision's time
    rows = {round(t, 9): i for i, t in enumerate(traj.t_s)}
    for obs in spy.seen:
        true = traj.states[rows[round(obs.t_s, 9)]]
        assert not np.allclose(obs.x[0:6], true[0:6], atol=1e-6)
        assert obs.covariance is not None and obs.covariance.shape == (16, 16)
    errors = np.array([np.linalg.norm(o.x[0:3] - traj.states[rows[round(o.t_s, 9)], 0:3]) for o in spy.seen])
    assert 0.0 < np.median(errors) < 5.0  # an estimate, and a good one on an open sky


def test_perfect_sensing_hands_the_truth_through(tmp_path):
    sc = _scenario()
    assert sc.prior_map is sc.city and sc.sensing.perfect
    spy = Spy()
    traj, _ = _fly(sc, tmp_path, spy)
    assert traj.nav is None and traj.estimate_m is None
    rows = {round(t, 9): i for i, t in enumerate(traj.t_s)}
    for obs in spy.seen:
        assert np.array_equal(obs.x, traj.states[rows[round(obs.t_s, 9)]])
        assert obs.covariance is None and obs.sensors.lidar == () and obs.sensors.gnss == ()


def test_readings_arrive_as_old_as_the_latency_and_once(tmp_path):
    sc = _scenario(sensing={"preset": "degraded", "latency_s": 0.1})
    spy = Spy()
    _fly(sc, tmp_path, spy)
    scans = [(o.t_s, s.t_s) for o in spy.seen for s in o.sensors.lidar]
    fixes = [(o.t_s, f.t_s) for o in spy.seen for f in o.sensors.gnss]
    assert len(scans) >= 30 and len(fixes) >= 30  # 10 Hz over ~4 s
    assert all(t_obs - t_read >= 0.1 - 1e-9 for t_obs, t_read in scans + fixes)
    assert len({t for _, t in scans}) == len(scans)  # each scan handed over once
    scan = spy.seen[-1].sensors.lidar or next(s for o in spy.seen for s in o.sensors.lidar)
    assert scan.ranges_m.shape[0] == scan.directions_body.shape[0] > 0


def test_one_seed_one_flight_and_another_seed_another(tmp_path):
    sc = _scenario(sensing="degraded")
    a, _ = _fly(sc, tmp_path, Spy(), seed=7)
    b, _ = _fly(sc, tmp_path, Spy(), seed=7)
    c, _ = _fly(sc, tmp_path, Spy(), seed=8)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.estimate_m, b.estimate_m)
    assert a.nav is not None and b.nav is not None and np.array_equal(a.nav.error_m, b.nav.error_m)
    assert not np.array_equal(a.estimate_m, c.estimate_m)


def test_the_controller_flies_on_the_estimate(tmp_path):
    """The same commands flown on the truth and on a biased estimate fly differently: the velocity controller acts
    on what the filter says, not on the true state."""
    sc = _scenario()
    world = _runner(sc, tmp_path).world(0)
    dyn = world.dynamics
    from uam_fdm.vehicle.model import hover_state

    x = hover_state(sc.vehicle, np.array([20.0, 40.0, 10.0]), 0.0)
    env = np.array([0.0, 0.0, 0.0, 1.0, 10.0])
    cmd = np.array([1.0, 0.0, 0.0, 0.0])
    none = np.r_[np.zeros(6), 1.0, np.zeros(6)]
    on_truth = dyn.period_velocity(x, np.zeros(3), cmd, env)
    on_exact = dyn.period_velocity_seen(x, np.zeros(3), cmd, env, none)
    assert np.array_equal(on_truth.states, on_exact.states)
    fast = none.copy()
    fast[3] = 1.0  # the estimate says 1 m/s east faster than the truth: the controller holds back
    on_biased = dyn.period_velocity_seen(x, np.zeros(3), cmd, env, fast)
    assert on_biased.states[-1, 3] < on_truth.states[-1, 3] - 1e-4


def test_metrics_score_estimation_and_the_unmapped(tmp_path):
    sc = _scenario(unmapped=[UNMAPPED], sensing="nominal")
    pilot = pilots.build("apf", pilots.BuildRequest(sc.vehicle, sc.vehicle_name, sc.source))
    runner = _runner(sc, tmp_path)
    meta, traj = runner.fly(Cell(0, 0, 0, "apf"))
    m = episode_metrics(SavedEpisode(meta, traj))
    assert (m.sensing, m.map_error) == ("nominal", "exact")
    assert traj.nav is not None and traj.unmapped_clearance_m is not None
    h = np.hypot(traj.nav.error_m[:, 0], traj.nav.error_m[:, 1])
    assert m.est_error_h_rms_m == pytest.approx(math.sqrt(np.mean(h ** 2))) and 0.0 < m.est_error_h_rms_m < 5.0
    assert m.est_error_h_max_m == pytest.approx(h.max()) and m.gnss_availability == 1.0
    nav = traj.nav
    inside = (nav.nees >= 0.2158) & (nav.nees <= 9.3484)
    assert m.est_nees_in_bounds == pytest.approx(inside.mean()) and len(nav.nees) == len(nav.t_s)
    # with a diagonal-dominant covariance the NEES is about the squared errors over the variances
    assert np.all(nav.nees >= 0.0) and np.median(nav.nees) > np.median((nav.error_m / nav.sigma_m) ** 2) * 0.3
    # clearance to the unmapped building alone: the distance to its box, less the collision radius
    pos = traj.states[:, 0:3]
    lo, hi = np.array([70.0, 15.0, 0.0]), np.array([80.0, 25.0, 40.0])
    d = np.linalg.norm(np.maximum(np.maximum(lo - pos, pos - hi), 0.0), axis=1) - sc.vehicle.collision_radius_m
    assert m.min_clearance_unmapped_m == pytest.approx(d.min(), abs=1e-6)
    assert pilot.name == "apf"


IN_VIEW = {"center": [30.0, 70.0], "size": [6.0, 6.0], "height": 30.0}  # a mast-like block in the open, north-west


def test_the_lidar_records_how_far_off_an_unmapped_obstacle_was_first_sensed(tmp_path):
    sc = _scenario(unmapped=[IN_VIEW], sensing="nominal")
    (bid,) = sc.unmapped_ids
    meta, traj = _runner(sc, tmp_path).fly(Cell(0, 0, 0, "apf"))
    m = episode_metrics(SavedEpisode(meta, traj))
    assert traj.nav is not None
    ((sensed_id, t_s, range_m),) = traj.nav.first_sensed
    assert sensed_id == bid and 0.0 < t_s <= traj.t_s[-1]
    assert (m.unmapped_sensed, m.unmapped_first_sensed_m_min, m.unmapped_first_sensed_m_median) == (1.0, range_m,
                                                                                                    range_m)
    assert range_m <= sc.sensing.lidar.max_range_m and range_m >= m.min_clearance_unmapped_m
    # a beam's range to the block is at least the straight distance from the vehicle to it at that scan
    lo, hi = np.array([27.0, 67.0, 0.0]), np.array([33.0, 73.0, 30.0])
    pos = traj.states[int(np.argmin(np.abs(traj.t_s - t_s))), 0:3]
    straight = float(np.linalg.norm(np.maximum(np.maximum(lo - pos, pos - hi), 0.0)))
    assert straight - 1e-3 <= range_m <= straight + 0.5  # the nearest beam: within half a beam spacing of it


def test_nothing_is_sensed_at_perfect_sensing(tmp_path):
    sc = _scenario(unmapped=[IN_VIEW])
    meta, traj = _runner(sc, tmp_path).fly(Cell(0, 0, 0, "apf"))
    m = episode_metrics(SavedEpisode(meta, traj))
    assert traj.nav is None and math.isfinite(m.min_clearance_unmapped_m)
    assert math.isnan(m.unmapped_sensed) and math.isnan(m.unmapped_first_sensed_m_min)
    assert math.isnan(m.unmapped_first_sensed_m_median)
