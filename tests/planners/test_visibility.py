"""Lines of sight along the path ahead, and the speed that stops within them (`planners.visibility`), as the
classical pilot's reference clock uses them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planners.visibility import arc_in_sight_m, in_sight, stopping_speed_m_s
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.raycast import RayCaster

# a block beside the first leg of an L-shaped path (east along y = 0, then north along x = 30): its corner at (28, 2)
BLOCK = Building(0, (24.0, 11.0), (8.0, 18.0), 30.0)
BOUNDS = ((-10.0, -30.0, 0.0), (80.0, 60.0, 50.0))


def _l_path(step_m: float = 0.25) -> np.ndarray:
    east = np.column_stack([np.arange(0.0, 30.0, step_m), np.zeros(int(30 / step_m)), np.full(int(30 / step_m), 10.0)])
    north = np.column_stack([np.full(81, 30.0), np.linspace(0.0, 20.0, 81), np.full(81, 10.0)])
    return np.vstack([east, north])


def _arc(eye, path, caster, max_range_m, tube_m=0.0, **fan) -> float:
    return arc_in_sight_m(path, in_sight(eye, path, caster, max_range_m, tube_m, **fan))


def test_the_arc_in_sight_ends_where_the_block_hides_the_path():
    caster = RayCaster(BuildingMap([BLOCK], *BOUNDS), ground=False)
    path = _l_path()
    eye = path[0]
    arc = _arc(eye, path, caster, 100.0)
    # from (0, 0): the north leg is in sight up to y = 2 * 30 / 28 (the line of sight grazes the corner (28, 2))
    assert 30.0 + 2.0 <= arc <= 30.0 + 2.0 * 30.0 / 28.0 + 0.25
    assert _arc(eye, path, RayCaster(BuildingMap([], *BOUNDS), ground=False), 100.0) == math.inf
    assert _arc(eye, path, caster, 20.0) == pytest.approx(20.0)  # the lidar's range ends it sooner
    # seen from inside the bend (east of the block's face) the whole leg is in sight
    assert _arc(np.array([30.0, 0.0, 10.0]), path[120:], caster, 100.0) == math.inf
    assert _arc(eye, path[:1], caster, 100.0) == math.inf
    # the tube 1 m round the path: hidden no later than its centre line
    tube = _arc(eye, path, caster, 100.0, tube_m=1.0)
    assert 30.0 - 1.0 <= tube <= arc
    assert _arc(eye, path[:100], caster, 100.0, tube_m=1.0) == math.inf  # the east leg's tube is in sight


def test_the_tube_beside_a_known_face_ends_at_the_face():
    """A path 0.5 m from a known wall with a tube of 1 m: the tube's points beyond the face are known (the wall),
    not unseen; the path is in sight along the wall, as it would be without the tube, and a block across the path
    still hides what lies behind it."""
    wall = Building(0, (15.0, 1.5), (30.0, 2.0), 30.0)  # its south face at y = 0.5, the path along y = 0
    caster = RayCaster(BuildingMap([wall], *BOUNDS), ground=False)
    path = _l_path()[:120]
    eye = path[0] + np.array([0.0, -0.2, 0.0])
    assert _arc(eye, path, caster, 100.0, tube_m=1.0) == math.inf
    across = Building(1, (20.0, 0.0), (1.0, 6.0), 30.0)  # a slab across the path at x = 19.5..20.5
    blocked = RayCaster(BuildingMap([wall, across], *BOUNDS), ground=False)
    assert 18.0 <= _arc(eye, path, blocked, 100.0, tube_m=1.0) <= 19.5


def test_a_fan_fixed_to_a_body_tilted_forward_does_not_see_the_level_path_ahead():
    """A +-15 degree fan on a body pitched 30 degrees nose down (flying east) looks 45 to 15 degrees below the horizon
    ahead: the level path ahead is out of it beyond the first metre; level, the fan sees it; a climb steeper than
    the fan is not asked to be in it."""
    caster = RayCaster(BuildingMap([], *BOUNDS), ground=False)
    path = _l_path()[:120]  # east, level, 30 m
    pitch = math.radians(30.0)  # nose down: the body's x axis points east and below the horizon
    nose_down = np.array([[math.cos(pitch), 0.0, math.sin(pitch)], [0.0, 1.0, 0.0],
                          [-math.sin(pitch), 0.0, math.cos(pitch)]])
    fan = (-15.0, 15.0)
    tilted = in_sight(path[0], path, caster, 100.0, body_to_world=nose_down, fov_deg=fan)
    assert not tilted[8:].any() and tilted[:4].all()  # beyond 1 m nothing; within it, taken as seen
    assert in_sight(path[0], path, caster, 100.0, body_to_world=np.eye(3), fov_deg=fan).all()
    climb = np.column_stack([np.zeros(40), np.zeros(40), 10.0 + np.arange(40) * 0.5])  # straight up
    assert in_sight(climb[0], climb, caster, 100.0, body_to_world=nose_down, fov_deg=fan).all()
    # at rest and level below a path climbing at 35 degrees: above the fan of any attitude flown, not asked of it
    # (asked, the vehicle would wait for ever)
    slope = math.radians(35.0)
    steady = np.column_stack([np.arange(40) * 0.5 * math.cos(slope), np.zeros(40), 10.0 + np.arange(40) * 0.5
                              * math.sin(slope)])
    assert in_sight(steady[0] - np.array([0.0, 0.0, 0.5]), steady, caster, 100.0, body_to_world=np.eye(3),
                    fov_deg=fan).all()
    # rolled 90 degrees about the direction of flight the fan stands vertical, and still holds the path ahead
    rolled = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    assert in_sight(path[0], path, caster, 100.0, body_to_world=rolled, fov_deg=fan).all()
    assert arc_in_sight_m(path, tilted) == pytest.approx(float(np.linalg.norm(path[np.argmin(tilted)] - path[0]))
                                                         - 0.25)


def test_the_stopping_speed_reacts_then_brakes_within_the_distance():
    v = stopping_speed_m_s(20.0, 4.0, 0.5)
    assert v * 0.5 + v * v / 8.0 == pytest.approx(20.0)
    assert stopping_speed_m_s(20.0, 4.0, 0.0) == pytest.approx(math.sqrt(160.0))
    assert stopping_speed_m_s(-3.0, 4.0, 0.5) == 0.0 and stopping_speed_m_s(math.inf, 4.0, 0.5) == math.inf
    with pytest.raises(ValueError, match="decel_m_s2"):
        stopping_speed_m_s(1.0, 0.0, 0.5)
