"""The learned pilot's lidar-measured obstacle senses (rl.sensing.lidar_view): against the exact senses on a city
built so that a sector's nearest return is the exact ray's hit, with a noiseless, dropout-free, dense lidar and the
estimate = the truth; the height memory (a building the prior lacks appears once sensed, stays, is forgotten when
reset or left behind); the ground band; the rays' band; slot independence; determinism; refused configurations."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rl.sensing.lidar_view import LidarView, LidarViewConfig, ObstacleSenses
from rl.sensing.observation import ObservationScales
from rl.sensing.perception import Perception, PerceptionConfig
from rl.sensing.senses import clearance_sensor, nearest_surface
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.lidar import Lidar, LidarScan
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import VLP16
from uam_fdm.vehicle.attitude import rotation_matrix

R = 0.42  # collision radius [m]
CFG = PerceptionConfig()  # 16 rays of 40 m, 9 x 9 cells of 6 m
SCALES = ObservationScales()
# noiseless, no dropout, dense: 31 channels 1 deg apart over +-15 deg (one at the horizontal), columns 0.5 deg apart
DENSE = dataclasses.replace(VLP16, channels=31, horizontal_resolution_deg=0.5, range_noise_m=0.0,
                            range_noise_per_m=0.0, dropout=0.0, min_range_m=0.1)
BOUNDS = ([0.0, 0.0, 0.0], [400.0, 400.0, 100.0])
CX, CY = 100.0, 100.0
CENTRE = np.array([CX, CY])
HEADING = 0.3  # the goal frame's heading [rad]; the vehicle's yaw is another (YAW)
YAW = 1.0
# A return's horizontal bearing lies within half a column of some beam's, its direction within half the beam grid's
# diagonal of the nearest point's: tolerances from the spacing (Embree's float32 adds ~1e-4 m).
COLUMN_RAD = math.radians(DENSE.horizontal_resolution_deg)
DIAGONAL_RAD = math.hypot(COLUMN_RAD, math.radians(30.0 / (DENSE.channels - 1))) / 2.0


def _quaternion(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Z-Y-X Euler angles [rad] as a unit quaternion [w, x, y, z], body FLU -> world ENU."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy])


def _state(x: float, y: float, z: float, roll: float = 0.05, pitch: float = -0.03, yaw: float = YAW) -> np.ndarray:
    s = np.zeros(13)
    s[0:3], s[6:10] = (x, y, z), _quaternion(roll, pitch, yaw)
    return s


def _wall_box(i: int, sector: int, distance_m: float, height_m: float, depth_m: float = 6.0,
              width_m: float = 4.0) -> Building:
    """A box in ray `sector`'s wedge around CENTRE, its near face `distance_m` away and square to the ray, narrow
    enough to lie inside the wedge (so the sector's nearest return is where the exact ray enters the box)."""
    bearing = HEADING + 2.0 * math.pi * sector / CFG.n_rays
    c = CENTRE + (distance_m + 0.5 * depth_m) * np.array([math.cos(bearing), math.sin(bearing)])
    return Building(i, (float(c[0]), float(c[1])), (depth_m, width_m), height_m, yaw_rad=bearing)


# sectors 0, 3, 8, 11 at 15-30 m; the roof of sector 3's is above z - r at z = 10 only, sector 8's below both
WEDGES = BuildingMap([_wall_box(0, 0, 15.0, 30.0), _wall_box(1, 3, 20.0, 11.0), _wall_box(2, 8, 25.0, 6.0),
                      _wall_box(3, 11, 30.0, 40.0)], *BOUNDS)
TOWER = Building(9, (112.0, 88.0), (5.0, 5.0), 18.0)  # the building the prior lacks (sector 14, ~16 m away)
TRUTH = BuildingMap(list(WEDGES.buildings) + [TOWER], *BOUNDS)
OPEN = BuildingMap([], *BOUNDS)


def _scan(city: BuildingMap, x: np.ndarray, t_s: float = 0.0) -> LidarScan:
    """A scan of `city` from the true state x (13,)."""
    lidar = Lidar(DENSE, RayCaster(city), np.random.default_rng(0))
    return lidar.scan(t_s, x[0:3], rotation_matrix(x[6:10]))[0]


def _view(prior: BuildingMap, n: int = 1, config: LidarViewConfig | None = None) -> LidarView:
    view = LidarView(Perception([prior], R, CFG), n, DENSE, SCALES.clearance_m, config or LidarViewConfig())
    view.reset(np.arange(n), np.zeros(n, dtype=np.int64))
    return view


def _read(view: LidarView, slots, x: np.ndarray, heading: float = HEADING) -> ObstacleSenses:
    return view.read(slots, x, np.full(len(x), heading))


def _arrays(s: ObstacleSenses) -> list[np.ndarray]:
    return [s.reading.ray_m, s.reading.roof_m, s.clearance_m, s.nearest_m]


@pytest.fixture(scope="module")
def poses() -> np.ndarray:
    """Three vehicles at CENTRE: the ground nearer than any building (z = 10), a building nearer (z = 25), and one
    far from everything and high enough that no beam returns (z = 45)."""
    return np.stack([_state(CX, CY, 10.0), _state(CX, CY, 25.0), _state(330.0, 330.0, 45.0)])


def test_rays_clearance_and_nearest_match_the_exact_senses(poses) -> None:
    view = _view(WEDGES, 3)
    view.integrate([0, 1, 2], [(_scan(WEDGES, x),) for x in poses], poses)
    got = _read(view, [0, 1, 2], poses)
    city = np.zeros(3, dtype=np.int64)
    exact = Perception([WEDGES], R, CFG).observe(poses[:, 0:3], np.full(3, HEADING), city)
    assert np.count_nonzero(exact.ray_m < CFG.ray_range_m) == 5  # 4 walls at z = 10, 2 at z = 25 (one wall twice)
    # a sector's nearest return lies at most a column's bearing off the face's foot: d / cos(column) - d
    ray_tol = 30.0 * (1.0 / math.cos(COLUMN_RAD) - 1.0) + 1e-3
    np.testing.assert_allclose(got.reading.ray_m, exact.ray_m, rtol=0.0, atol=ray_tol)
    clear, nearest = nearest_surface(clearance_sensor([WEDGES], SCALES, R), poses[:, 0:3], city)
    np.testing.assert_allclose(got.clearance_m, clear, rtol=0.0, atol=15.0 * (1.0 / math.cos(DIAGONAL_RAD) - 1) + 1e-3)
    # the nearest return is within half the beam grid's diagonal of the face's nearest point, 15 m away
    np.testing.assert_allclose(got.nearest_m, nearest, rtol=0.0, atol=15.0 * math.tan(DIAGONAL_RAD) + 1e-3)
    np.testing.assert_array_equal(got.nearest_m[0], [0.0, 0.0, -10.0])  # the ground, exactly
    np.testing.assert_array_equal(got.nearest_m[2], [0.0, 0.0, 0.0])  # nothing within the clearance range
    assert got.clearance_m[2] == SCALES.clearance_m


def test_a_building_the_prior_lacks_appears_in_the_height_map_only_once_sensed() -> None:
    x = _state(CX, CY, 10.0)[None]
    view = _view(WEDGES)
    prior, tower = _roofs(WEDGES, x), _tower_cells(x)
    before = _read(view, [0], x).reading.roof_m
    np.testing.assert_array_equal(before, prior)
    assert len(tower) and np.all(prior[0, tower] == 0.0)
    view.integrate([0], [(_scan(TRUTH, x[0]),)], x)
    after = _read(view, [0], x).reading.roof_m
    assert np.all(after >= prior)  # never below the prior
    top = after[0, tower].max()
    assert x[0, 2] < top <= TOWER.height_m + 0.1  # the highest return seen (the top channel: ~14 m), rounded up
    # a later scan that returns nothing: the memory holds the tower; a reset forgets it
    view.integrate([0], [(LidarScan(0.1, np.zeros((0, 3)), np.zeros(0)),)], x)
    np.testing.assert_array_equal(_read(view, [0], x).reading.roof_m, after)
    view.reset([0], [0])
    np.testing.assert_array_equal(_read(view, [0], x).reading.roof_m, prior)


def _roofs(city: BuildingMap, x: np.ndarray) -> np.ndarray:
    """`Perception`'s height map of `city` around the state x (1, 13) in the goal frame at HEADING."""
    return Perception([city], R, CFG).roofs(x[:, 0:3], np.array([HEADING]), np.zeros(1, dtype=np.int64))


def _tower_cells(x: np.ndarray) -> np.ndarray:
    """The height-map cells around x (1, 13) that the tower raises."""
    return np.flatnonzero(_roofs(TRUTH, x)[0] > _roofs(WEDGES, x)[0])


def test_the_height_memory_forgets_what_its_window_leaves_behind() -> None:
    """The window (memory range 60 m: 41 cells of 3 m, 61.5 m either way of its centre cell) follows the vehicle
    east: the tower, 12 m east of the start, stays in it 50 m on and leaves it 80 m on."""
    x = _state(CX, CY, 10.0)[None]
    view = _view(WEDGES, config=LidarViewConfig(memory_range_m=60.0))
    view.integrate([0], [(_scan(TRUTH, x[0]),)], x)
    tower = _tower_cells(x)
    sensed = _read(view, [0], x).reading.roof_m[0, tower]
    assert np.all(sensed > 10.0)
    nothing = (LidarScan(0.0, np.zeros((0, 3)), np.zeros(0)),)
    away = x.copy()
    away[0, 0] += 50.0
    view.integrate([0], [nothing], away)
    np.testing.assert_array_equal(_read(view, [0], x).reading.roof_m[0, tower], sensed)
    away[0, 0] += 30.0
    view.integrate([0], [nothing], away)
    assert np.all(_read(view, [0], x).reading.roof_m[0, tower] == 0.0)
    view.integrate([0], [nothing], x)  # back: the window holds the tower's cells again, forgotten
    assert np.all(_read(view, [0], x).reading.roof_m[0, tower] == 0.0)


def test_ground_returns_are_never_obstacles_with_the_estimate_off_in_height() -> None:
    """In an open city every return is the ground: placed on an estimate 1 m too high (sigma 0.4 m: a band of
    0.5 + 3 x 0.4 m), none is an obstacle; with the estimate claimed exact (sigma 0) they are."""
    truth = _state(200.0, 200.0, 3.0)
    est = truth.copy()
    est[2] += 1.0
    scan = (_scan(OPEN, truth),)
    assert len(scan[0].ranges_m) > 1000
    view = _view(OPEN)
    view.integrate([0], [scan], est[None], np.array([0.4]))
    got = _read(view, [0], est[None])
    assert np.all(got.reading.ray_m == CFG.ray_range_m)
    assert np.all(got.reading.roof_m == 0.0)
    assert got.clearance_m[0] == est[2] - R
    np.testing.assert_array_equal(got.nearest_m[0], [0.0, 0.0, -est[2]])
    overconfident = _view(OPEN)
    overconfident.integrate([0], [scan], est[None], np.array([0.0]))
    wrong = _read(overconfident, [0], est[None])
    assert wrong.reading.roof_m.max() > 0.5  # the ground, 1 m up


def test_the_rays_band_reaches_band_above_m_over_the_sphere() -> None:
    """A raised slab (a crane's jib) over the vehicle's path: a ray when its underside is within `band_above_m` of
    the collision sphere's top, not when it is higher (where `Perception`, reading every box as a column, sees it)."""
    x = _state(CX, CY, 10.0, roll=0.0, pitch=0.0)[None]
    reads = []
    for base in (10.0 + R + 1.5, 10.0 + R + 2.5):
        jib = BuildingMap([Building(0, (CX + 15.0, CY), (4.0, 30.0), base + 2.0,
                                    base_m=base)], *BOUNDS)
        view = _view(jib)
        view.integrate([0], [(_scan(jib, x[0]),)], x)
        reads.append(_read(view, [0], x, heading=0.0).reading.ray_m[0, 0])
    assert reads[0] == pytest.approx(13.0 - R, abs=2e-3)
    assert reads[1] == CFG.ray_range_m


def test_kept_points_are_read_from_the_current_estimate_until_the_next_scan() -> None:
    """Slot 0 keeps its scan's points while no new scan comes, and drops them for a scan of nothing, read beside
    slot 1, which keeps a full scan from the same pose."""
    x = _state(CX, CY, 10.0)[None]
    view = _view(WEDGES, 2)
    view.integrate([0, 1], [(_scan(WEDGES, x[0]),)] * 2, np.repeat(x, 2, axis=0))
    ahead = _read(view, [0], x).reading.ray_m[0, 0]
    moved = x.copy()
    moved[0, 0:2] += 2.0 * np.array([math.cos(HEADING), math.sin(HEADING)])
    view.integrate([0], [()], moved)  # a decision without a scan keeps the points
    assert _read(view, [0], moved).reading.ray_m[0, 0] == pytest.approx(ahead - 2.0, abs=1e-3)
    view.integrate([0], [(LidarScan(0.2, np.zeros((0, 3)), np.zeros(0)),)], moved)  # a scan of nothing: none kept
    got = _read(view, [0, 1], np.concatenate([moved, x]))
    assert np.all(got.reading.ray_m[0] == CFG.ray_range_m) and np.any(got.reading.ray_m[1] < CFG.ray_range_m)
    np.testing.assert_array_equal(got.nearest_m[0], [0.0, 0.0, -10.0])


def test_a_stamped_scan_is_placed_on_its_stamp_not_on_the_decisions_estimate() -> None:
    """The vehicle turned and moved between its scan and the decision: the scan's points land where its stamp (the
    pose estimated at the scan) puts them, as a scan placed on that pose at the decision itself would."""
    then = _state(CX, CY, 10.0)[None]
    scan = _scan(WEDGES, then[0])
    stamped = dataclasses.replace(scan, pose_estimate=np.concatenate((then[0, 0:3], then[0, 6:10])))
    now = _state(CX + 1.5, CY - 0.5, 10.4, yaw=0.3)[None]
    on_stamp, at_then = _view(WEDGES, 1), _view(WEDGES, 1)
    on_stamp.integrate([0], [(stamped,)], now)
    at_then.integrate([0], [(scan,)], then)
    np.testing.assert_array_equal(on_stamp._points, at_then._points)
    unstamped = _view(WEDGES, 1)
    unstamped.integrate([0], [(scan,)], now)  # without its stamp: placed on the decision's estimate, elsewhere
    assert not np.array_equal(unstamped._points, at_then._points)


def _decisions(poses: np.ndarray) -> list[tuple[list[tuple[LidarScan, ...]], np.ndarray, np.ndarray]]:
    """Two decisions of the three poses: the first with one, two and no scans, the second moved, one scan each."""
    first = [(_scan(TRUTH, poses[0]),), (_scan(WEDGES, poses[1]), _scan(TRUTH, poses[1], 0.1)), ()]
    moved = poses.copy()
    moved[:, 0] += 0.7
    second: list[tuple[LidarScan, ...]] = [(_scan(TRUTH, p, 0.2),) for p in moved]
    return [(first, poses, np.array([0.3, 0.0, 1.1])), (second, moved, np.array([0.2, 0.5, 0.0]))]


HEADINGS = np.array([HEADING, -2.0, 1.2])  # the three slots' goal frames


def test_a_slots_reading_depends_neither_on_the_other_slots_nor_on_m(poses) -> None:
    together = _view(WEDGES, 5)
    slots = [4, 0, 2]
    alone = [_view(WEDGES) for _ in slots]
    for scans, est, sigma in _decisions(poses):
        together.integrate(slots, scans, est, sigma)
        both = _arrays(together.read(slots, est, HEADINGS))
        for k, view in enumerate(alone):
            view.integrate([0], [scans[k]], est[k:k + 1], sigma[k:k + 1])
            for a, b in zip(both, _arrays(view.read([0], est[k:k + 1], HEADINGS[k:k + 1]))):
                np.testing.assert_array_equal(a[k:k + 1], b)


def test_the_same_inputs_give_identical_arrays(poses) -> None:
    runs = []
    for _ in range(2):
        view = _view(WEDGES, 3)
        out = []
        for scans, est, sigma in _decisions(poses):
            view.integrate([0, 1, 2], scans, est, sigma)
            out += _arrays(view.read([0, 1, 2], est, HEADINGS))
        runs.append(out)
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("field", "value"), [
    ("band_above_m", -0.1), ("band_above_m", math.inf), ("ground_band_m", -1.0), ("ground_band_m", math.nan),
    ("ground_sigmas", -3.0), ("sensed_cells_per_cell", 0), ("sensed_cells_per_cell", 9),
    ("sensed_cells_per_cell", 2.5), ("sensed_cells_per_cell", True), ("memory_range_m", 0.0),
    ("memory_range_m", math.inf)])
def test_bad_config_values_are_refused_naming_the_field(field: str, value) -> None:
    with pytest.raises(ValueError, match=f"LidarViewConfig.{field}"):
        LidarViewConfig(**{field: value})


def test_bad_view_arguments_are_refused() -> None:
    prior = Perception([WEDGES], R, CFG)
    with pytest.raises(ValueError, match="clearance_range_m"):
        LidarView(prior, 2, DENSE, 0.0)
    with pytest.raises(ValueError, match="at least one slot"):
        LidarView(prior, 0, DENSE, 30.0)
    view = _view(WEDGES, 2)
    x = _state(CX, CY, 10.0)[None]
    with pytest.raises(ValueError, match="distinct"):
        view.read([1, 1], np.repeat(x, 2, axis=0), np.zeros(2))
    with pytest.raises(ValueError, match="finite estimates"):
        view.integrate([0], [()], np.full((1, 13), np.nan))
