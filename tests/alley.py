"""A dead-end alley narrower than twice a cruise margin of 4 m but open to 1-2 m, for the classical pilot's tests."""
from __future__ import annotations

from uam_fdm.city.buildings import Building, BuildingMap


def alley_city(radius_m: float, closed: bool = False, z_m: float = 10.0
               ) -> tuple[BuildingMap, tuple[float, float, float], tuple[float, float, float]]:
    """A 30 m dead-end alley whose centre line is radius + 3 m from its walls (40 m tall, the ceiling):
    open to a margin of 1 or 2 m, closed to 4 m. `closed`: a fourth block shuts its mouth.

    Returns:
        (city, start outside the alley, goal deep inside it), ENU metres, both at height `z_m`.
    """
    half = radius_m + 3.0
    blocks = [Building(0, (15.0, half + 10.0), (30.0, 20.0), 40.0),
              Building(1, (15.0, -half - 10.0), (30.0, 20.0), 40.0),
              Building(2, (35.0 + radius_m, 0.0), (10.0, 2 * half + 40.0), 40.0)]  # its face r + 5 m past the goal
    if closed:
        blocks.append(Building(3, (-1.0, 0.0), (2.0, 2 * half + 1.0), 40.0))
    city = BuildingMap(blocks, (-40.0, -40.0 - half, 0.0), (50.0 + radius_m, 40.0 + half, 40.0), name="alley")
    return city, (-30.0, 0.0, z_m), (25.0, 0.0, z_m)
