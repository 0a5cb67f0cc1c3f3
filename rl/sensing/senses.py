"""The pilot's senses of a state, shared by the environment and the flying pilot: the exact clearance
sensor and the nearest surface, the route fields of a task, and the observation assembled from them."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rl.sensing.observation import (
    OBS_CLIP,
    ObservationScales,
    ObservedContext,
    PilotMemory,
    Surroundings,
    build_observations,
    context_elements,
)
from rl.sensing.perception import Perception, PerceptionConfig, PerceptionReading
from rl.sensing.route import LeveledRoute, RouteBank, RouteConfig, flight_levels, leveled_route
from rl.sensing.sensor import BoxSensor
from rl.sensing.truth import TruthSensing
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Task
from uam_fdm.vehicle.params import VehicleParams


def clearance_sensor(cities: Sequence[BuildingMap], scales: ObservationScales, radius_m: float) -> BoxSensor:
    """The exact clearance sensor of a task (range `scales.clearance_m`) for a vehicle of collision
    radius `radius_m` [m]. Its candidate grid's cells are a third of the range (10 m at least): the
    readings are exact whatever the cell, the cell only trades memory for work."""
    rng = scales.clearance_m
    return BoxSensor(cities, 1, rng, radius_m, cell_m=max(10.0, rng / 3.0))


def route_for(city: BuildingMap, task: Task, radius_m: float, config: RouteConfig,
              columns: np.ndarray | None = None) -> LeveledRoute:
    """The geodesic route fields of a task at its flight levels (`rl.sensing.route.flight_levels`: the
    higher of start and goal alone, or levels from the lower to the higher), with `columns` (K, 5) standing
    beside the city's buildings (`rl.sensing.route.route_field`)."""
    levels = flight_levels(task.start_m[2], task.goal_m[2], config.level_step_m)
    return leveled_route(city, task.goal_m, levels, radius_m, config, columns)


def nearest_surface(sensor: BoxSensor | TruthSensing, points_m: np.ndarray,
                    city: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clearance (N,) [m] and the vector (N, 3) [m, world] to the nearest surface point (a building
    within the sensor's range, or the ground; zero when neither is within range). `city`: the points' city
    indices of a `BoxSensor`, or their truths' indices of a `TruthSensing`."""
    r = sensor.query(points_m, city)
    vec = r.nearest_m[:, 0, :] - points_m  # zero for an empty row (the nearest point is the query point)
    ground = ((points_m[:, 2] - sensor.radius_m < r.distance_m[:, 0])
              & (points_m[:, 2] - sensor.radius_m < sensor.range_m))
    vec[ground] = 0.0
    vec[ground, 2] = -points_m[ground, 2]
    return r.clearance_m, vec


def observe_slots(idx: np.ndarray, x: np.ndarray, goal_m: np.ndarray, route_m: np.ndarray, clearance_m: np.ndarray,
                  nearest_m: np.ndarray, t_frac: np.ndarray, city: np.ndarray, perception: Perception | TruthSensing,
                  routes: RouteBank, memory: PilotMemory, perception_config: PerceptionConfig,
                  scales: ObservationScales, decision_hz: float, vehicle: VehicleParams,
                  observe: ObservedContext | None = None, around: Surroundings | None = None,
                  reading: PerceptionReading | None = None, position_sigma_m: np.ndarray | None = None) -> np.ndarray:
    """Observations (M, obs) of slots idx (the env's batch, or the learned pilot's single slot).

    Args:
        idx: (M,) slots of `routes` and `memory`; x: (M, nx) states; goal_m: (M, 3) [m];
        route_m: (M,) Φ [m]; clearance_m: (M,) [m]; nearest_m: (M, 3) vector to the nearest surface [m];
        t_frac: (M,) time used / limit;
        city: (M,) city indices of `perception` (truth indices of a `TruthSensing`).
        perception_config, scales, decision_hz, observe: the task's (`rl.task.config.NavConfig`).
        around: the vehicles' surroundings, when `observe` asks for the air or the geofence.
        reading: the rays and height maps when measured (the lidar's, `rl.sensing.lidar_view`); None: the exact
            ones of `perception` (the truth's slab tests).
        position_sigma_m: (M,) the estimates' position sigma along their longest axis [m], when `observe` asks for
            the uncertainty (None: 0, flying on the truth).
    """
    pos = x[:, 0:3]
    heading = memory.heading_rad[idx]
    if reading is None:
        reading = perception.observe(pos, heading, city)
    obs = build_observations(x, goal_m, heading, route_m, routes.direction(pos, idx), clearance_m, nearest_m,
                             memory.prev_action[idx], memory.route_history_m[idx], t_frac, reading,
                             perception_config, vehicle, decision_hz, scales)
    if observe is None or not observe.size():
        return obs
    extra = context_elements(observe, x, heading, memory.velocity_history[idx], memory.action_history[idx], around,
                             vehicle, scales, position_sigma_m)
    return np.concatenate([obs, np.clip(extra, -OBS_CLIP, OBS_CLIP).astype(np.float32)], axis=1)
