"""Lines of sight along the path ahead, and the speed that stops within them (`planners.visibility`), as the
classical pilot's reference clock uses them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from planners.visibility import stopping_speed_m_s, visible_arc_m
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.sensing.raycast import RayCaster

# a block beside the first leg of an L-shaped path (east along y = 0, then north along x = 30): its corner at (28, 2)
BLOCK = Building(0, (24.0, 11.0), (8.0, 18.0), 30.0)
BOUNDS = ((-10.0, -30.0, 0.0), (80.0, 60.0, 50.0))


def _l_path(step_m: float = 0.25) -> np.ndarray:
    east = np.column_stack([np.arange(0.0, 30.0, step_m), np.zeros(int(30 / step_m)), np.full(int(30 / step_m), 10.0)])
    north = np.column_stack([np.full(81, 30.0), np.linspace(0.0, 20.0, 81), np.full(81, 10.0)])
    return np.vstack([east, north])


def test_the_visible_arc_ends_where_the_block_hides_the_path():
    caster = RayCaster(BuildingMap([BLOCK], *BOUNDS), ground=False)
    path = _l_path()
    eye = path[0]
    arc = visible_arc_m(eye, path, caster, 100.0)
    # from (0, 0): the north leg is in sight up to y = 2 * 30 / 28 (the line of sight grazes the corner (28, 2))
    assert 30.0 + 2.0 <= arc <= 30.0 + 2.0 * 30.0 / 28.0 + 0.25
    assert visible_arc_m(eye, path, RayCaster(BuildingMap([], *BOUNDS), ground=False), 100.0) == math.inf
    assert visible_arc_m(eye, path, caster, 20.0) == pytest.approx(20.0)  # the lidar's range ends it sooner
    # seen from inside the bend (east of the block's face) the whole leg is in sight
    assert visible_arc_m(np.array([30.0, 0.0, 10.0]), path[120:], caster, 100.0) == math.inf
    assert visible_arc_m(eye, path[:1], caster, 100.0) == math.inf
    # the tube 1 m round the path: hidden no later than its centre line
    tube = visible_arc_m(eye, path, caster, 100.0, tube_m=1.0)
    assert 30.0 - 1.0 <= tube <= arc
    assert visible_arc_m(eye, path[:100], caster, 100.0, tube_m=1.0) == math.inf  # the east leg's tube is in sight


def test_the_stopping_speed_reacts_then_brakes_within_the_distance():
    v = stopping_speed_m_s(20.0, 4.0, 0.5)
    assert v * 0.5 + v * v / 8.0 == pytest.approx(20.0)
    assert stopping_speed_m_s(20.0, 4.0, 0.0) == pytest.approx(math.sqrt(160.0))
    assert stopping_speed_m_s(-3.0, 4.0, 0.5) == 0.0 and stopping_speed_m_s(math.inf, 4.0, 0.5) == math.inf
    with pytest.raises(ValueError, match="decel_m_s2"):
        stopping_speed_m_s(1.0, 0.0, 0.5)
