"""Clearance against analytic distances, an independent brute-force reference and FCL."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from uam_fdm.city import distance
from uam_fdm.city.buildings import Building, BuildingMap, NoFlyZone, Prism
from uam_fdm.city.generator import CityGenConfig, generate_city


def _one_box(yaw_deg: float = 0.0) -> BuildingMap:
    """One 20 x 10 x 30 m box centred at (50, 40), on a 100 x 100 x 100 m volume."""
    return BuildingMap([Building(7, (50.0, 40.0), (20.0, 10.0), 30.0, math.radians(yaw_deg))],
                       (0.0, 0.0, 0.0), (100.0, 100.0, 100.0))


def _all_paths(bmap: BuildingMap, pts: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d_np = bmap.clearance(pts, r).distance_m
    d_fcl = bmap.clearance(pts, r, backend="fcl").distance_m
    d_one = np.array([bmap.clearance_one(*p, r) for p in pts])
    return d_np, d_fcl, d_one


@pytest.fixture(scope="module")
def city() -> BuildingMap:
    """A generated, rotated-grid city of ~200 buildings plus two convex prisms and an L of boxes."""
    params = CityGenConfig(extent_m=(1000.0, 1000.0), block_size_m=(80.0, 70.0), street_width_m=20.0,
                           density=0.6, core_radius_m=200.0, core_height_factor=3.0, grid_yaw_deg=17.0,
                           yaw_jitter_deg=5.0)
    base = generate_city(params, seed=11)
    extra = [Prism(10_000, ((2.0, 2.0), (30.0, 4.0), (26.0, 30.0), (6.0, 24.0)), 45.0),
             Prism(10_001, ((960.0, 960.0), (995.0, 962.0), (990.0, 990.0)), 80.0)]
    return BuildingMap(list(base.buildings) + extra, base.bounds_min_m, base.bounds_max_m, name="test")


def _box_distance(b: Building, p: np.ndarray) -> float:
    """Signed distance from one point to one box building, by rotating into the box frame."""
    return float(_box_distances(b, p[None])[0])


def _box_distances(b: Building, pts: np.ndarray) -> np.ndarray:
    c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
    rel = pts - np.array([*b.center_xy_m, 0.5 * b.height_m])
    local = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]])
    half = np.array([0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1], 0.5 * b.height_m])
    q = np.abs(local) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _brute_force(bmap: BuildingMap, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent reference for box-only maps: per building, rotate into its frame, clamp."""
    best = pts[:, 2].copy()  # the ground
    best_id = np.full(len(pts), -1)
    for b in bmap.buildings:
        d = _box_distances(b, pts)
        better = d < best
        best[better], best_id[better] = d[better], b.id
    return best, best_id


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, -115.0])
def test_analytic_box_distances(yaw_deg: float) -> None:
    bmap = _one_box(yaw_deg)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))

    def world(lx: float, ly: float, z: float) -> list[float]:  # box-frame offsets -> ENU
        return [50.0 + c * lx - s * ly, 40.0 + s * lx + c * ly, z]

    cases = [  # (box-frame point, expected signed distance of the point)
        (world(15.0, 0.0, 10.0), 5.0),  # 5 m off the +x face
        (world(0.0, -9.0, 20.0), 4.0),  # off the -y face
        (world(0.0, 0.0, 36.0), 6.0),  # above the roof
        (world(13.0, 9.0, 10.0), 5.0),  # off a vertical edge: hypot(3, 4)
        (world(-12.0, 7.0, 32.0), math.sqrt(12.0)),  # off a roof corner: norm(2, 2, 2)
        (world(0.0, 0.0, 10.0), -5.0),  # inside: nearest face is +-y at 5 m
        (world(9.0, 0.0, 15.0), -1.0),  # inside, 1 m from the +x face
        (world(2.0, 1.0, 29.5), -0.5),  # inside, just under the roof
        (world(10.0, 0.0, 10.0), 0.0),  # on the face
    ]
    pts = np.array([p for p, _ in cases])
    expected = np.array([d for _, d in cases])
    for r in (0.0, 0.75):
        for d in _all_paths(bmap, pts, r):
            np.testing.assert_allclose(d, expected - r, atol=1e-9)
    res = bmap.clearance(pts)
    assert np.all(res.building_id == 7)
    # The nearest point is on the surface, |p - q| = |d|.
    np.testing.assert_allclose(np.linalg.norm(res.nearest_point_m - pts, axis=1), np.abs(expected), atol=1e-9)


def test_ground_is_the_plane_z0() -> None:
    bmap = _one_box()
    pts = np.array([[5.0, 5.0, 3.0], [95.0, 90.0, 0.2], [5.0, 5.0, -1.0]])
    res = bmap.clearance(pts, 0.5)
    np.testing.assert_allclose(res.distance_m, [2.5, -0.3, -1.5])
    assert res.building_id.tolist() == [-1, -1, -1]
    np.testing.assert_allclose(res.nearest_point_m, [[5, 5, 0], [95, 90, 0], [5, 5, 0]])
    np.testing.assert_allclose([bmap.clearance_one(*p, 0.5) for p in pts], [2.5, -0.3, -1.5])
    np.testing.assert_allclose(bmap.clearance(pts, 0.5, backend="fcl").distance_m, [2.5, -0.3, -1.5])
    # Next to the building but low: the ground is nearer than the wall.
    assert bmap.clearance(np.array([[65.0, 40.0, 2.0]])).building_id[0] == -1
    assert bmap.clearance(np.array([[62.0, 40.0, 5.0]])).building_id[0] == 7


def test_box_kernel_against_brute_force_and_its_scalar_twin() -> None:
    """The one box kernel (NumPy) at random points around random yawed boxes, a third of them inside:
    equal to the brute-force reference to rounding, and the plain-Python twin and the key form give
    the very same doubles."""
    rng = np.random.default_rng(7)
    n_box, n_pt = 40, 400
    boxes = [Building(j, tuple(rng.uniform(-50.0, 50.0, 2)), tuple(rng.uniform(0.5, 30.0, 2)),
                      float(rng.uniform(1.0, 80.0)), float(rng.uniform(-2.0 * math.pi, 2.0 * math.pi)))
             for j in range(n_box)]
    col = {k: np.array([v[k] for v in (_kernel_box(b) for b in boxes)]) for k in range(8)}
    pts = rng.uniform([-90.0, -90.0, -5.0], [90.0, 90.0, 100.0], size=(n_pt, 3))
    for i in range(n_pt // 3):  # inside points: a random box's own frame, scaled into it
        b = boxes[i % n_box]
        c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
        lx, ly = rng.uniform(-0.999, 0.999, 2) * 0.5 * np.array(b.size_xy_m)
        pts[i] = [b.center_xy_m[0] + c * lx - s * ly, b.center_xy_m[1] + s * lx + c * ly,
                  rng.uniform(0.001, 0.999) * b.height_m]
    args = (pts[:, 0:1], pts[:, 1:2], pts[:, 2:3], *(col[k] for k in range(8)))
    got = distance.box_signed_distance(*args)
    ref = np.column_stack([_box_distances(b, pts) for b in boxes])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)
    assert (got < 0).sum() >= n_pt // 3  # the inside points are inside
    np.testing.assert_array_equal(distance.signed_sqrt(distance.box_signed_sq_distance(*args)), got)
    one = np.array([[distance.box_signed_distance_one(*p, _kernel_box(b)) for b in boxes]
                    for p in pts.tolist()])
    np.testing.assert_array_equal(one, got)
    # Points on faces, edges and corners: distance 0 on every path.
    b = boxes[0]
    c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
    hx, hy = 0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1]
    on_surface = ((hx, 0.0, 1.0), (hx, hy, 0.5 * b.height_m), (-hx, -hy, b.height_m), (0.0, 0.0, b.height_m))
    for lx, ly, z in on_surface:
        p = (b.center_xy_m[0] + c * lx - s * ly, b.center_xy_m[1] + s * lx + c * ly, z)
        assert abs(distance.box_signed_distance_one(*p, _kernel_box(b))) < 1e-12


def test_numpy_and_plain_python_paths_give_the_same_doubles(city: BuildingMap) -> None:
    """Per part (boxes and convex prisms), the plain-Python distance CellIndex uses equals the NumPy
    kernel's exactly, so `clearance_one` and `clearance` agree to the last bit within the indexed
    volume (outside it, `clearance_one` asks FCL)."""
    rng = np.random.default_rng(4)
    pts = rng.uniform([-20.0, -20.0, -1.0], [1020.0, 1020.0, 330.0], size=(300, 3))
    pts[:100] = rng.uniform([0.0, 0.0, 0.0], [40.0, 40.0, 50.0], size=(100, 3))  # around the first prism
    a = city._packed
    d_np = distance.part_distances(pts, a)
    parts = distance._python_parts(a)
    d_py = np.array([[fn(*p, shape) for fn, shape in parts] for p in pts.tolist()])
    np.testing.assert_array_equal(d_py, d_np)
    assert (d_np < 0).any()
    indexed = city.in_bounds(pts) & (pts[:, 2] < 300.0)
    np.testing.assert_array_equal(np.array([city.clearance_one(*p, 0.5) for p in pts[indexed]]),
                                  city.clearance(pts[indexed], 0.5).distance_m)
    assert indexed.sum() > 150


def _kernel_box(b: Building) -> tuple[float, ...]:
    """A box building as the kernel takes it: (cx, cy, cos, sin, hx, hy, zc, hz)."""
    return (*b.center_xy_m, math.cos(b.yaw_rad), math.sin(b.yaw_rad), 0.5 * b.size_xy_m[0],
            0.5 * b.size_xy_m[1], 0.5 * b.height_m, 0.5 * b.height_m)


def test_brute_force_reference_10k_points(city: BuildingMap) -> None:
    boxes = BuildingMap([b for b in city.buildings if isinstance(b, Building)], city.bounds_min_m,
                        city.bounds_max_m)
    rng = np.random.default_rng(0)
    pts = rng.uniform([0.0, 0.0, -2.0], [1000.0, 1000.0, 260.0], size=(10_000, 3))
    ref_d, ref_id = _brute_force(boxes, pts)
    res = boxes.clearance(pts, 1.5)
    np.testing.assert_allclose(res.distance_m, ref_d - 1.5, rtol=0, atol=1e-9)
    assert np.mean(res.building_id == ref_id) > 0.999  # exact ties may differ
    assert (ref_d < 0).sum() > 100 and (ref_id >= 0).sum() > 1000  # the sample exercises insides and walls
    one = np.array([boxes.clearance_one(*p, 1.5) for p in pts[:3000]])
    np.testing.assert_allclose(one, ref_d[:3000] - 1.5, rtol=0, atol=1e-9)


def test_numpy_scalar_and_fcl_agree(city: BuildingMap) -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform([-20.0, -20.0, -1.0], [1020.0, 1020.0, 330.0], size=(3000, 3))  # some outside bounds
    pts[:500] = rng.uniform([0.0, 0.0, 0.0], [40.0, 40.0, 50.0], size=(500, 3))  # around the first prism
    for r in (0.0, 2.0):
        d_np, d_fcl, d_one = _all_paths(city, pts, r)
        np.testing.assert_allclose(d_np, d_fcl, rtol=0, atol=1e-9)
        np.testing.assert_allclose(d_one, d_np, rtol=0, atol=1e-9)
    a, b = city.clearance(pts), city.clearance(pts, backend="fcl")
    assert np.mean(a.building_id == b.building_id) > 0.999
    outside = (a.distance_m > 1e-6) & (a.building_id == b.building_id)
    np.testing.assert_allclose(a.nearest_point_m[outside], b.nearest_point_m[outside], atol=1e-7)
    inside = (a.distance_m < 0) & (a.building_id >= 0)
    assert inside.sum() > 20
    np.testing.assert_allclose(np.linalg.norm(a.nearest_point_m[inside] - pts[inside], axis=1),
                               -a.distance_m[inside], atol=1e-9)


def test_is_free_and_bounds(city: BuildingMap) -> None:
    rng = np.random.default_rng(2)
    pts = rng.uniform([-50.0, -50.0, -5.0], [1050.0, 1050.0, 320.0], size=(2000, 3))
    np.testing.assert_array_equal(city.is_free(pts, 1.0), city.clearance(pts, 1.0).distance_m > 0)
    assert [city.is_free_one(*p, 1.0) for p in pts[:200]] == city.is_free(pts[:200], 1.0).tolist()
    inb = city.in_bounds(pts)
    expected = np.all((pts >= city.bounds_min_m) & (pts <= city.bounds_max_m), axis=1)
    np.testing.assert_array_equal(inb, expected)
    assert city.in_bounds(np.array([[1.0, 500.0, 50.0]]), radius_m=2.0).tolist() == [False]
    assert city.in_bounds(np.array([[3.0, 500.0, 50.0]]), radius_m=2.0).tolist() == [True]
    with pytest.raises(ValueError):
        city.clearance(np.array([[1.0, np.nan, 3.0]]))
    with pytest.raises(ValueError):
        city.clearance(np.zeros(3))


def test_no_fly_zones_are_not_obstacles() -> None:
    zone = NoFlyZone((20.0, 20.0), (10.0, 10.0), (0.0, 50.0), math.radians(45.0))
    bmap = BuildingMap([Building(0, (80.0, 80.0), (10.0, 10.0), 20.0)], (0, 0, 0), (100, 100, 100), [zone])
    pts = np.array([[20.0, 20.0, 10.0], [20.0 + 5.0 * math.sqrt(2) + 1.0, 20.0, 10.0], [20.0, 20.0, 52.0]])
    assert bmap.in_no_fly(pts).tolist() == [True, False, False]
    assert bmap.in_no_fly(pts, radius_m=2.5).tolist() == [True, True, True]
    assert bmap.clearance(pts).building_id.tolist() == [-1, -1, -1]


def test_nearest_obstacles(city: BuildingMap) -> None:
    p = np.array([480.0, 510.0, 30.0])
    pts, dist = city.nearest_obstacles(p, k=5, radius_m=1.0)
    assert pts.shape == (5, 3) and dist.shape == (5,)
    assert np.all(np.diff(dist) >= 0)
    # Reference: each box building's brute-force distance (the two prisms sit > 600 m away).
    boxes = [b for b in city.buildings if isinstance(b, Building)]
    ref_all = np.array([_box_distance(b, p) for b in boxes]) - 1.0
    ref = np.sort(ref_all)[:5]
    assert ref[-1] < 500.0
    np.testing.assert_allclose(dist, ref, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pts - p, axis=1), np.abs(dist + 1.0), atol=1e-9)  # [0] is inside
    # Batch form and padding.
    _, bd, bid = city.nearest_obstacles_batch(np.vstack([p, p + 100.0]), 5, 1.0)
    np.testing.assert_allclose(bd[0], dist)
    assert len(set(bid[0].tolist())) == 5
    small = _one_box()
    pts2, d2 = small.nearest_obstacles([50.0, 60.0, 10.0], k=3, radius_m=0.0, pad_distance_m=500.0)
    np.testing.assert_allclose(d2, [15.0, 500.0, 500.0])
    np.testing.assert_allclose(pts2[1:], [[50.0, 60.0, 10.0]] * 2)
    np.testing.assert_allclose(pts2[0], [50.0, 45.0, 10.0])


def test_pickle_round_trip(city: BuildingMap) -> None:
    clone = pickle.loads(pickle.dumps(city))
    assert clone.buildings == city.buildings and clone.name == city.name
    np.testing.assert_array_equal(clone.bounds_max_m, city.bounds_max_m)
    pts = np.random.default_rng(3).uniform([0, 0, 0], [1000, 1000, 200], size=(300, 3))
    np.testing.assert_array_equal(clone.clearance(pts, 1.0).distance_m, city.clearance(pts, 1.0).distance_m)
    np.testing.assert_allclose(clone.clearance(pts, 1.0, backend="fcl").distance_m,
                               city.clearance(pts, 1.0).distance_m, atol=1e-9)
    assert clone.segment_free([10.0, 500.0, 280.0], [990.0, 500.0, 280.0], 1.0)


def test_results_are_read_only(city: BuildingMap) -> None:
    res = city.clearance(np.array([[10.0, 10.0, 10.0]]))
    with pytest.raises(ValueError):
        res.distance_m[0] = 0.0


def test_empty_map_is_ground_only() -> None:
    bmap = BuildingMap([], (0, 0, 0), (10, 10, 10))
    pts = np.array([[1.0, 2.0, 3.0]])
    assert bmap.clearance(pts, 1.0).distance_m.tolist() == [2.0]
    assert bmap.clearance(pts, 1.0, backend="fcl").distance_m.tolist() == [2.0]
    assert bmap.clearance_one(1.0, 2.0, 3.0, 1.0) == 2.0
    assert bmap.segment_free([1, 1, 2], [9, 9, 3], 1.0) and not bmap.segment_free([1, 1, 2], [9, 9, 0.5], 1.0)
    _, d3 = bmap.nearest_obstacles([1, 2, 3], 2)
    assert d3.tolist() == [math.inf, math.inf]


def test_invalid_geometry_is_rejected() -> None:
    with pytest.raises(ValueError):
        Building(0, (0.0, 0.0), (0.0, 5.0), 10.0)
    with pytest.raises(ValueError):
        Prism(0, ((0.0, 0.0), (0.0, 10.0), (10.0, 0.0)), 5.0)  # clockwise
    with pytest.raises(ValueError):
        BuildingMap([Building(0, (5.0, 5.0), (20.0, 2.0), 5.0)], (0, 0, 0), (100, 100, 100))  # leaves bounds


def test_leaving_out_boxes_that_cannot_be_nearest_changes_no_answer(monkeypatch):
    """`nearest_parts` skips, per chunk of points, the boxes that cannot be any point's nearest: the same distances
    and parts (ties included) as the exhaustive search, for points along a path and scattered ones."""
    rng = np.random.default_rng(5)
    centres = rng.uniform(20.0, 280.0, (400, 2))
    boxes = [Building(i, tuple(c), tuple(rng.uniform(1.0, 12.0, 2)), float(rng.uniform(3.0, 60.0)),
                      yaw_rad=float(rng.uniform(-3.0, 3.0))) for i, c in enumerate(centres)]
    boxes.append(Building(400, tuple(centres[0]), boxes[0].size_xy_m, boxes[0].height_m, boxes[0].yaw_rad))  # a tie
    packed = BuildingMap(boxes, (0.0, 0.0, 0.0), (300.0, 300.0, 100.0))._packed
    path = np.cumsum(rng.normal(0.0, 0.3, (2000, 3)), axis=0) + (150.0, 150.0, 20.0)
    points = np.vstack([path, rng.uniform((0.0, 0.0, 0.0), (300.0, 300.0, 80.0), (1000, 3)), [[*centres[0], 1.0]]])
    pruned = distance.nearest_parts(points, packed)
    monkeypatch.setattr(distance, "_PRUNE_FROM", 10**9)
    exhaustive = distance.nearest_parts(points, packed)
    assert np.array_equal(pruned[0], exhaustive[0]) and np.array_equal(pruned[1], exhaustive[1])
    assert pruned[1][-1] == 0  # the tie goes to the lower index
