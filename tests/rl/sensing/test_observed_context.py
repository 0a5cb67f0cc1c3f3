"""The observation's optional context (`ObservedContext`): the air, the flight volume's edge, past decisions."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rl.sensing.observation import (
    TURBULENCE_VALUE,
    ObservationScales,
    ObservedContext,
    PilotMemory,
    Surroundings,
    context_elements,
)
from uam_fdm.air.wind import TurbulenceLevel
from uam_fdm.vehicle.params import load_vehicle

QUAD = load_vehicle("small_quad")
SCALES = ObservationScales()


def _state(p, v=(0.0, 0.0, 0.0)) -> np.ndarray:
    x = np.zeros((1, 13))
    x[0, 0:3], x[0, 3:6], x[0, 6] = p, v, 1.0
    return x


def _around(sigma: float = 0.8, level: TurbulenceLevel = TurbulenceLevel.MODERATE) -> Surroundings:
    return Surroundings(np.array([sigma]), np.array([TURBULENCE_VALUE[level]]), np.array([[0.0, 0.0, 0.0]]),
                        np.array([[400.0, 300.0, 120.0]]))


def test_the_air_is_the_density_ratio_less_one_and_the_forecast() -> None:
    e = context_elements(ObservedContext(air=True), _state((100, 100, 20)), np.zeros(1), np.zeros((1, 0, 3)),
                         np.zeros((1, 0, 3)), _around(0.8), QUAD, SCALES)
    np.testing.assert_allclose(e, [[0.8 - 1.0, 2.0 / 3.0]])


@pytest.mark.parametrize(("heading", "expected_dir"), [(0.0, (1.0, 0.0)), (math.pi / 2, (0.0, -1.0))])
def test_the_geofence_points_to_the_nearest_side_in_the_goal_frame(heading: float, expected_dir) -> None:
    """10 m from the east side (x = 400 m), 30 m below the ceiling: distance 0.1 goal scales towards +x (east),
    which is ahead facing east and to the right facing north."""
    e = context_elements(ObservedContext(geofence=True), _state((390, 150, 90)), np.array([heading]),
                         np.zeros((1, 0, 3)), np.zeros((1, 0, 3)), _around(), QUAD, SCALES)
    np.testing.assert_allclose(e[0], [0.1, *expected_dir, 30.0 / SCALES.altitude_m], atol=1e-12)
    far = context_elements(ObservedContext(geofence=True), _state((200, 150, 10)), np.zeros(1), np.zeros((1, 0, 3)),
                           np.zeros((1, 0, 3)), _around(), QUAD, SCALES)
    np.testing.assert_array_equal(far[0], [0.0, 0.0, 0.0, 1.0])  # beyond a goal scale: no direction; ceiling capped


def test_the_history_holds_past_velocities_and_actions_newest_first() -> None:
    m = PilotMemory.empty(1, 10.0, history=2)
    idx = np.zeros(1, dtype=np.int64)
    m.start(idx, np.zeros((1, 3)), np.ones((1, 3)), np.ones(1))
    m.record(idx, np.array([[0.1, 0.2, 0.3]]), np.ones(1), np.array([[6.0, 0.0, 1.0]]))
    m.record(idx, np.array([[-0.5, 0.0, 0.5]]), np.ones(1), np.array([[0.0, 12.0, 0.0]]))
    e = context_elements(ObservedContext(history=2), _state((0, 0, 10)), np.zeros(1), m.velocity_history,
                         m.action_history, None, QUAD, SCALES)
    c = QUAD.controller
    np.testing.assert_allclose(e[0], [0.0, 12.0 / c.max_speed_m_s, 0.0, -0.5, 0.0, 0.5,
                                      6.0 / c.max_speed_m_s, 0.0, 1.0 / c.max_vertical_speed_m_s, 0.1, 0.2, 0.3])


def test_observing_the_air_without_surroundings_is_refused() -> None:
    with pytest.raises(ValueError, match="needs the vehicles' surroundings"):
        context_elements(ObservedContext(air=True), _state((0, 0, 10)), np.zeros(1), np.zeros((1, 0, 3)),
                         np.zeros((1, 0, 3)), None, QUAD, SCALES)
    with pytest.raises(ValueError, match="observe.history"):
        ObservedContext(history=-1)
