"""Margins as a function of the reference speed: the rule on a fixed binned table, its inverse and taper,
the shipped table, and the clearance contract that narrows towards a start or goal."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planners.clearance import MarginTaper, RequiredClearance
from planners.margins import (
    MarginRule,
    SpeedBin,
    SpeedMargins,
    TrackingErrorRow,
    TrackingErrorTable,
    bin_by_speed,
    load_tracking_table,
    margins_for,
    write_tracking_table,
)
from uam_fdm.air.wind import TurbulenceLevel as T
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.vehicle.params import load_vehicle

QUAD = load_vehicle("small_quad")
RULE = MarginRule(floor_m=1.0, k=2.0, mpc_fraction=0.5)


def _bins(*spec: tuple[float, float, float]) -> tuple[SpeedBin, ...]:
    """Bins from (speed_lo, speed_hi, p99)."""
    return tuple(SpeedBin(lo, hi, 600, p99 / 4, p99 / 2, p99, 1.5 * p99) for lo, hi, p99 in spec)


def _row(turbulence: T, sigma: float, bins: tuple[SpeedBin, ...]) -> TrackingErrorRow:
    pooled = max(b.p99_m for b in bins)
    return TrackingErrorRow(QUAD.name, QUAD.fingerprint(), turbulence, sigma, 4, 1800, pooled / 4, pooled / 2,
                            pooled, 2 * pooled, bins)


# sea level: slow 0.2 m, middling 0.8 m, fast 0.6 m (less than the middle: the rule keeps the larger)
SEA = _row(T.MODERATE, 1.0, _bins((0.0, 2.0, 0.2), (2.1, 6.0, 0.8), (6.2, 9.6, 0.6)))
# thin air: slow 0.7 m, fast 3.0 m, bins at other speeds
THIN = _row(T.MODERATE, 0.7, _bins((0.0, 3.0, 0.7), (3.1, 9.6, 3.0)))
TABLE = TrackingErrorTable((SEA, THIN), {})


@pytest.mark.parametrize(("sigma", "speeds", "margins"), [
    # sea level: max(1, 2 x p99) = 1 | 1.6 | 1.2, made non-decreasing: 1 up to 2 m/s, 1.6 above
    (1.0, (0.0, 2.0, 2.05, 6.0, 9.0, 30.0), (1.0, 1.0, 1.6, 1.6, 1.6, 1.6)),
    # thin air (measured there): 1.4 up to 3 m/s, 6 above
    (0.7, (0.0, 3.0, 3.05, 9.0), (1.4, 1.4, 6.0, 6.0)),
    # halfway in density, on the union of the bins' speeds: p99 at <=2: (0.2+0.7)/2, <=3: (0.8+0.7)/2,
    # <=6: (0.8+3)/2, above: (0.6+3)/2 -> 2 x: 0.9 | 1.5 | 3.8 | 3.6 -> floor and non-decreasing
    (0.85, (1.0, 2.5, 4.0, 8.0), (1.0, 1.5, 3.8, 3.8)),
])
def test_the_margin_follows_the_speed_as_the_table_says(sigma, speeds, margins):
    m = margins_for(TABLE, RULE, QUAD, "moderate", sigma, 1.0, 0.5)
    got = m.by_speed.margin_m(np.array(speeds))
    assert got == pytest.approx(margins, abs=1e-12)
    assert m.planner_m == pytest.approx(max(margins)) and m.mpc_m == pytest.approx(0.5 * max(margins))
    assert m.by_speed.floor_m == pytest.approx(margins[0]) and np.all(np.diff(got) >= 0)
    assert "m/s" in m.source


def test_an_unmeasured_level_takes_the_larger_margin_at_every_speed():
    calm = _row(T.NONE, 1.0, _bins((0.0, 4.0, 1.0), (4.1, 9.6, 0.1)))
    table = TrackingErrorTable((SEA, calm), {})
    m = margins_for(table, RULE, QUAD, "severe", 1.0, 1.0, 0.5)
    # calm's slow 2 m beats moderate's 1 m; moderate's 1.6 m wins only where calm has no larger step before it
    assert m.by_speed.margin_m(np.array([1.0, 3.0, 5.0, 9.0])) == pytest.approx([2.0, 2.0, 2.0, 2.0])


def test_inverse_and_taper_of_the_step_function():
    s = SpeedMargins((2.0, 6.0), (1.0, 2.0, 4.0))
    # the fastest speed whose margin fits in a clearance
    assert s.speed_limit_m_s(np.array([4.0, 10.0, 3.9, 2.0, 1.5, 1.0, 0.3])) == pytest.approx(
        [math.inf, math.inf, 6.0, 6.0, 2.0, 2.0, 2.0])   # below the floor: the first step's speed (crawl)
    # round trip: at the allowed speed the margin fits
    for c in (1.0, 1.7, 2.0, 3.0):
        assert s.margin_m(s.speed_limit_m_s(c)) <= c
    # from rest with 2 m/s^2: v <= 2 within 1 m, v <= 6 within 9 m
    assert s.taper(2.0) == ((1.0, 9.0), (1.0, 2.0))
    # leaving at 3 m/s: the 2 m/s step is never flown; v <= 6 within (36 - 9) / 4 m
    assert s.taper(2.0, 3.0) == ((6.75,), (2.0,))
    assert SpeedMargins.constant(1.5).taper(2.0) == ((), ())
    with pytest.raises(ValueError, match="non-decreasing"):
        SpeedMargins((2.0,), (2.0, 1.0))


def test_binning_merges_thin_bins_and_the_table_round_trips(tmp_path):
    rng = np.random.default_rng(0)
    speeds = np.concatenate([rng.uniform(0.0, 0.6, 100), rng.uniform(1.3, 2.3, 900), rng.uniform(8.0, 9.5, 2000)])
    dev = 0.05 + 0.02 * speeds
    bins = bin_by_speed(dev, speeds, 12.0, edges=(0.0, 0.1, 0.5), min_samples=500)
    # the 100 slow decisions join the next faster bin; the fast ones make their own
    assert [b.samples for b in bins] == [1000, 2000]
    assert bins[0].speed_lo_m_s == pytest.approx(speeds[:100].min()) and bins[1].speed_lo_m_s >= 8.0
    assert bins[0].p99_m == pytest.approx(np.percentile(dev[:1000], 99))
    row = TrackingErrorRow(QUAD.name, QUAD.fingerprint(), T.NONE, 1.0, 3, 3000, 0.1, 0.2, 0.3, 0.4, bins)
    back = load_tracking_table(write_tracking_table([row], {"pool": "validation"}, tmp_path / "t.json"))
    assert back.rows[0].speed_bins[1].samples == 2000
    assert back.rows[0].speed_bins[0].p99_m == pytest.approx(bins[0].p99_m, abs=1e-4)


def test_the_shipped_table_gives_margins_by_speed_with_provenance():
    table = load_tracking_table()
    assert table.provenance.get("pool", "").startswith("validation")
    for row in table.rows:
        vehicle = load_vehicle(row.vehicle)
        m = margins_for(table, MarginRule(), vehicle, row.turbulence, row.density_ratio, 1.0, 0.5)
        if not row.speed_bins:
            continue
        # at each bin's speeds: max(1 m, 2 x p99 of this and every slower bin)
        want = np.maximum.accumulate([max(1.0, 2.0 * b.p99_m) for b in row.speed_bins])
        for b, w in zip(row.speed_bins, want, strict=True):
            assert m.by_speed.margin_m(np.array([b.speed_lo_m_s, b.speed_hi_m_s])) == pytest.approx([w, w])
        assert m.by_speed.floor_m >= 1.0 and m.planner_m == pytest.approx(want[-1])


# ---- the clearance contract -------------------------------------------------------------------------
CITY = BuildingMap([Building(0, (20.0, 5.0), (40.0, 4.0), 30.0)], (-20.0, -20.0, 0.0), (60.0, 20.0, 40.0))


def test_required_clearance_narrows_towards_an_endpoint_and_its_runs_bound_it():
    goal = (10.0, 0.0, 10.0)     # 3 m from the wall's face (y = 3)
    taper = MarginTaper(goal, (1.0, 9.0), (1.0, 2.0))
    req = RequiredClearance(CITY, 0.5, 4.0, endpoints=[goal], tapers=[taper])
    # at the goal, 3 m from the wall, the margin at rest (1 m) holds: no relaxation needed
    assert not req.relaxed
    pts = np.array([goal, (10.0, -0.5, 10.0), (10.0, -5.0, 10.0), (10.0, -12.0, 10.0)])
    assert req.at(pts) == pytest.approx([1.5, 1.5, 2.5, 4.5])
    assert [req.at_one(*p) for p in pts] == pytest.approx(list(req.at(pts)))
    # a segment's runs never ask less than R at any point of the run
    a, b = (10.0, -15.0, 10.0), goal
    runs = req.runs(a, b)
    assert len(runs) >= 3 and np.allclose(runs[0][0], a) and np.allclose(runs[-1][1], b)
    for p, q, big_r in runs:
        inside = p + (q - p) * np.linspace(0.0, 1.0, 21)[:, None]
        assert np.all(req.at(inside) <= big_r + 1e-12)
    # far from the goal: one run at the cruise R
    assert req.runs((-10.0, -15.0, 10.0), (-10.0, 15.0, 30.0))[0][2] == pytest.approx(4.5)


def test_the_reference_slows_where_it_passes_closer_than_the_cruise_margin():
    """A straight 100 m flight whose middle 40 m pass 2.5 m from a wall: with margins 1 / 2 / 4 m up to 2 / 6 /
    any m/s the reference may fly at most 6 m/s there (M = 2 m fits 2.5 m, 4 m does not), faster elsewhere."""
    from planners.timing import TimingLimits, time_parameterize

    wall = BuildingMap([Building(0, (50.0, 4.0), (40.0, 2.0), 30.0)], (-10.0, -20.0, 0.0), (110.0, 20.0, 40.0))
    limits = TimingLimits(12.0, 3.0, 4.0, 3.0)
    path = np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0]])
    speeds = SpeedMargins((2.0, 6.0), (1.0, 2.0, 4.0))
    capped = time_parameterize(path, limits, wall, 0.5, 1.0, speed_limit=speeds.speed_limit_m_s)
    free = time_parameterize(path, limits, wall, 0.5, 1.0)
    assert capped.ok and free.ok
    along = np.abs(capped.pos_m[:, 0] - 50.0) < 20.0
    v = np.linalg.norm(capped.vel_m_s, axis=1)
    assert v[along].max() <= 6.0 + 1e-6 and v.max() > 9.0
    assert np.linalg.norm(free.vel_m_s, axis=1).max() > 11.9 and capped.duration_s > free.duration_s
    # the margin in force along the curve never exceeds the clearance there
    clear = wall.clearance(capped.pos_m, 0.5).distance_m
    assert np.all(speeds.margin_m(v) <= clear + 1e-6)


def test_margins_widen_by_the_estimates_uncertainty_at_every_speed():
    from planners.margins import Margins, SpeedMargins

    speed = SpeedMargins((2.0, 5.0), (1.0, 1.5, 2.0), 0.5)
    wide = speed.widened(0.75)
    assert wide.margins_m == (1.75, 2.25, 2.75) and wide.uppers_m_s == speed.uppers_m_s
    assert speed.widened(0.0) is speed
    m = Margins(2.0, 1.0, 0.4, "table", speed)
    w = m.widened(0.75)
    assert (w.planner_m, w.mpc_m, w.floor_m) == (2.75, 1.375, 1.75)
    assert "uncertainty" in w.source and m.widened(0.0) is m
