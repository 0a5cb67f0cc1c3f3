"""RayCaster (Embree) against analytic ray/box and ray/plane intersections."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap, Prism
from uam_fdm.sensing.raycast import RayCaster, part_mesh

BOUNDS = ([-500.0, -500.0, 0.0], [500.0, 500.0, 300.0])


def slab_range(o: np.ndarray, d: np.ndarray, b: Building) -> np.ndarray:
    """Exact entry distance of rays (N, 3) into a yawed box, float64; inf on a miss (origins outside)."""
    c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
    rel = o[:, :2] - np.asarray(b.center_xy_m)
    lo = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], o[:, 2]])
    ld = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
    box_lo = np.array([-b.size_xy_m[0] / 2, -b.size_xy_m[1] / 2, b.base_m])
    box_hi = np.array([b.size_xy_m[0] / 2, b.size_xy_m[1] / 2, b.height_m])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (box_lo - lo) / ld, (box_hi - lo) / ld
    t_in = np.nanmax(np.minimum(t1, t2), axis=1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((t_in <= t_out) & (t_in > 0), t_in, np.inf)


def random_rays(rng: np.random.Generator, n: int, target: np.ndarray, spread: float) -> tuple[np.ndarray, np.ndarray]:
    o = rng.uniform([-300, -300, 1], [300, 300, 250], (n, 3))
    aim = target + rng.uniform(-spread, spread, (n, 3))
    d = aim - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_yawed_elevated_box_ranges_match_the_slab_test():
    box = Building(3, (120.0, -80.0), (30.0, 12.0), 90.0, yaw_rad=0.7, base_m=40.0)
    caster = RayCaster(BuildingMap([box], *BOUNDS), ground=False)
    o, d = random_rays(np.random.default_rng(0), 20000, np.array([120.0, -80.0, 65.0]), 30.0)
    exact = slab_range(o, d, box)
    hit = np.isfinite(exact)
    assert 0.3 < hit.mean() < 0.9  # the rays test both hits and misses
    for refine, typical, worst in ((False, 3e-4, 1.5e-3), (True, 1e-9, 1.5e-3)):
        got = caster.ranges_m(o, d, 1e4, exact=refine)
        # a ray through an edge may go either way in float32: only those few may disagree on hit/miss
        assert np.mean(np.isfinite(got) == hit) > 0.999
        both = hit & np.isfinite(got)
        err = np.abs(got[both] - exact[both])
        assert np.quantile(err, 0.999) < typical
        assert np.max(err) < worst  # float32 rays grazing a face
    assert np.array_equal(caster.hits_any(o, d, 1e4), np.isfinite(caster.ranges_m(o, d, 1e4)))


def test_ground_and_prism_ranges_are_exact():
    tri = Prism(1, ((200.0, 200.0), (260.0, 200.0), (230.0, 250.0)), 70.0)
    caster = RayCaster(BuildingMap([tri], *BOUNDS))
    rng = np.random.default_rng(1)
    # straight down onto the ground, away from the prism: range = height
    o = np.column_stack([rng.uniform(-450, 150, 500), rng.uniform(-450, 150, 500), rng.uniform(0.5, 299, 500)])
    r = caster.ranges_m(o, np.tile([0.0, 0.0, -1.0], (500, 1)), 1e3)
    assert np.max(np.abs(r - o[:, 2])) < 1e-4
    # slanted onto the ground: z / sin(depression)
    dep = rng.uniform(0.05, 1.5, 500)
    az = rng.uniform(0, 2 * np.pi, 500)
    d = np.column_stack([np.cos(dep) * np.cos(az), np.cos(dep) * np.sin(az), -np.sin(dep)])
    o2 = np.column_stack([np.zeros(500), np.zeros(500), np.full(500, 10.0)])
    r = caster.ranges_m(o2, d, 1e4)
    expected = 10.0 / np.sin(dep)
    assert np.max(np.abs(r - expected) / np.maximum(expected, 1.0)) < 2e-6
    # the prism's south face (y = 200), hit square on from the south at heights below its roof
    x = rng.uniform(205, 255, 200)
    z = rng.uniform(1, 69, 200)
    o3 = np.column_stack([x, np.full(200, 150.0), z])
    r = caster.ranges_m(o3, np.tile([0.0, 1.0, 0.0], (200, 1)), 500)
    assert np.max(np.abs(r - 50.0)) < 1e-3
    # its roof from above
    r = caster.ranges_m(np.array([230.0, 215.0, 100.0]), np.array([[0.0, 0.0, -1.0]]), 500)
    assert r[0] == pytest.approx(30.0, abs=1e-4)


def test_max_range_and_misses_read_inf():
    box = Building(0, (0.0, 0.0), (10.0, 10.0), 50.0)
    caster = RayCaster(BuildingMap([box], *BOUNDS))
    o = np.array([-100.0, 0.0, 20.0])
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    r = caster.ranges_m(o, d, 1e4)
    assert r[0] == pytest.approx(95.0, abs=1e-4) and r[3] == pytest.approx(20.0, abs=1e-5)
    assert np.isinf(r[1]) and np.isinf(r[2])  # the ground ends 2 km out; nothing above
    r = caster.ranges_m(o, d, 50.0)
    assert np.isinf(r[0]) and r[3] == pytest.approx(20.0, abs=1e-5)
    assert caster.hits_any(o, d).tolist() == [True, False, False, True]
    assert caster.hits_any(o, d, 50.0).tolist() == [False, False, False, True]
    assert RayCaster(BuildingMap([box], *BOUNDS), ground=False).ranges_m(o, d[3:], 1e3)[0] == np.inf


def test_far_corner_of_a_large_map_keeps_millimetre_precision():
    # a map whose coordinates run to 5 km: the local origin keeps float32 exact there
    bounds = ([4000.0, 4000.0, 0.0], [5000.0, 5000.0, 200.0])
    box = Building(0, (4990.0, 4990.0), (10.0, 10.0), 100.0)
    caster = RayCaster(BuildingMap([box], *bounds))
    o = np.array([4010.123, 4990.0, 33.3])
    r = caster.ranges_m(o, np.array([[1.0, 0.0, 0.0]]), 2000.0)
    assert r[0] == pytest.approx(4985.0 - 4010.123, abs=1e-3)


def test_part_mesh_is_closed():
    for part in (Building(0, (0.0, 0.0), (4.0, 2.0), 10.0, yaw_rad=0.2, base_m=3.0),
                 Prism(1, ((0.0, 0.0), (4.0, 0.0), (5.0, 3.0), (2.0, 5.0), (-1.0, 3.0)), 8.0)):
        v, t = part_mesh(part)
        edges = np.sort(np.vstack([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
        # every edge of a closed surface belongs to two triangles
        uniq, count = np.unique(edges, axis=0, return_counts=True)
        on_ground = np.all(v[uniq][:, :, 2] == 0.0, axis=1)  # the open bottom of a grounded prism
        assert np.all(count[~on_ground] == 2) and np.all(count[on_ground] == 1)
        assert len(v) == 2 * len(part.footprint_xy_m())


def test_bad_shapes_raise():
    empty = RayCaster(BuildingMap([], *BOUNDS), ground=False)
    assert np.isinf(empty.ranges_m(np.zeros(3), np.array([[0.0, 0.0, -1.0]]), 10.0)).all()
    assert not empty.hits_any(np.zeros(3), np.array([[0.0, 0.0, -1.0]])).any()
    caster = RayCaster(BuildingMap([], *BOUNDS))
    with pytest.raises(ValueError):
        caster.ranges_m(np.zeros((2, 3)), np.zeros((3, 3)), 10.0)
    with pytest.raises(ValueError):
        caster.ranges_m(np.zeros(3), np.zeros(3), 10.0)
    assert caster.ranges_m(np.zeros(3), np.zeros((0, 3)), 10.0).shape == (0,)


def test_pickles_by_rebuilding_the_scene():
    box = Building(0, (0.0, 0.0), (10.0, 10.0), 50.0, yaw_rad=0.4)
    caster = RayCaster(BuildingMap([box], *BOUNDS), ground_margin_m=500.0)
    copy = pickle.loads(pickle.dumps(caster))
    o, d = random_rays(np.random.default_rng(3), 500, np.zeros(3) + 20.0, 40.0)
    assert np.array_equal(copy.ranges_m(o, d, 1e3), caster.ranges_m(o, d, 1e3))
    assert copy.n_triangles == caster.n_triangles
