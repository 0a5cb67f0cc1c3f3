"""BatchOnboard: a slot estimates what `Onboard` estimates from the same seed and true states, bit for bit (one slot;
three slots, one reset mid-way, one leaving early; an IMU rate that leaves steps over between periods), its numbers
depend on neither its neighbours nor N, and bad inputs are refused naming what was wrong."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.air.atmosphere import Atmosphere, AtmosphereConditions
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.baro import Barometer, pressure_altitude_m
from uam_fdm.sensing.batch_onboard import BatchOnboard
from uam_fdm.sensing.batch_sensors import PressureColumn, PressureColumns, SlotStreams
from uam_fdm.sensing.gnss import line_of_sight_enu
from uam_fdm.sensing.onboard import Onboard
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import MS5611, SensingConfig, sensing_preset
from uam_fdm.sim import Simulator
from uam_fdm.vehicle.model import hover_state

BOUNDS = ([0.0, 0.0, 0.0], [200.0, 200.0, 300.0])
# a north-south street 30 m wide between two 40 m walls: the canyon blocks satellites and reflects some
STREET = BuildingMap([Building(0, (40.0, 100.0), (20.0, 200.0), 40.0),
                      Building(1, (90.0, 100.0), (20.0, 200.0), 40.0)], *BOUNDS)
OPEN = BuildingMap([Building(0, (170.0, 170.0), (20.0, 20.0), 30.0)], *BOUNDS)
CITIES = (OPEN, STREET)
PERIODS = 200  # 4 s of flight at 50 Hz: 40 GNSS epochs, 1,000 IMU samples


@dataclasses.dataclass(frozen=True)
class Flight:
    """A flown leg: the true initial state and, per control period, (state at its start, substep states, t_s)."""

    x0: np.ndarray
    periods: tuple[tuple[np.ndarray, np.ndarray, float], ...]


@pytest.fixture(scope="module")
def quad(compiled_dynamics):
    return compiled_dynamics["small_quad"]


@pytest.fixture(scope="module")
def casters() -> list[RayCaster]:
    return [RayCaster(c) for c in CITIES]


def _fly(dyn, atmosphere: Atmosphere, start: list[float], yaw_rad: float, speed_m_s: float) -> Flight:
    """A climb and a straight leg north along the street under the velocity controller, turning slowly."""
    p = dyn.params
    sim = Simulator(dyn, atmosphere)
    x0 = hover_state(p, np.array(start), yaw_rad, density_ratio=atmosphere.density_ratio(start[2]))
    sim.reset(x0)
    out = []
    for k in range(PERIODS):
        s, t = sim.state, 0.02 * k
        r = sim.advance_velocity(np.array([0.0, min(t, speed_m_s), 0.5 if t < 2.0 else 0.0, yaw_rad + 0.1 * t]))
        out.append((s.x.copy(), r.states.copy(), s.t_s))
    return Flight(x0, tuple(out))


@pytest.fixture(scope="module")
def flights(quad, air) -> dict[str, Flight]:
    return {"a": _fly(quad, air[0], [62.0, 20.0, 8.0], 0.3, 4.0), "b": _fly(quad, air[1], [70.0, 40.0, 5.0], -1.0, 2.5)}


def _level(name: str, mass_kg: float) -> SensingConfig:
    if name == "degraded-outages":  # outages every ~2 s of up to 1 s: the outage draws and gaps exercised
        cfg = sensing_preset("degraded", mass_kg)
        return dataclasses.replace(cfg, gnss=dataclasses.replace(cfg.gnss, outage_rate_per_min=30.0, max_outage_s=1.0))
    if name == "degraded-imu150":  # 150 Hz: every 3 physics steps, so steps are carried over between periods
        cfg = sensing_preset("degraded", mass_kg)
        return dataclasses.replace(cfg, imu=dataclasses.replace(cfg.imu, rate_hz=150.0))
    return sensing_preset(name, mass_kg)


def _assert_same(onboard: Onboard, batch: BatchOnboard, slot: int, x_true: np.ndarray, t_s: float) -> None:
    """The slot's estimate, position covariance and controller offset are exactly the single vehicle's."""
    obs = onboard.observation(t_s)
    est = batch.estimates([slot])
    np.testing.assert_array_equal(est.state[0], obs.x[:13])
    assert obs.covariance is not None
    np.testing.assert_array_equal(est.position_covariance_m2[0], obs.covariance[0:3, 0:3])
    assert est.t_s[0] == obs.estimate_t_s
    np.testing.assert_array_equal(batch.controller_offset(x_true[None], [slot])[0], onboard.controller_offset(x_true))


@pytest.mark.parametrize("level", ["nominal", "degraded", "degraded-outages"])
def test_one_slot_is_onboard_bit_for_bit(quad, air, casters, flights, level):
    cfg = _level(level, quad.params.mass_kg)
    f = flights["a"]
    single = Onboard(cfg, STREET, casters[1], air[0], f.x0, quad.dt_s, 7)
    batch = BatchOnboard(cfg, quad.dt_s, 1, air, cities=CITIES, casters=casters)
    batch.reset([0], [7], f.x0[None], city=[1], field=[0])
    for x_start, states, t_s in f.periods:
        _assert_same(single, batch, 0, x_start, t_s)
        single.advance(x_start, states, t_s)
        batch.advance(x_start[None], states[None], t_s)
    _assert_same(single, batch, 0, f.periods[-1][1][-1], f.periods[-1][2] + 0.02)
    record = single.record()
    assert (batch.gnss.epochs[0], batch.gnss.fixes[0]) == (record.gnss_epochs, record.gnss_fixes)
    assert batch.gnss.satellites[0] == record.satellites[-1]
    if level == "degraded-outages":
        assert 0 < record.gnss_fixes < record.gnss_epochs
    if level == "degraded":
        # the street blocks satellites, and some blocked ones are tracked through reflections
        los = line_of_sight_enu(single.gnss.azimuth_rad, single.gnss.elevation_rad)
        x_end = f.periods[-1][1][-1]
        visible = int(np.count_nonzero(~casters[1].hits_any(x_end[0:3], los)))
        assert visible < cfg.gnss.satellites and batch.gnss.satellites[0] > visible


@pytest.mark.parametrize("level", ["degraded", "degraded-imu150"])
def test_three_slots_one_reset_mid_way_are_three_onboards(quad, air, casters, flights, level):
    """Slot 0 flies leg a in the street; slot 1 flies leg a, then a new episode of leg b from its own clock's 0;
    slot 2 flies leg b in the open city and its episode ends early (it is left out of later periods)."""
    cfg = _level(level, quad.params.mass_kg)
    a, b = flights["a"], flights["b"]
    reset_at, leave_at = 91, 150  # at 91: slot 0 carries one physics step over at 150 Hz, slot 1 none
    batch = BatchOnboard(cfg, quad.dt_s, 3, air, cities=CITIES, casters=casters)
    batch.reset([0, 1, 2], [11, 12, 14], np.stack([a.x0, a.x0, b.x0]), city=[1, 1, 0], field=[0, 0, 1])
    singles = [Onboard(cfg, STREET, casters[1], air[0], a.x0, quad.dt_s, 11),
               Onboard(cfg, STREET, casters[1], air[0], a.x0, quad.dt_s, 12),
               Onboard(cfg, OPEN, casters[0], air[1], b.x0, quad.dt_s, 14)]
    legs = [a.periods, a.periods, b.periods]
    clock = [0, 0, 0]  # each slot's period index on its own leg
    for k in range(PERIODS):
        if k == reset_at:
            batch.reset([1], [13], b.x0[None], city=[0], field=[1])
            singles[1] = Onboard(cfg, OPEN, casters[0], air[1], b.x0, quad.dt_s, 13)
            legs[1], clock[1] = b.periods, 0
        flying = [i for i in range(3) if not (i == 2 and k >= leave_at)]
        rows = [legs[i][clock[i]] for i in flying]
        for i, (x_start, _, t_s) in zip(flying, rows):
            _assert_same(singles[i], batch, i, x_start, t_s)
            singles[i].advance(*legs[i][clock[i]])
        batch.advance(np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows]),
                      np.array([r[2] for r in rows]), flying)
        for i in flying:
            clock[i] += 1
    for i in range(3):
        x_end, t_end = legs[i][clock[i] - 1][1][-1], legs[i][clock[i] - 1][2] + 0.02
        _assert_same(singles[i], batch, i, x_end, t_end)


def test_a_slot_depends_on_neither_its_neighbours_nor_n(quad, air, casters, flights):
    cfg = _level("degraded", quad.params.mass_kg)
    a, b = flights["a"], flights["b"]

    def run(n: int, slot: int, seeds: list[int]) -> list[np.ndarray]:
        batch = BatchOnboard(cfg, quad.dt_s, n, air, cities=CITIES, casters=casters)
        x0 = np.stack([a.x0 if i == slot else b.x0 for i in range(n)])
        batch.reset(list(range(n)), seeds, x0, city=[1 if i == slot else 0 for i in range(n)],
                    field=[0 if i == slot else 1 for i in range(n)])
        out = []
        for (xa, sa, ta), (xb, sb, _) in zip(a.periods[:100], b.periods[:100]):
            pick = [(xa, sa) if i == slot else (xb, sb) for i in range(n)]
            batch.advance(np.stack([p[0] for p in pick]), np.stack([p[1] for p in pick]), ta)
            e = batch.estimates([slot])
            out.append(np.concatenate((e.state[0], e.position_covariance_m2[0].ravel(), e.sigma_max_m)))
        return out

    alone = run(1, 0, [5])
    among = run(5, 3, [1, 2, 3, 5, 4])
    again = run(5, 3, [1, 2, 3, 5, 4])
    other = run(5, 3, [9, 8, 7, 5, 6])  # the same slot's seed among other neighbours
    for x, y, z, w in zip(alone, among, again, other):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(y, z)
        np.testing.assert_array_equal(y, w)
    assert not np.array_equal(run(1, 0, [6])[-1], alone[-1])  # and the seed matters


def test_the_pressure_column_is_the_barometers(air):
    z = np.array([-40.0, -1e-3, 0.0, 3.7, 55.5, 199.9, 200.0, 350.0])  # below, in and above the table
    for atmosphere in air:
        baro = Barometer(MS5611, atmosphere, 0.0, np.random.default_rng(0))
        expected = [float(pressure_altitude_m(baro.pressure_pa(float(v)))) for v in z]
        assert PressureColumn(atmosphere).pressure_altitude_m(z) == expected


def test_the_stacked_pressure_columns_read_each_day_as_its_own_column(air):
    rng = np.random.default_rng(3)
    z = np.concatenate([[-40.0, -1e-3, 0.0, 200.0, 350.0], rng.uniform(-50.0, 400.0, 200)])
    z = np.concatenate([z, air[0].heights_m[1:4]])  # on the grid itself
    field = rng.integers(0, len(air), len(z))
    columns = [PressureColumn(a) for a in air]
    stacked = PressureColumns(columns)
    assert stacked._stacked  # the pool's days share one grid: read together
    expected = [columns[f].pressure_altitude_m(np.array([v]))[0] for f, v in zip(field, z, strict=True)]
    np.testing.assert_array_equal(stacked.pressure_altitude_m(field, z), expected)
    taller = PressureColumn(Atmosphere.from_jsbsim(AtmosphereConditions(), z_max_m=300.0))  # another grid
    mixed = PressureColumns([*columns, taller])
    assert not mixed._stacked
    field[::3] = len(air)
    expected = [mixed.columns[f].pressure_altitude_m(np.array([v]))[0] for f, v in zip(field, z, strict=True)]
    np.testing.assert_array_equal(mixed.pressure_altitude_m(field, z), expected)


def test_sigma_max_is_the_longest_axis_of_the_position_error(quad, air, flights):
    batch = BatchOnboard(_level("nominal", quad.params.mass_kg), quad.dt_s, 2, air)
    batch.reset([0, 1], [1, 2], np.stack([flights["a"].x0] * 2))
    for x_start, states, t_s in flights["a"].periods[:60]:
        batch.advance(np.stack([x_start] * 2), np.stack([states] * 2), t_s)
    est = batch.estimates()
    for k in range(2):
        cov = est.position_covariance_m2[k]
        assert est.sigma_max_m[k] == pytest.approx(np.sqrt(np.linalg.eigvalsh(cov).max()), rel=1e-12)
        assert est.sigma_max_m[k] >= np.sqrt(cov.diagonal().max())
    assert np.all(batch.gnss_availability == 1.0)


def test_bad_inputs_are_refused_naming_what_was_wrong(quad, air, casters, flights):
    m = quad.params.mass_kg
    with pytest.raises(ValueError, match="perfect"):
        BatchOnboard(sensing_preset("perfect", m), quad.dt_s, 2, air)
    with pytest.raises(ValueError, match="RayCaster per city"):
        BatchOnboard(sensing_preset("degraded", m), quad.dt_s, 2, air, cities=CITIES, casters=casters[:1])
    with pytest.raises(ValueError, match="physics_dt_s"):
        BatchOnboard(sensing_preset("nominal", m), 0.0, 2, air)
    batch = BatchOnboard(sensing_preset("degraded", m), quad.dt_s, 2, air, cities=CITIES, casters=casters)
    x0 = flights["a"].x0
    x_start, states, t_s = flights["a"].periods[0]
    with pytest.raises(ValueError, match=r"never reset"):
        batch.advance(x_start[None], states[None], t_s, [0])
    with pytest.raises(ValueError, match=r"x0 must be \(M=2"):
        batch.reset([0, 1], [1, 2], x0[None])
    with pytest.raises(ValueError, match="slots must be distinct"):
        batch.reset([1, 1], [1, 2], np.stack([x0, x0]))
    with pytest.raises(ValueError, match=r"slots must lie in \[0, 2\), got \[2\]"):
        batch.reset([2], [1], x0[None])
    with pytest.raises(ValueError, match=r"city must be \[0, 1\], got \[2\]"):
        batch.reset([0], [1], x0[None], city=[2])
    with pytest.raises(ValueError, match=r"seeds must be >= 0"):
        batch.reset([0], [-1], x0[None])
    batch.reset([0, 1], [1, 2], np.stack([x0, x0]))
    with pytest.raises(ValueError, match=r"states must be \(M=2, S, nx="):
        batch.advance(np.stack([x_start] * 2), states[None], t_s)
    with pytest.raises(ValueError, match=r"t_start_s must be a finite time or 2"):
        batch.advance(np.stack([x_start] * 2), np.stack([states] * 2), np.array([t_s]))
    broken = np.stack([states] * 2)
    broken[1, 3, 0] = np.nan
    with pytest.raises(ValueError, match=r"states of slots \[1\] are not finite"):
        batch.advance(np.stack([x_start] * 2), broken, t_s)


@pytest.mark.parametrize("uniform", [False, True])
def test_slot_streams_hand_out_each_generators_sequence_however_taken(uniform):
    streams = SlotStreams(3, 10, uniform=uniform)
    for i in range(3):
        streams.restart(i, np.random.default_rng(i + 1))
    taken: list[list[float]] = [[], [], []]
    rng = np.random.default_rng(9)
    for k in range(200):  # random subsets and sizes, beyond the block after a while (the buffer grows)
        slots = np.sort(rng.choice(3, size=int(rng.integers(1, 4)), replace=False))
        out = streams.take(slots, int(rng.integers(1, 25 if k > 50 else 8)))
        for row, i in zip(out, slots.tolist()):
            taken[i] += row.tolist()
    for i in range(3):
        gen = np.random.default_rng(i + 1)
        expected = gen.random(len(taken[i])) if uniform else gen.standard_normal(len(taken[i]))
        assert np.array_equal(expected, taken[i])
