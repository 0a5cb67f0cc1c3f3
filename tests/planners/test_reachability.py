"""The two-sided reachability test (planners.reachability): proved reachable, proved unreachable, undetermined,
on the dead-end alley (open to a 1 m margin, closed to 4 m; walled in when closed) and in the open."""
from __future__ import annotations

import pytest

from alley import alley_city
from planners.reachability import check_reachable
from uam_fdm.city.buildings import Building, BuildingMap

R_QUAD = 0.42


def test_the_alley_is_reachable_at_the_floor_margin_and_not_at_the_cruise_margin():
    city, start, goal = alley_city(R_QUAD)
    beside = (-30.0, 25.0, 10.0)  # the straight line to the goal crosses a block: the grid decides
    ok = check_reachable(city, beside, goal, R_QUAD, 1.0)
    assert ok.verdict == "reachable" and ok.cells > 0 and "exists" in ok.reason
    # 4 m: the alley's centre line is r + 3 m from its walls and its ends reach the 40 m ceiling; the goal
    # inside it is accepted (its own clearance, 2.1 m around it) but no way in keeps 4 m
    narrow = check_reachable(city, start, goal, R_QUAD, 4.0)
    assert narrow.verdict == "unreachable" and "no connected free space" in narrow.reason
    assert narrow.cell_m < R_QUAD + 4.0  # finer than the first grid (cells of R): it took a refinement


def test_a_walled_in_goal_is_proved_unreachable():
    city, start, goal = alley_city(R_QUAD, closed=True)
    found = check_reachable(city, start, goal, R_QUAD, 1.0)
    assert found.verdict == "unreachable" and found.margin_m == 1.0


def test_the_straight_line_and_invalid_ends_need_no_grid():
    city, start, _ = alley_city(R_QUAD)
    assert check_reachable(city, start, (-5.0, 25.0, 10.0), R_QUAD, 1.0).cells == 0
    inside = check_reachable(city, start, (15.0, 20.0, 10.0), R_QUAD, 1.0)  # in a block
    assert inside.verdict == "unreachable" and inside.reason == "the goal itself is not valid at margin 1.00 m"


def test_what_the_grid_cannot_decide_is_undetermined_and_says_at_which_cell():
    city, start, goal = alley_city(R_QUAD)
    # the 4 m case above needs cells of about 2.2 m; allowed only the first grid (cells of R = 4.42 m)
    coarse = check_reachable(city, start, goal, R_QUAD, 4.0, max_cells=5000)
    assert coarse.verdict == "undetermined" and coarse.cell_m > 4.0 and 0 < coarse.cells <= 5000
    assert f"down to a {coarse.cell_m:.2f} m grid" in coarse.reason
    none = check_reachable(city, start, goal, R_QUAD, 4.0, max_cells=10)
    assert none.verdict == "undetermined" and none.cells == 0 and "more than 10 cells" in none.reason


def test_over_a_low_wall_is_a_way():
    """A wall across the way but lower than the ceiling: the path goes over it (the test is 3-D)."""
    wall = Building(0, (0.0, 0.0), (2.0, 80.0), 20.0)
    city = BuildingMap([wall], (-40.0, -40.0, 0.0), (40.0, 40.0, 40.0), name="wall")
    assert check_reachable(city, (-20.0, 0.0, 5.0), (20.0, 0.0, 5.0), R_QUAD, 1.0).verdict == "reachable"
    tall = BuildingMap([Building(0, (0.0, 0.0), (2.0, 80.0), 40.0)], (-40.0, -40.0, 0.0), (40.0, 40.0, 40.0))
    assert check_reachable(tall, (-20.0, 0.0, 5.0), (20.0, 0.0, 5.0), R_QUAD, 1.0).verdict == "unreachable"


def test_bad_arguments_are_named():
    city, start, goal = alley_city(R_QUAD)
    with pytest.raises(ValueError, match="margin_m"):
        check_reachable(city, start, goal, R_QUAD, -1.0)
    with pytest.raises(ValueError, match="cell_m"):
        check_reachable(city, start, goal, R_QUAD, 1.0, cell_m=0.0)
