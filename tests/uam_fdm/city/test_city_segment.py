"""segment_free: exact swept-sphere checks that cannot tunnel through thin walls."""
from __future__ import annotations

import math

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.generator import SHIPPED_MAPS, generate_city


def _wall_map(thickness_m: float) -> BuildingMap:
    """A 40 m long, 30 m tall wall of the given thickness across x = 50, yawed by 0."""
    return BuildingMap([Building(1, (50.0, 50.0), (thickness_m, 40.0), 30.0)], (0, 0, 0), (100, 100, 100))


def test_thin_wall_cannot_be_tunnelled() -> None:
    wall = _wall_map(0.01)  # 1 cm thick
    a, b = [10.0, 50.0, 10.0], [90.0, 50.0, 10.0]
    # A sampler stepping 1 m would jump over the wall: no sample along the segment touches it.
    samples = np.linspace(a, b, 81)  # x = 10, 11, ..., 90: the wall spans 49.995..50.005
    assert wall.is_free(samples + [0.3, 0.0, 0.0], 0.2).all()
    for r in (0.0, 0.2, 1.0):
        assert not wall.segment_free(np.add(a, [0.3, 0, 0]), np.add(b, [0.3, 0, 0]), r)
        assert not wall.segment_free(b, a, r)
    # Over the top and around the end: free exactly when the clearance exceeds the radius.
    r = 0.5
    for dz, free in ((1e-4, True), (-1e-4, False)):
        z = 30.0 + r + dz
        assert wall.segment_free([10.0, 50.0, z], [90.0, 50.0, z], r) is free
    for dy, free in ((1e-4, True), (-1e-4, False)):
        y = 70.0 + r + dy  # the wall ends at y = 70
        assert wall.segment_free([10.0, y, 10.0], [90.0, y, 10.0], r) is free


def test_yawed_corner_and_diagonal_grazing() -> None:
    yaw = math.radians(30.0)
    bmap = BuildingMap([Building(3, (50.0, 50.0), (20.0, 10.0), 40.0, yaw)], (0, 0, 0), (100, 100, 100))
    corner = np.array([50.0, 50.0]) + np.array([[math.cos(yaw), -math.sin(yaw)],
                                                [math.sin(yaw), math.cos(yaw)]]) @ [10.0, 5.0]
    # A segment perpendicular to the corner's bisector direction, passing at distance r +- 1e-4.
    out = np.array([math.cos(yaw + math.atan2(5, 10)), math.sin(yaw + math.atan2(5, 10))])
    along = np.array([-out[1], out[0]])
    r = 1.0
    for gap, free in ((1e-4, True), (-1e-4, False)):
        c = corner + out * (r + gap)
        a, b = np.r_[c - 30.0 * along, 20.0], np.r_[c + 30.0 * along, 20.0]
        assert bmap.segment_free(a, b, r) is free


def _segment_min_distance(bmap: BuildingMap, a: np.ndarray, b: np.ndarray) -> float:
    """Reference for box maps: per box, a golden-section search of the distance along a-b (convex in
    t for a convex box), all boxes at once; then the minimum over boxes and the ground."""
    boxes = bmap.buildings
    cx = np.array([p.center_xy_m[0] for p in boxes])
    cy = np.array([p.center_xy_m[1] for p in boxes])
    co = np.cos([p.yaw_rad for p in boxes])
    si = np.sin([p.yaw_rad for p in boxes])
    half = np.array([[0.5 * p.size_xy_m[0], 0.5 * p.size_xy_m[1], 0.5 * p.height_m] for p in boxes])

    def f(t: np.ndarray) -> np.ndarray:  # distance from a + t (b - a) to box i, for every i
        p = a + t[:, None] * (b - a)
        dx, dy = p[:, 0] - cx, p[:, 1] - cy
        q = np.abs(np.column_stack([co * dx + si * dy, -si * dx + co * dy, p[:, 2] - half[:, 2]])) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    g = (math.sqrt(5.0) - 1.0) / 2.0
    lo, hi = np.zeros(len(boxes)), np.ones(len(boxes))
    for _ in range(80):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(x1) < f(x2)
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
    ends = np.minimum(f(np.zeros(len(boxes))), f(np.ones(len(boxes))))
    return float(min(np.min(np.minimum(f(0.5 * (lo + hi)), ends)), a[2], b[2]))


def test_random_segments_match_reference() -> None:
    params, _ = SHIPPED_MAPS["canyon"]
    full = generate_city(params, seed=5)
    # A 200 m square of the canyon keeps the reference search quick.
    parts = [b for b in full.buildings if np.all((b.footprint_xy_m() > 250) & (b.footprint_xy_m() < 450))]
    bmap = BuildingMap(parts, (250, 250, 0), (450, 450, 300))
    rng = np.random.default_rng(0)
    n_free = n_blocked = 0
    for _ in range(300):
        a = rng.uniform([250, 250, 1], [450, 450, 120])
        b = a + rng.normal(size=3) * rng.choice([3.0, 15.0, 60.0])
        r = float(rng.choice([0.0, 0.5, 3.0]))
        ref = _segment_min_distance(bmap, a, b) - r
        if abs(ref) < 1e-6:
            continue
        assert bmap.segment_free(a, b, r) == (ref > 0), (a, b, r, ref)
        n_free += ref > 0
        n_blocked += ref <= 0
    assert n_free > 10 and n_blocked > 10


def test_endpoints_and_ground() -> None:
    bmap = _wall_map(2.0)
    assert not bmap.segment_free([50.0, 50.0, 10.0], [10.0, 10.0, 10.0], 0.1)  # starts inside
    assert not bmap.segment_free([10.0, 10.0, 10.0], [20.0, 10.0, 0.05], 0.1)  # ends below the radius
    assert bmap.segment_free([10.0, 10.0, 10.0], [10.0, 10.0, 10.0], 0.1)  # zero length, free point
    assert not bmap.segment_free([49.5, 50.0, 10.0], [49.5, 50.0, 10.0], 0.1)  # zero length, inside
    # Outside the flight volume the geometry still answers (bounds are checked by the runner).
    assert bmap.segment_free([-50.0, -50.0, 10.0], [150.0, -40.0, 12.0], 1.0)


@pytest.mark.parametrize("name", sorted(SHIPPED_MAPS))
def test_long_segments_agree_with_dense_sampling_when_clearly_free(name: str) -> None:
    """Long segments at cruise altitude: when dense samples show a margin > the step, the check agrees."""
    params, seed = SHIPPED_MAPS[name]
    bmap = generate_city(params, seed)
    rng = np.random.default_rng(1)
    hi = bmap.bounds_max_m
    for _ in range(30):
        a = rng.uniform([0, 0, 5], [hi[0], hi[1], 80])
        b = rng.uniform([0, 0, 5], [hi[0], hi[1], 80])
        step = 0.05
        n = int(np.linalg.norm(b - a) / step) + 2
        d = bmap.clearance(np.linspace(a, b, n), 1.0).distance_m
        if d.min() > step:
            assert bmap.segment_free(a, b, 1.0)
        if d.min() <= 0:
            assert not bmap.segment_free(a, b, 1.0)
