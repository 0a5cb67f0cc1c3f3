"""GNSS receiver: open-sky accuracy against σ·HDOP, time correlation, blocking, NLOS bias, outages, determinism."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.gnss import Gnss, GnssFix, dop, draw_sky, line_of_sight_enu
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import NEO_M9N, ZED_F9P

BOUNDS = ([0.0, 0.0, 0.0], [200.0, 200.0, 300.0])
OPEN = BuildingMap([], *BOUNDS)
# a north-south street 30 m wide between two 40 m walls (x = 50..80), 200 m long
STREET = BuildingMap([Building(0, (40.0, 100.0), (20.0, 200.0), 40.0),
                      Building(1, (90.0, 100.0), (20.0, 200.0), 40.0)], *BOUNDS)
IN_STREET = np.array([58.0, 100.0, 10.0])  # 8 m from the west wall


def run(gnss: Gnss, p: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, list[GnssFix | None]]:
    fixes = [gnss.measure(k * dt, p, np.zeros(3)) for k in range(n)]
    err = np.array([f.position_m - p for f in fixes if f is not None]).reshape(-1, 3)
    return err, fixes


def canyon(spec, nlos: float):
    return dataclasses.replace(spec, urban_canyon=True, nlos_probability=nlos)


def test_sky_is_uniform_over_the_visible_cap():
    az, el = draw_sky(20000, 10.0, np.random.default_rng(0))
    assert np.all(el >= np.radians(10.0)) and np.all(el <= np.pi / 2)
    s = np.sin(el)
    assert np.mean(s) == pytest.approx(0.5 * (np.sin(np.radians(10.0)) + 1.0), abs=0.01)
    assert np.mean(az) == pytest.approx(np.pi, abs=0.05)
    los = line_of_sight_enu(np.array([0.0, 0.5 * np.pi]), np.array([0.0, 0.0]))
    assert np.allclose(los, [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # azimuth from north, clockwise


def test_open_sky_error_matches_sigma_times_hdop():
    # a short correlation time: nearly independent epochs, so 10,000 of them pin the RMS to ~1 %
    spec = dataclasses.replace(NEO_M9N, correlation_time_s=0.5)
    for seed in range(2):
        gnss = Gnss(spec, OPEN, None, np.random.default_rng(seed))
        err, fixes = run(gnss, np.array([100.0, 100.0, 50.0]), 10000, 1.0)
        assert len(err) == 10000 and gnss.last_fix and gnss.last_satellites == 24
        f = fixes[-1]
        assert f is not None and f.sigma_h_m == pytest.approx(spec.pseudorange_sigma_m * f.hdop)
        rms_h = np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1)))
        rms_v = np.sqrt(np.mean(err[:, 2] ** 2))
        assert rms_h == pytest.approx(f.sigma_h_m, rel=0.05)
        assert rms_v == pytest.approx(f.sigma_v_m, rel=0.05)
        assert 0.4 < f.hdop < 1.2  # 24 satellites: a good geometry


def test_errors_are_time_correlated_at_10_hz():
    gnss = Gnss(NEO_M9N, OPEN, None, np.random.default_rng(3))
    err, _ = run(gnss, np.array([100.0, 100.0, 50.0]), 6000, 0.1)
    for axis in range(3):
        e = err[:, axis] - err[:, axis].mean()
        assert np.dot(e[1:], e[:-1]) / np.dot(e, e) > 0.9
    # and the velocity noise is white with the spec's σ
    fixes = [gnss.measure(600.0 + 0.1 * k, np.zeros(3) + 50.0, np.array([1.0, 2.0, 3.0])) for k in range(4000)]
    dv = np.array([f.velocity_m_s for f in fixes if f is not None]) - [1.0, 2.0, 3.0]
    assert np.std(dv) == pytest.approx(NEO_M9N.velocity_sigma_m_s, rel=0.05)
    assert abs(np.dot(dv[1:, 0], dv[:-1, 0]) / np.dot(dv[:, 0], dv[:, 0])) < 0.1


def test_walls_block_satellites_and_worsen_the_geometry():
    caster = RayCaster(STREET)
    for seed in range(5):
        open_sky = Gnss(NEO_M9N, STREET, caster, np.random.default_rng(seed))
        street = Gnss(canyon(NEO_M9N, 0.0), STREET, caster, np.random.default_rng(seed))
        f_open = open_sky.measure(0.0, IN_STREET, np.zeros(3))
        f_street = street.measure(0.0, IN_STREET, np.zeros(3))
        assert f_open is not None and open_sky.last_satellites == 24
        assert street.last_satellites < 20
        if f_street is not None:
            assert f_street.hdop > f_open.hdop and f_street.satellites == street.last_satellites
        # above the roofs, the same receiver sees the whole sky again
        assert street.measure(1.0, np.array([65.0, 100.0, 45.0]), np.zeros(3)) is not None
        assert street.last_satellites == 24


def test_no_fix_in_a_deep_courtyard():
    # a 20 m courtyard enclosed by four 250 m blocks: nothing under ~85 deg of elevation is visible
    walls = [Building(0, (100.0, 70.0), (80.0, 40.0), 250.0), Building(1, (100.0, 130.0), (80.0, 40.0), 250.0),
             Building(2, (70.0, 100.0), (20.0, 20.0), 250.0), Building(3, (130.0, 100.0), (20.0, 20.0), 250.0)]
    court = BuildingMap(walls, *BOUNDS)
    gnss = Gnss(canyon(ZED_F9P, 0.0), court, RayCaster(court), np.random.default_rng(0))
    for k in range(20):
        assert gnss.measure(0.1 * k, np.array([100.0, 100.0, 5.0]), np.zeros(3)) is None
        assert gnss.last_satellites < 4 and not gnss.last_fix


def test_reflections_bias_the_fix_while_the_receiver_reports_good_accuracy():
    caster = RayCaster(STREET)
    # a 1 m pseudorange σ, so that the reflections' ~10 m biases stand well above the noise
    spec = dataclasses.replace(NEO_M9N, pseudorange_sigma_m=1.0, correlation_time_s=2.0)
    rms, reported = {}, {}
    for nlos in (0.0, 1.0):
        gnss = Gnss(canyon(spec, nlos), STREET, caster, np.random.default_rng(7))
        err, fixes = run(gnss, IN_STREET, 2000, 1.0)
        assert len(err) == 2000
        rms[nlos] = np.sqrt(np.mean(np.sum(err ** 2, axis=1)))
        reported[nlos] = np.hypot(fixes[-1].sigma_h_m, fixes[-1].sigma_v_m)
    # all 24 satellites tracked with reflections: a better DOP reported, a far worse true error (8 m walls: ~10 m)
    assert reported[1.0] < reported[0.0]
    assert rms[1.0] > 3.0 * rms[0.0] and rms[1.0] > 3.0 * reported[1.0]


def test_a_reflection_is_drawn_once_per_blockage():
    caster = RayCaster(STREET)
    tracked = {}
    for nlos in (0.0, 0.5, 1.0):
        gnss = Gnss(canyon(NEO_M9N, nlos), STREET, caster, np.random.default_rng(2))  # the same sky
        counts = []
        for k in range(50):
            gnss.measure(0.1 * k, IN_STREET, np.zeros(3))
            counts.append(gnss.last_satellites)
        assert len(set(counts)) == 1  # standing still: the same satellites, reflected or not, at every epoch
        tracked[nlos] = counts[0]
    assert tracked[0.0] < tracked[0.5] < tracked[1.0] == 24


def test_outages_follow_the_spec():
    spec = dataclasses.replace(NEO_M9N, outage_rate_per_min=2.0, max_outage_s=10.0)
    gnss = Gnss(spec, OPEN, None, np.random.default_rng(4))
    _, fixes = run(gnss, np.array([100.0, 100.0, 50.0]), 36000, 0.1)  # an hour at 10 Hz
    lost = np.array([f is None for f in fixes])
    starts = np.flatnonzero(lost[1:] & ~lost[:-1])
    lengths = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2] * 0.1
    # 2 per minute of lock, mean length 5 s: ~110 outages, ~8 % of the time without a fix
    assert 80 < len(starts) < 140
    assert lengths.max() <= 10.0 + 1e-9 and np.mean(lengths) == pytest.approx(5.0, abs=1.0)
    assert np.mean(lost) == pytest.approx(110 * 5.0 / 3600.0, abs=0.04)


def test_same_seed_same_fixes():
    caster = RayCaster(STREET)
    spec = dataclasses.replace(canyon(NEO_M9N, 0.5), outage_rate_per_min=1.0, max_outage_s=5.0)
    path = [np.array([58.0 + 0.5 * k, 100.0, 10.0 + 0.2 * k]) for k in range(100)]

    def fly(seed: int) -> list:
        g = Gnss(spec, STREET, caster, np.random.default_rng(seed))
        return [g.measure(0.1 * k, p, np.ones(3)) for k, p in enumerate(path)]

    a, b, c = fly(9), fly(9), fly(10)
    assert [f is None for f in a] == [f is None for f in b]
    for fa, fb in zip(a, b):
        if fa is not None:
            assert np.array_equal(fa.position_m, fb.position_m) and np.array_equal(fa.velocity_m_s, fb.velocity_m_s)
            assert (fa.satellites, fa.hdop) == (fb.satellites, fb.hdop)
    pos_a = [f.position_m for f in a if f is not None]
    pos_c = [f.position_m for f in c if f is not None]
    assert not np.array_equal(pos_a[0], pos_c[0])


def test_dop_of_a_known_geometry():
    # one satellite at the zenith and three 120 deg apart on the horizon: HᵀH is diag(1.5, 1.5) horizontally and
    # [[1, -1], [-1, 4]] in (up, clock), so HDOP = sqrt(2 / 1.5) and VDOP = sqrt(4 / 3)
    los = line_of_sight_enu(np.radians([0.0, 0.0, 120.0, 240.0]), np.radians([90.0, 0.0, 0.0, 0.0]))
    hdop, vdop = dop(los)
    assert hdop == pytest.approx(np.sqrt(2.0 / 1.5)) and vdop == pytest.approx(np.sqrt(4.0 / 3.0))
    assert dop(los[:3]) is None


def test_time_must_not_go_back():
    gnss = Gnss(NEO_M9N, OPEN, None, np.random.default_rng(0))
    gnss.measure(1.0, np.full(3, 10.0), np.zeros(3))
    with pytest.raises(ValueError):
        gnss.measure(0.5, np.full(3, 10.0), np.zeros(3))
    with pytest.raises(ValueError):
        Gnss(canyon(NEO_M9N, 0.5), OPEN, None, np.random.default_rng(0))
