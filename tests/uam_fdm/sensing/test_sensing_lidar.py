"""Lidar: beam layout, exact geometry through the true pose, noise, dropout, thin unmapped obstacles, what each
returned beam truly hit."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap, Prism
from uam_fdm.sensing.lidar import Lidar, LidarScan, beam_directions_body
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import VLP16, VLP32C

BOUNDS = ([0.0, 0.0, 0.0], [400.0, 400.0, 200.0])
QUIET = dataclasses.replace(VLP16, range_noise_m=0.0, range_noise_per_m=0.0, dropout=0.0)


def rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_beam_layout_follows_the_spec():
    for spec in (VLP16, VLP32C):
        d = beam_directions_body(spec)
        assert d.shape == (spec.rays_per_scan, 3) and spec.rays_per_scan == spec.channels * 1800
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
        el = np.degrees(np.arcsin(d[:, 2]))
        assert (el.min(), el.max()) == pytest.approx(spec.vertical_fov_deg)
        assert len(np.unique(np.round(el, 6))) == spec.channels
        assert np.allclose(np.diff(np.unique(np.round(el, 6))), np.diff(spec.vertical_fov_deg) / (spec.channels - 1))
        az = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 360.0
        assert np.allclose(np.unique(np.round(az, 6)), np.arange(1800) * 0.2)


def test_a_thin_unmapped_crane_jib_is_seen_at_50_m():
    # a 2 m x 2 m jib, 60 m long, 40-42 m up, its near face 50 m north of the vehicle; no ground, nothing else
    jib = Building(7, (200.0, 251.0), (60.0, 2.0), 42.0, base_m=40.0)
    caster = RayCaster(BuildingMap([jib], *BOUNDS), ground=False)
    scan, truth = Lidar(QUIET, caster, np.random.default_rng(0)).scan(0.0, np.array([200.0, 200.0, 41.0]), np.eye(3))
    assert len(scan.ranges_m) >= 100  # the ±1° channels, over the jib's ±31° of azimuth
    assert np.allclose(truth.points_m[:, 1], 250.0, atol=1e-3)  # every point on the jib's near face
    assert np.all((truth.points_m[:, 2] > 40.0) & (truth.points_m[:, 2] < 42.0))
    assert np.all(truth.part_index == 0)  # the jib: the city's only part
    el = np.degrees(np.arcsin(scan.directions_body[:, 2]))
    assert set(np.round(el, 6)) == {-1.0, 1.0}
    assert np.min(scan.ranges_m) == pytest.approx(50.0 / math.cos(math.radians(1.0)), abs=1e-3)


def test_the_true_attitude_turns_the_beams():
    wall = Building(1, (300.0, 200.0), (2.0, 300.0), 150.0)  # east of the vehicle, face at x = 299
    lidar = Lidar(QUIET, RayCaster(BuildingMap([wall], *BOUNDS), ground=False), np.random.default_rng(0))
    p = np.array([200.0, 200.0, 50.0])
    for yaw in (0.0, 0.5 * math.pi, 2.0):
        scan, truth = lidar.scan(0.0, p, rot_z(yaw))
        assert np.allclose(truth.points_m[:, 0], 299.0, atol=1e-3)
        # the body-frame points, turned by the true attitude, land on the true hits (no noise here)
        assert np.allclose(p + scan.points_body_m() @ rot_z(yaw).T, truth.points_m, atol=1e-3)
        # the wall lies along world +x: in the body frame, at azimuth -yaw
        body_az = np.arctan2(scan.directions_body[:, 1], scan.directions_body[:, 0])
        assert abs(math.remainder(float(np.median(body_az)) + yaw, 2 * math.pi)) < 0.05


def test_ranges_are_gated_by_min_and_max_range():
    caster = RayCaster(BuildingMap([], *BOUNDS))  # the ground only
    p = np.array([200.0, 200.0, 10.0])
    scan, _ = Lidar(QUIET, caster, np.random.default_rng(0)).scan(0.0, p, np.eye(3))
    # the downward channels reach the ground at 10 / sin(-el): under 100 m for -el >= 5.74 deg
    el = np.round(np.degrees(np.arcsin(scan.directions_body[:, 2])), 6)
    assert set(el) == {-15.0, -13.0, -11.0, -9.0, -7.0}
    assert np.allclose(scan.ranges_m, 10.0 / np.sin(np.radians(-el)))
    # min range 40 m drops the steepest channel (10 / sin(15 deg) = 38.6 m)
    close = dataclasses.replace(QUIET, min_range_m=40.0)
    scan, _ = Lidar(close, caster, np.random.default_rng(0)).scan(0.0, p, np.eye(3))
    assert set(np.round(np.degrees(np.arcsin(scan.directions_body[:, 2])), 6)) == {-13.0, -11.0, -9.0, -7.0}


def test_noise_and_dropout_have_the_spec_statistics():
    wall = Building(1, (300.0, 200.0), (2.0, 390.0), 190.0)
    caster = RayCaster(BuildingMap([wall], *BOUNDS), ground=False)
    spec = dataclasses.replace(VLP16, range_noise_m=0.02, range_noise_per_m=1e-3, dropout=0.3)
    lidar = Lidar(spec, caster, np.random.default_rng(5))
    all_hits = Lidar(QUIET, caster, np.random.default_rng(5)).scan(0.0, np.array([200.0, 200.0, 100.0]), np.eye(3))[0]
    kept, res, sig = [], [], []
    for k in range(20):
        scan, truth = lidar.scan(0.1 * k, np.array([200.0, 200.0, 100.0]), np.eye(3))
        r_true = np.linalg.norm(truth.points_m - [200.0, 200.0, 100.0], axis=1)
        assert np.allclose(truth.ranges_m, r_true)
        kept.append(len(scan.ranges_m) / len(all_hits.ranges_m))
        res.append(scan.ranges_m - r_true)
        sig.append(0.02 + 1e-3 * r_true)
    assert np.mean(kept) == pytest.approx(0.7, abs=0.02)
    z = np.concatenate(res) / np.concatenate(sig)
    assert len(z) > 5000  # standard errors: 0.014 on the mean, 0.01 on the σ
    assert np.mean(z) == pytest.approx(0.0, abs=0.05) and np.std(z) == pytest.approx(1.0, abs=0.04)


def test_same_seed_same_scan_and_the_scan_holds_no_truth():
    wall = Building(1, (300.0, 200.0), (2.0, 300.0), 150.0)
    caster = RayCaster(BuildingMap([wall], *BOUNDS))
    pose = (np.array([200.0, 200.0, 30.0]), rot_z(0.3))
    a = [Lidar(VLP16, caster, np.random.default_rng(11)).scan(0.0, *pose) for _ in range(2)]
    b = Lidar(VLP16, caster, np.random.default_rng(12)).scan(0.0, *pose)
    assert np.array_equal(a[0][0].ranges_m, a[1][0].ranges_m)
    assert np.array_equal(a[0][0].directions_body, a[1][0].directions_body)
    assert not (len(b[0].ranges_m) == len(a[0][0].ranges_m) and np.array_equal(b[0].ranges_m, a[0][0].ranges_m))
    # no truth: what it measured, and the vehicle's own estimate of its pose (stamped by the onboard, not here)
    assert {f.name for f in dataclasses.fields(LidarScan)} == {"t_s", "directions_body", "ranges_m", "pose_estimate"}
    assert a[0][0].pose_estimate is None
    with pytest.raises(ValueError):
        a[0][0].ranges_m[0] = 1.0  # read-only


def _parts_city() -> BuildingMap:
    """Boxes (one yawed, one elevated like a crane's jib) and a footprint of two prisms sharing one id."""
    return BuildingMap([Building(3, (240.0, 200.0), (10.0, 30.0), 60.0),
                        Building(5, (180.0, 250.0), (20.0, 8.0), 35.0, yaw_rad=0.4),
                        Building(9, (200.0, 160.0), (40.0, 2.0), 42.0, base_m=38.0),
                        Prism(11, ((140.0, 180.0), (160.0, 180.0), (160.0, 200.0)), 50.0),
                        Prism(11, ((140.0, 180.0), (160.0, 200.0), (140.0, 200.0)), 50.0)], *BOUNDS)


def test_each_returned_beam_names_the_part_it_hit():
    city = _parts_city()
    caster = RayCaster(city)
    lidar = Lidar(VLP16, caster, np.random.default_rng(3))  # noise and dropout as shipped
    named = set()
    for p, rot in ((np.array([200.0, 200.0, 40.0]), np.eye(3)), (np.array([195.0, 205.0, 20.0]), rot_z(0.7))):
        scan, truth = lidar.scan(0.0, p, rot)
        part = truth.part_index
        assert part.shape == truth.ranges_m.shape == scan.ranges_m.shape and np.all(part >= -1)
        # where each beam truly ends, in float64 on the hit triangle's plane (the lidar's ranges are float32's)
        d = scan.directions_body @ rot.T
        exact = caster.ranges_m(p, d, VLP16.max_range_m, exact=True)
        assert np.allclose(truth.ranges_m, exact, atol=1e-3)
        ends = p + d * exact[:, None]
        assert np.all(np.abs(ends[part == -1, 2]) <= 1e-6)  # the ground
        for k in set(part.tolist()) - {-1}:
            on = BuildingMap([city.buildings[k]], *BOUNDS).obstacle_clearance_m(ends[part == k])
            assert np.all(np.abs(on) <= 1e-6), (k, np.abs(on).max())
        named |= set(part.tolist())
    assert named == {-1, 0, 1, 2, 3, 4}  # every part, both prisms of building 11 told apart, and the ground


def test_the_scan_is_the_one_the_ranges_and_the_seed_give():
    """Naming the parts leaves the scan bit for bit as it was: the ranges as `ranges_m` casts them, then dropout
    and noise drawn from the lidar's generator in the same order."""
    caster = RayCaster(_parts_city())
    spec = dataclasses.replace(VLP16, dropout=0.3)
    lidar, rng = Lidar(spec, caster, np.random.default_rng(21)), np.random.default_rng(21)
    for t, (p, rot) in enumerate(((np.array([200.0, 200.0, 40.0]), rot_z(0.2)),
                                  (np.array([190.0, 210.0, 25.0]), rot_z(-1.1)))):
        scan, truth = lidar.scan(0.1 * t, p, rot)
        d = lidar.directions_body @ rot.T
        r_true = caster.ranges_m(p, d, spec.max_range_m)
        idx = np.flatnonzero((r_true >= spec.min_range_m) & (r_true <= spec.max_range_m))
        idx = idx[rng.random(len(idx)) >= spec.dropout]
        r = r_true[idx]
        measured = np.maximum(r + (spec.range_noise_m + spec.range_noise_per_m * r) * rng.standard_normal(len(idx)),
                              0.0)
        assert np.array_equal(scan.ranges_m, measured) and np.array_equal(truth.ranges_m, r)
        assert np.array_equal(scan.directions_body, lidar.directions_body[idx])
        assert np.array_equal(truth.points_m, p + d[idx] * r[:, None])


def test_bad_spec_raises():
    caster = RayCaster(BuildingMap([], *BOUNDS))
    with pytest.raises(ValueError):
        Lidar(dataclasses.replace(VLP16, dropout=1.5), caster, np.random.default_rng(0))
    with pytest.raises(ValueError):
        Lidar(dataclasses.replace(VLP16, min_range_m=200.0), caster, np.random.default_rng(0))
