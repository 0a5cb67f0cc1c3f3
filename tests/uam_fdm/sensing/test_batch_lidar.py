"""BatchOnboard's lidar: per slot, the scans `Onboard` hands a decision (directions, ranges, times) bit for bit, for the
same seed, true states and true world (four slots in three worlds, reset at different times on their own clocks,
one leaving early; a reduced spec and the level's full one), independent of the other slots and of N; handed-over
scans are dropped; without lidar casters nothing changes."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.city.buildings import Building, BuildingMap, Prism
from uam_fdm.sensing.batch_lidar import CAST_RAYS
from uam_fdm.sensing.batch_onboard import BatchOnboard
from uam_fdm.sensing.lidar import LidarScan
from uam_fdm.sensing.onboard import Onboard
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import SensingConfig, sensing_preset

BOUNDS = ([0.0, 0.0, 0.0], [200.0, 200.0, 300.0])
STREET = BuildingMap([Building(0, (40.0, 100.0), (20.0, 200.0), 40.0),
                      Building(1, (90.0, 100.0), (20.0, 200.0), 40.0)], *BOUNDS)
OPEN = BuildingMap([Building(0, (170.0, 170.0), (20.0, 20.0), 30.0)], *BOUNDS)
# a yawed tower, a convex prism and a crane jib in the air (rays from below hit its underside)
YARD = BuildingMap([Building(0, (100.0, 30.0), (15.0, 25.0), 35.0, yaw_rad=0.4),
                    Prism(1, ((40.0, 50.0), (52.0, 48.0), (55.0, 60.0), (45.0, 66.0)), 22.0),
                    Building(2, (75.0, 70.0), (40.0, 2.0), 17.0, base_m=15.0)], *BOUNDS)
WORLDS = (STREET, OPEN, YARD)
DT_S, STEPS = 0.002, 10  # 500 Hz physics, 50 Hz control
PERIODS = 150  # 3 s: 30 scans at 10 Hz
ROTORS = 4


@dataclasses.dataclass(frozen=True)
class Flight:
    """A flown leg: the true initial state and, per control period, (state at its start, substep states, t_s)."""

    x0: np.ndarray
    periods: tuple[tuple[np.ndarray, np.ndarray, float], ...]


def _quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    """Z-Y-X Euler angles [rad] as a unit quaternion [w, x, y, z], body FLU -> world ENU."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def _state(t: float, start: tuple[float, float, float], yaw0: float, speed_m_s: float) -> np.ndarray:
    """A weaving climb north at `speed_m_s`, turning and rocking (kinematic: the lidar needs only the pose)."""
    x = np.zeros(13 + ROTORS)
    x[0:3] = [start[0] + 3.0 * math.sin(0.8 * t), start[1] + speed_m_s * t, start[2] + 0.5 * t]
    x[3:6] = [2.4 * math.cos(0.8 * t), speed_m_s, 0.5]
    roll, pitch, yaw = 0.15 * math.sin(2.0 * t), 0.1 * math.cos(1.5 * t), yaw0 + 0.4 * t
    x[6:10] = _quaternion(roll, pitch, yaw)
    x[10:13] = [0.3 * math.cos(2.0 * t), -0.15 * math.sin(1.5 * t), 0.4]
    x[13:] = 800.0
    return x


def _flight(start: tuple[float, float, float], yaw0: float, speed_m_s: float, t0_s: float = 0.0) -> Flight:
    """PERIODS control periods from `t0_s` on the slot's clock [s]."""
    periods = []
    for k in range(PERIODS):
        t = t0_s + k * STEPS * DT_S
        states = np.stack([_state(t - t0_s + (j + 1) * DT_S, start, yaw0, speed_m_s) for j in range(STEPS)])
        periods.append((_state(t - t0_s, start, yaw0, speed_m_s), states, t))
    return Flight(_state(0.0, start, yaw0, speed_m_s), tuple(periods))


@pytest.fixture(scope="module")
def casters() -> list[RayCaster]:
    return [RayCaster(c) for c in WORLDS]


def _level(level: str, spec: str) -> SensingConfig:
    """A small quad's sensing level with its lidar as shipped ("full") or reduced to 8 channels x 10 degrees."""
    cfg = sensing_preset(level, 1.5)
    if spec == "reduced":
        reduced = dataclasses.replace(cfg.lidar, channels=8, horizontal_resolution_deg=10.0)
        return dataclasses.replace(cfg, lidar=reduced)
    return cfg


def _assert_scans_equal(got: tuple[LidarScan, ...], expected: tuple[LidarScan, ...]) -> None:
    assert [s.t_s for s in got] == [s.t_s for s in expected]
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a.directions_body, b.directions_body)
        np.testing.assert_array_equal(a.ranges_m, b.ranges_m)
        assert a.ranges_m.dtype == b.ranges_m.dtype and not a.ranges_m.flags.writeable
        # stamped alike with the vehicle's own pose estimate at the scan
        assert a.pose_estimate is not None and b.pose_estimate is not None
        np.testing.assert_array_equal(a.pose_estimate, b.pose_estimate)


def _onboard(cfg: SensingConfig, world: int, casters: list[RayCaster], atmosphere: Atmosphere, flight: Flight,
             seed: int) -> Onboard:
    return Onboard(cfg, WORLDS[world], casters[world], atmosphere, flight.x0, DT_S, seed, flight.periods[0][2])


@pytest.mark.parametrize("level,spec", [("nominal", "reduced"), ("degraded", "reduced"), ("degraded", "full")])
def test_four_slots_in_three_worlds_hand_over_onboards_scans(air, casters, level, spec):
    """Slots 0 and 3 fly the street from their clocks' 0 and 5 s (their scans are cast together); slot 1 the yard,
    then (at period 53) a new episode in the open city from its clock's 10.37 s; slot 2 starts at period 17 in the
    open city from 0.31 s and ends at period 120. Decisions come at irregular times, some after several scans, some
    exactly `latency_s` after a scan."""
    cfg = _level(level, spec)
    periods = PERIODS if spec == "reduced" else 40  # the full spec: 28,800 rays a scan
    legs = [_flight((62.0, 20.0, 8.0), 0.3, 4.0), _flight((60.0, 30.0, 6.0), -1.0, 2.5),
            _flight((70.0, 40.0, 5.0), 2.0, 3.0, t0_s=0.31), _flight((75.0, 25.0, 12.0), 1.2, 3.5, t0_s=5.0)]
    second = _flight((80.0, 60.0, 10.0), 0.7, 1.5, t0_s=10.37)
    batch = BatchOnboard(cfg, DT_S, 4, air, cities=WORLDS, casters=casters, lidar_casters=casters)
    batch.reset([0, 1, 3], [11, 12, 15], np.stack([legs[0].x0, legs[1].x0, legs[3].x0]), city=[0, 2, 0],
                field=[0, 1, 1], t0_s=[0.0, 0.0, 5.0])
    singles: list[Onboard | None] = [_onboard(cfg, 0, casters, air[0], legs[0], 11),
                                     _onboard(cfg, 2, casters, air[1], legs[1], 12), None,
                                     _onboard(cfg, 0, casters, air[1], legs[3], 15)]
    clock = [0, 0, 0, 0]
    rng = np.random.default_rng(3)
    scans, returns = 0, []
    for k in range(periods):
        if k == 17:
            batch.reset([2], [14], legs[2].x0[None], city=[1], field=[1], t0_s=legs[2].periods[0][2])
            singles[2] = _onboard(cfg, 1, casters, air[1], legs[2], 14)
        if k == 53:
            batch.reset([1], [13], second.x0[None], city=[1], field=[0], t0_s=second.periods[0][2])
            singles[1], legs[1], clock[1] = _onboard(cfg, 1, casters, air[0], second, 13), second, 0
        flying = [i for i in range(4) if singles[i] is not None and not (i == 2 and k >= 120)]
        deciding = [i for i in flying if rng.random() < 0.4]
        if deciding:  # at the period's start, or in the middle of a period already flown
            t_dec = np.array([legs[i].periods[clock[i]][2] - (0.01 if rng.random() < 0.3 else 0.0) for i in deciding])
            got = batch.lidar_scans(t_dec, deciding)
            for i, t, g in zip(deciding, t_dec.tolist(), got):
                single = singles[i]
                assert single is not None
                expected = single.observation(t).sensors.lidar
                _assert_scans_equal(g, expected)
                scans += len(g)
                returns += [len(s.ranges_m) for s in g]
        rows = [legs[i].periods[clock[i]] for i in flying]
        for i, row in zip(flying, rows):
            single = singles[i]
            assert single is not None
            single.advance(*row)
        batch.advance(np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows]), np.array([r[2] for r in rows]),
                      flying)
        for i in flying:
            clock[i] += 1
    assert scans >= (40 if spec == "reduced" else 10)
    rays = cfg.lidar.rays_per_scan
    assert 0 < min(returns) and max(returns) < rays  # beams hit, and some miss or drop out


def test_the_truth_index_picks_the_lidars_world(air, casters):
    """The lidar's worlds in another order than the GNSS cities: `truth` picks the lidar's (the street's scans
    are the street's whatever the city index says)."""
    cfg = _level("degraded", "reduced")
    leg = _flight((62.0, 20.0, 8.0), 0.3, 4.0)
    lidar_worlds = [casters[2], casters[0], casters[1]]
    batch = BatchOnboard(cfg, DT_S, 2, air, cities=WORLDS, casters=casters, lidar_casters=lidar_worlds)
    batch.reset([0, 1], [5, 5], np.stack([leg.x0, leg.x0]), city=[0, 0], truth=[1, 0])
    single = _onboard(cfg, 0, casters, air[0], leg, 5)
    for x_start, states, t_s in leg.periods[:60]:
        single.advance(x_start, states, t_s)
        batch.advance(np.stack([x_start] * 2), np.stack([states] * 2), t_s)
    t_end = leg.periods[59][2] + STEPS * DT_S
    street, yard = batch.lidar_scans(t_end)
    _assert_scans_equal(street, single.observation(t_end).sensors.lidar)
    assert len(street) == len(yard) == 12  # at 0.02 s, then every 0.1 s up to 1.2 s - 0.1 s of latency
    assert not all(np.array_equal(a.ranges_m, b.ranges_m) for a, b in zip(street, yard))


def test_a_slots_scans_depend_on_neither_its_neighbours_nor_n(air, casters):
    cfg = _level("degraded", "reduced")
    mine, theirs = _flight((62.0, 20.0, 8.0), 0.3, 4.0), _flight((60.0, 30.0, 6.0), -1.0, 2.5)

    def run(n: int, slot: int, seeds: list[int], worlds: list[int]) -> list[tuple[LidarScan, ...]]:
        batch = BatchOnboard(cfg, DT_S, n, air, cities=WORLDS, casters=casters, lidar_casters=casters)
        batch.reset(list(range(n)), seeds, np.stack([mine.x0 if i == slot else theirs.x0 for i in range(n)]),
                    city=worlds)
        out = []
        for (xa, sa, ta), (xb, sb, _) in zip(mine.periods[:100], theirs.periods[:100]):
            pick = [(xa, sa) if i == slot else (xb, sb) for i in range(n)]
            batch.advance(np.stack([p[0] for p in pick]), np.stack([p[1] for p in pick]), ta)
            out.append(batch.lidar_scans(ta + STEPS * DT_S, [slot])[0])
        return out

    alone = run(1, 0, [5], [2])
    among = run(5, 3, [1, 2, 3, 5, 4], [0, 2, 1, 2, 2])  # a neighbour in the same world: cast in one call
    other = run(5, 3, [9, 8, 7, 5, 6], [1, 1, 0, 2, 0])  # other seeds and worlds around it
    assert CAST_RAYS // cfg.lidar.rays_per_scan == 14
    crowd = run(17, 15, [100 + i if i != 15 else 5 for i in range(17)], [2] * 17)  # one world: cast 14 + 3 slots
    assert sum(len(s) for s in alone) == 20
    for x, y, z, c in zip(alone, among, other, crowd):
        assert len(x) == len(y) == len(z) == len(c)
        _assert_scans_equal(y, x)
        _assert_scans_equal(z, x)
        _assert_scans_equal(c, x)
    moved = run(1, 0, [6], [2])  # and the seed matters
    assert not all(np.array_equal(a.ranges_m, b.ranges_m) for s, t in zip(alone, moved) for a, b in zip(s, t))


def test_handed_over_scans_are_dropped_and_a_reset_drops_the_rest(air, casters):
    cfg = dataclasses.replace(_level("nominal", "reduced"), latency_s=0.1)  # a scan waits at each 10 Hz decision
    leg = _flight((62.0, 20.0, 8.0), 0.3, 4.0)
    batch = BatchOnboard(cfg, DT_S, 2, air, lidar_casters=casters)
    batch.reset([0, 1], [1, 2], np.stack([leg.x0, leg.x0]), truth=[0, 2])
    assert batch.lidar is not None
    scans = PERIODS // 5 + 1  # at the first period's end, then every 0.1 s
    taken: list[float] = []
    for k, (x_start, states, t_s) in enumerate(leg.periods):
        if k % 5 == 0:
            taken += [s.t_s for s in batch.lidar_scans(t_s, [0])[0]]
            assert batch.lidar.queued([0])[0] <= 2  # bounded: only the scans of the last 0.1 s are kept
        batch.advance(np.stack([x_start] * 2), np.stack([states] * 2), t_s)
    assert taken == sorted(set(taken)) and len(taken) == scans - 2  # each once; those at 2.9 s and 3 s wait
    assert batch.lidar.queued().tolist() == [2, scans]  # slot 1 asked for none: its queue holds them all
    assert len(batch.lidar_scans(99.0, [0])[0]) == 2 and batch.lidar.queued().tolist() == [0, scans]
    batch.reset([1], [2], leg.x0[None], truth=[2])
    assert batch.lidar.queued().tolist() == [0, 0] and batch.lidar_scans(99.0) == [(), ()]


@pytest.mark.parametrize("level", ["nominal", "degraded"])
def test_without_lidar_casters_nothing_changes(air, casters, level):
    """The same estimates, bit for bit, with and without the lidar (it draws from its own stream)."""
    cfg = _level(level, "reduced")
    legs = [_flight((62.0, 20.0, 8.0), 0.3, 4.0), _flight((60.0, 30.0, 6.0), -1.0, 2.5)]
    canyon = {"cities": WORLDS, "casters": casters}
    plain = BatchOnboard(cfg, DT_S, 2, air, **canyon)
    seeing = BatchOnboard(cfg, DT_S, 2, air, **canyon, lidar_casters=casters)
    assert plain.lidar is None and seeing.lidar is not None
    for b in (plain, seeing):
        b.reset([0, 1], [3, 4], np.stack([legs[0].x0, legs[1].x0]), city=[0, 2], field=[1, 0])
    for (xa, sa, ta), (xb, sb, _) in zip(legs[0].periods, legs[1].periods):
        x_start, states = np.stack([xa, xb]), np.stack([sa, sb])
        for b in (plain, seeing):
            b.advance(x_start, states, ta)
        e, f = plain.estimates(), seeing.estimates()
        np.testing.assert_array_equal(e.state, f.state)
        np.testing.assert_array_equal(e.position_covariance_m2, f.position_covariance_m2)
        np.testing.assert_array_equal(plain.controller_offset(x_start), seeing.controller_offset(x_start))
    assert sum(len(s.ranges_m) for s in seeing.lidar_scans(99.0)[0]) > 0
    with pytest.raises(ValueError, match="no lidar is simulated"):
        plain.lidar_scans(99.0)


def test_bad_lidar_inputs_are_refused_naming_what_was_wrong(air, casters):
    cfg = _level("nominal", "reduced")
    x0 = _flight((62.0, 20.0, 8.0), 0.3, 4.0).x0
    plain = BatchOnboard(cfg, DT_S, 2, air)
    with pytest.raises(ValueError, match="no lidar_casters"):
        plain.reset([0], [1], x0[None], truth=[0])
    batch = BatchOnboard(cfg, DT_S, 2, air, cities=WORLDS, casters=casters, lidar_casters=casters[:2])
    with pytest.raises(ValueError, match=r"truth \(None: the city index\) must be \[0, 1\], got \[2\]"):
        batch.reset([0], [1], x0[None], city=[2])
    with pytest.raises(ValueError, match=r"truth .* must be \[0, 1\], got \[5\]"):
        batch.reset([0], [1], x0[None], truth=[5])
    with pytest.raises(ValueError, match="never reset"):
        batch.lidar_scans(0.0, [1])
    batch.reset([0, 1], [1, 2], np.stack([x0, x0]))
    with pytest.raises(ValueError, match=r"t_s must be a finite time or 2"):
        batch.lidar_scans(np.array([0.0]))
    with pytest.raises(ValueError, match="dropout"):
        BatchOnboard(dataclasses.replace(cfg, lidar=dataclasses.replace(cfg.lidar, dropout=1.5)), DT_S, 2, air,
                     lidar_casters=casters)
