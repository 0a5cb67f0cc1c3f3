"""The learned pilot's observation, action and short memory, shared by the environment and the pilot.

Everything is expressed in the **goal frame**: a horizontal frame whose x' axis points from the
vehicle towards the goal (y' to its left, z up). The policy never sees absolute position or the
city's size, so what it learns transfers between cities, headings and map extents. The frame's
heading is held while the goal is within `HEADING_HOLD_M` horizontally (there the bearing is
ill-defined and would spin the whole observation).

Observation (float32, `obs_size(perception)` = 18 + n_rays + grid_cells² elements):

=====================  =====  ==================================================================
elements               count  meaning
=====================  =====  ==================================================================
0   goal distance        1    horizontal distance to the goal / goal scale (100 m)
1   goal height          1    (goal z - z) / height scale (20 m)
2   route distance       1    geodesic distance-to-go Φ (`rl.sensing.route`, around the buildings) / goal scale
3:5 route direction      2    the route's horizontal direction (steepest descent of Φ), goal frame
5:8 velocity             3    (v_x', v_y') / max horizontal speed, v_z / max vertical speed
8   altitude             1    z / altitude scale (50 m)
9   clearance            1    signed clearance of the collision sphere to buildings or the ground
                              / clearance scale (30 m; capped at 1)
10:13 previous action    3    the action of the previous decision (memory)
13  progress stall       1    (Φ now - Φ 2 s ago) / (max speed x 2 s): about -1 at full progress,
                              0 when stuck (memory)
14  time used            1    t / time limit (the time limit is part of the task)
15:18 nearest surface     3    vector to the nearest point of a building or the ground, goal frame,
                              / clearance scale (zero when nothing is within it): where the clearance is
18: rays              n_rays  horizontal sphere-cast distances / range, ray j at bearing 2πj/n
                              counter-clockwise from x' (`rl.sensing.perception`)
 .. height map        g²     (roof height - z) / height scale, clipped to [-1, 1], of a g x g grid of
                              cells around the vehicle in the goal frame (x' index slow)
=====================  =====  ==================================================================

The scales (in brackets: the small quad's) are an `ObservationScales` of the task: a vehicle ten
times larger and faster sees its world at its own scale (`rl.task.vehicles`).

Action: a = (a_x', a_y', a_z) in [-1, 1]³ in the goal frame: horizontal velocity command
(a_x', a_y') x max horizontal speed (its norm clipped to the max speed) rotated to the world, and
vertical a_z x max vertical speed. The heading is held at the episode's start yaw. The low-level
controller (`uam_fdm.vehicle.control`) turns the velocity command into rotor speeds at the physics rate;
the command is held for the whole decision period (several control periods).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rl.sensing.perception import PerceptionConfig, PerceptionReading
from uam_fdm.air.wind import TurbulenceLevel
from uam_fdm.pilot import VelocityCommand
from uam_fdm.vehicle.params import VehicleParams

N_BASE = 18
OBS_CLIP = 10.0
HEADING_HOLD_M = 1.0
STALL_WINDOW_S = 2.0


@dataclass(frozen=True)
class ObservationScales:
    """Length scales of the observation [m] (see the module table).

    Attributes:
        goal_m: horizontal goal and route distances.
        height_m: goal height difference and the height map's roof-minus-altitude (clipped at ±1).
        altitude_m: altitude above the ground.
        clearance_m: clearance and the nearest-surface vector; also the range within which the
            clearance is measured exactly (beyond it, it reads this value).
    """

    goal_m: float = 100.0
    height_m: float = 20.0
    altitude_m: float = 50.0
    clearance_m: float = 30.0

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"observation scale {k} must be positive and finite, got {v!r}")


TURBULENCE_VALUE = {TurbulenceLevel.NONE: 0.0, TurbulenceLevel.LIGHT: 1.0 / 3.0, TurbulenceLevel.MODERATE: 2.0 / 3.0,
                    TurbulenceLevel.SEVERE: 1.0}
"""The forecast turbulence level as an observation element."""


@dataclass(frozen=True)
class ObservedContext:
    """What the observation holds after the base elements and the perception (all off: the shipped layout).

    Attributes:
        air: the air as the pilot interface states it to every pilot (2 elements): the density ratio at
            the vehicle's altitude minus 1 (0 at sea level on a standard day, about -0.26 at a density
            altitude of 3 km: the thrust lost at the same rotor speed) and the forecast turbulence level
            (`TURBULENCE_VALUE`: none 0 ... severe 1).
        geofence: the flight volume's edge (4 elements): the horizontal distance to its nearest side
            / goal scale and the direction to that side in the goal frame (2), both zero beyond one goal
            scale, and the height below its ceiling / altitude scale, capped at 1.
        history: decisions remembered (0: none), each the velocity (goal frame, scaled as the base
            velocity) and the action taken then (6 elements per decision, newest first): from what was
            commanded and what followed the policy can infer its thrust margin and the wind.
        uncertainty: how far its own position may be off (1 element, after the others): the navigation
            estimate's position standard deviation along its covariance's longest axis / clearance scale, capped
            at 1 (0 at perfect sensing: the state is the truth).
    """

    air: bool = False
    geofence: bool = False
    history: int = 0
    uncertainty: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.history <= 50:
            raise ValueError(f"observe.history must be 0 to 50 decisions, got {self.history!r}")

    def size(self) -> int:
        """Number of elements it adds."""
        return 2 * self.air + 4 * self.geofence + 6 * self.history + self.uncertainty


@dataclass(frozen=True)
class Surroundings:
    """What a pilot is told about where its M vehicles fly (for `ObservedContext`'s air and geofence).

    Attributes:
        density_ratio: (M,) air density / sea-level standard at each vehicle's altitude.
        turbulence: (M,) forecast turbulence levels as `TURBULENCE_VALUE`s.
        lo_m, hi_m: (M, 3) the flight volume's corners [m, world].
    """

    density_ratio: np.ndarray
    turbulence: np.ndarray
    lo_m: np.ndarray
    hi_m: np.ndarray


def obs_size(perception: PerceptionConfig, observe: ObservedContext | None = None) -> int:
    """Observation length for a perception configuration and what else is observed."""
    return N_BASE + perception.n_rays + perception.grid_cells ** 2 + (observe.size() if observe else 0)


def context_elements(observe: ObservedContext, x: np.ndarray, heading_rad: np.ndarray, memory_vel: np.ndarray,
                     memory_act: np.ndarray, around: Surroundings | None, vehicle: VehicleParams,
                     scales: ObservationScales, position_sigma_m: np.ndarray | None = None) -> np.ndarray:
    """The `ObservedContext` elements (M, observe.size()) of M vehicles in states x (M, nx).

    Args:
        heading_rad: (M,) goal-frame headings; memory_vel: (M, K, 3) past world velocities [m/s] and
        memory_act: (M, K, 3) past actions, newest first (K >= observe.history); around: the vehicles'
        surroundings (needed for air and geofence); position_sigma_m: (M,) the estimates' position sigma along
        their longest axis [m] (for uncertainty; None: 0, the truth).
    """
    m = len(x)
    parts: list[np.ndarray] = []
    if observe.air or observe.geofence:
        if around is None:
            raise ValueError("observing the air or the geofence needs the vehicles' surroundings")
    if observe.air:
        assert around is not None
        parts.append(np.stack([around.density_ratio - 1.0, around.turbulence], axis=1))
    if observe.geofence:
        assert around is not None
        p = x[:, 0:3]
        sides = np.stack([p[:, 0] - around.lo_m[:, 0], around.hi_m[:, 0] - p[:, 0],
                          p[:, 1] - around.lo_m[:, 1], around.hi_m[:, 1] - p[:, 1]], axis=1)
        k = np.argmin(sides, axis=1)
        dist = sides[np.arange(m), k] / scales.goal_m
        outward = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])[k]
        near = dist < 1.0
        direction = to_goal_frame(outward, heading_rad) * near[:, None]
        ceiling = np.minimum((around.hi_m[:, 2] - p[:, 2]) / scales.altitude_m, 1.0)
        parts.append(np.stack([np.where(near, dist, 0.0), direction[:, 0], direction[:, 1], ceiling], axis=1))
    if observe.history:
        c = vehicle.controller
        k = observe.history
        vel = memory_vel[:, :k]
        cos, sin = np.cos(heading_rad)[:, None], np.sin(heading_rad)[:, None]
        vx = (cos * vel[..., 0] + sin * vel[..., 1]) / c.max_speed_m_s
        vy = (cos * vel[..., 1] - sin * vel[..., 0]) / c.max_speed_m_s
        vz = vel[..., 2] / c.max_vertical_speed_m_s
        parts.append(np.concatenate([np.stack([vx, vy, vz], axis=2), memory_act[:, :k]], axis=2).reshape(m, 6 * k))
    if observe.uncertainty:
        sigma = np.zeros(m) if position_sigma_m is None else np.asarray(position_sigma_m, dtype=float).reshape(m)
        parts.append(np.minimum(sigma / scales.clearance_m, 1.0)[:, None])
    return np.concatenate(parts, axis=1) if parts else np.zeros((m, 0))


def goal_heading(p_m: np.ndarray, goal_m: np.ndarray, held_rad: np.ndarray) -> np.ndarray:
    """Goal-frame headings (N,) [rad, CCW from east]: the bearing to the goal, or `held_rad` within HEADING_HOLD_M."""
    d = goal_m[:, 0:2] - p_m[:, 0:2]
    far = np.sqrt(np.add.reduce(d * d, axis=1)) > HEADING_HOLD_M
    return np.where(far, np.arctan2(d[:, 1], d[:, 0]), held_rad)


def to_goal_frame(v_world: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    """Rotate horizontal world vectors (N, 2) into the goal frame (x' along heading)."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return np.stack([c * v_world[:, 0] + s * v_world[:, 1], c * v_world[:, 1] - s * v_world[:, 0]], axis=1)


def to_world_frame(v_goal: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    """Rotate horizontal goal-frame vectors (N, 2) into the world (ENU)."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return np.stack([c * v_goal[:, 0] - s * v_goal[:, 1], s * v_goal[:, 0] + c * v_goal[:, 1]], axis=1)


@dataclass
class PilotMemory:
    """What the observation remembers between decisions, for N vehicles (the env's slots or one pilot).

    Attributes:
        heading_rad: (N,) goal-frame heading.
        prev_action: (N, 3) previous action.
        route_history_m: (N, H) route distance Φ at the last H decisions (newest last).
    """

    heading_rad: np.ndarray
    prev_action: np.ndarray
    route_history_m: np.ndarray
    velocity_history: np.ndarray  # (N, K, 3) world velocities after the last K decisions [m/s], newest first
    action_history: np.ndarray  # (N, K, 3) the last K actions, newest first

    @classmethod
    def empty(cls, n: int, decision_hz: float, history: int = 0) -> PilotMemory:
        h = max(1, int(round(STALL_WINDOW_S * decision_hz)))
        return cls(np.zeros(n), np.zeros((n, 3)), np.zeros((n, h)), np.zeros((n, history, 3)),
                   np.zeros((n, history, 3)))

    def start(self, idx: np.ndarray, p_m: np.ndarray, goal_m: np.ndarray, route_m: np.ndarray) -> None:
        """New episodes in slots idx: positions, goals (M, 3) [m] and route distances (M,) [m]."""
        d = goal_m[:, 0:2] - p_m[:, 0:2]
        self.heading_rad[idx] = np.arctan2(d[:, 1], d[:, 0])
        self.prev_action[idx] = 0.0
        self.route_history_m[idx] = route_m[:, None]
        self.velocity_history[idx] = 0.0
        self.action_history[idx] = 0.0

    def record(self, idx: np.ndarray, action: np.ndarray, route_m: np.ndarray,
               velocity_m_s: np.ndarray | None = None) -> None:
        """After a decision in slots idx: the action taken (M, 3), the route distance now (M,) and (with a
        history) the world velocity now (M, 3) [m/s]."""
        self.prev_action[idx] = action
        hist = self.route_history_m[idx]
        hist[:, :-1] = hist[:, 1:]
        hist[:, -1] = route_m
        self.route_history_m[idx] = hist
        if self.velocity_history.shape[1]:
            assert velocity_m_s is not None, "a memory with a history needs the velocity"
            for h, new in ((self.velocity_history, velocity_m_s), (self.action_history, action)):
                rows = h[idx]
                rows[:, 1:] = rows[:, :-1]
                rows[:, 0] = new
                h[idx] = rows


def build_observations(x: np.ndarray, goal_m: np.ndarray, heading_rad: np.ndarray, route_m: np.ndarray,
                       route_dir: np.ndarray, clearance_m: np.ndarray, nearest_m: np.ndarray, prev_action: np.ndarray,
                       route_history_m: np.ndarray, t_frac: np.ndarray, reading: PerceptionReading,
                       perception: PerceptionConfig, vehicle: VehicleParams, decision_hz: float,
                       scales: ObservationScales) -> np.ndarray:
    """Observations (N, obs_size) float32 (see the module table).

    Args:
        x: states (N, 13 + n) (see `uam_fdm.vehicle.model`).
        goal_m: goals (N, 3) ENU [m].
        heading_rad: goal-frame headings (N,) [rad].
        route_m: geodesic distance-to-go Φ (N,) [m]; route_dir: its world direction (N, 2).
        clearance_m: clearance (N,) [m]; nearest_m: vector to the nearest surface point (N, 3) [m, world].
        prev_action: (N, 3); route_history_m: (N, H) Φ at the last H decisions [m].
        t_frac: time used / time limit (N,).
        reading: the perception (rays, roof heights) in the goal frame.
        perception: its configuration; vehicle: the vehicle (speed limits).
        decision_hz: decision rate [Hz] (scales the stall window).
        scales: the observation's length scales.
    """
    if len(x) == 1:
        return _build_observation_one(x, goal_m, heading_rad, route_m, route_dir, clearance_m, nearest_m,
                                      prev_action, route_history_m, t_frac, reading, perception, vehicle,
                                      decision_hz, scales)
    p = x[:, 0:3]
    c = vehicle.controller
    g = goal_m - p
    d_h = np.sqrt(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1])
    v_goal = to_goal_frame(x[:, 3:5], heading_rad)
    window_s = route_history_m.shape[1] / decision_hz
    stall = (route_m - route_history_m[:, 0]) / (c.max_speed_m_s * window_s)
    base = np.stack([
        d_h / scales.goal_m,
        g[:, 2] / scales.height_m,
        route_m / scales.goal_m,
        *to_goal_frame(route_dir, heading_rad).T,
        v_goal[:, 0] / c.max_speed_m_s,
        v_goal[:, 1] / c.max_speed_m_s,
        x[:, 5] / c.max_vertical_speed_m_s,
        p[:, 2] / scales.altitude_m,
        np.minimum(clearance_m / scales.clearance_m, 1.0),
        *prev_action.T,
        stall,
        t_frac,
        *(to_goal_frame(nearest_m[:, 0:2], heading_rad) / scales.clearance_m).T,
        nearest_m[:, 2] / scales.clearance_m,
    ], axis=1)
    roofs = np.clip((reading.roof_m - p[:, 2:3]) / scales.height_m, -1.0, 1.0)
    out = np.concatenate([base, reading.ray_m / perception.ray_range_m, roofs], axis=1)
    np.minimum(np.maximum(out, -OBS_CLIP, out=out), OBS_CLIP, out=out)
    return out.astype(np.float32)


def _build_observation_one(x, goal_m, heading_rad, route_m, route_dir, clearance_m, nearest_m, prev_action,
                           route_history_m, t_frac, reading, perception, vehicle, decision_hz,
                           scales: ObservationScales) -> np.ndarray:
    """`build_observations` (1, obs_size) of one vehicle: the 18 base elements in plain Python (NumPy's
    per-call overhead on one row dominated a single vehicle's step), the same operations on the same
    doubles (cos and sin of the heading from NumPy, as `to_goal_frame` takes them); the perception
    part and the final clip are the same NumPy calls on a row of the same shape."""
    px, py, pz, vx, vy, vz = x[0, 0:6].tolist()
    gx, gy, gz = goal_m[0].tolist()
    heading = np.asarray(heading_rad).reshape(-1)
    c, s = float(np.cos(heading)[0]), float(np.sin(heading)[0])
    ctl = vehicle.controller
    dx, dy, dz = gx - px, gy - py, gz - pz
    route = float(route_m[0])
    rdx, rdy = route_dir[0].tolist()
    nx, ny, nz = nearest_m[0].tolist()
    window_s = route_history_m.shape[1] / decision_hz
    out = np.empty((1, N_BASE + perception.n_rays + perception.grid_cells ** 2))
    out[0, 0:N_BASE] = (
        math.sqrt(dx * dx + dy * dy) / scales.goal_m,
        dz / scales.height_m,
        route / scales.goal_m,
        c * rdx + s * rdy, c * rdy - s * rdx,
        (c * vx + s * vy) / ctl.max_speed_m_s,
        (c * vy - s * vx) / ctl.max_speed_m_s,
        vz / ctl.max_vertical_speed_m_s,
        pz / scales.altitude_m,
        min(float(clearance_m[0]) / scales.clearance_m, 1.0),  # np.minimum: NaN stays NaN
        *prev_action[0].tolist(),
        (route - float(route_history_m[0, 0])) / (ctl.max_speed_m_s * window_s),
        float(t_frac[0]),
        (c * nx + s * ny) / scales.clearance_m,
        (c * ny - s * nx) / scales.clearance_m,
        nz / scales.clearance_m,
    )
    n_rays = perception.n_rays
    out[:, N_BASE:N_BASE + n_rays] = reading.ray_m / perception.ray_range_m
    out[:, N_BASE + n_rays:] = np.clip((reading.roof_m - pz) / scales.height_m, -1.0, 1.0)
    np.minimum(np.maximum(out, -OBS_CLIP, out=out), OBS_CLIP, out=out)
    return out.astype(np.float32)


def action_to_command(action: np.ndarray, heading_rad: np.ndarray, p: VehicleParams,
                      yaw_rad: np.ndarray | float) -> np.ndarray:
    """Velocity commands (N, 4) = [v_e, v_n, v_u (m/s), yaw (rad)] from goal-frame actions (N, 3) in [-1, 1]."""
    a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64).reshape(-1, 3), -1.0), 1.0)
    c = p.controller
    horiz = to_world_frame(a[:, 0:2], heading_rad) * c.max_speed_m_s
    norm = np.sqrt(np.add.reduce(horiz * horiz, axis=1))
    cmd = np.empty((a.shape[0], 4))
    cmd[:, 0:2] = horiz * np.minimum(1.0, c.max_speed_m_s / np.maximum(norm, 1e-12))[:, None]
    cmd[:, 2] = a[:, 2] * c.max_vertical_speed_m_s
    cmd[:, 3] = yaw_rad
    return cmd


def velocity_command(action: np.ndarray, heading_rad: np.ndarray, p: VehicleParams, yaw_rad: float,
                     hold_periods: int) -> VelocityCommand:
    """The runner's actuation for one goal-frame action (1, 3) in [-1, 1] (`heading_rad` (1,) its goal
    frame [rad]): `action_to_command`'s world velocity [m/s] and heading `yaw_rad` [rad], held for
    `hold_periods` control periods; the runner flies it through the vehicle's low-level controller, as
    the environment does. Every pilot of this package that flies the runner commands through it."""
    cmd = action_to_command(action, heading_rad, p, yaw_rad)[0]
    return VelocityCommand(cmd[0:3], float(cmd[3]), hold_periods=hold_periods)


def world_velocity_to_action(v_frac: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    """Goal-frame actions (N, 3) for world velocity commands given as fractions of the limits (N, 3)."""
    out = np.empty((len(v_frac), 3))
    out[:, 0:2] = to_goal_frame(v_frac[:, 0:2], heading_rad)
    out[:, 2] = v_frac[:, 2]
    return np.clip(out, -1.0, 1.0)

