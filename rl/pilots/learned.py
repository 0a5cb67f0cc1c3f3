"""The learned pilot as a `Pilot`: policy -> velocity command -> the vehicle's low-level controller.

Loads a policy folder (the shipped `rl/policies/default` or one written by `uam-compare train`),
builds the same observation the environment builds (`rl.sensing.senses.observe_slots`: the same perception,
route field and memory), normalises it with the training statistics and acts deterministically.
At reset it computes the task's geodesic route field on the prior map (timed, reported as planning time).
At `perfect` sensing it observes the state it is handed (the truth) with the prior map's exact senses. Below it,
it flies with the reduced lidar it was trained on (`sensing_flown`) and observes as a sensing slot of the env does
(`rl.env.onboard_slots`): the estimate it is handed stands for the state, its lidar scans are integrated on that
estimate into a one-slot `LidarView` over the prior map's height maps, and the view is read at the estimate. It returns
a `VelocityCommand` held for the policy's decision period (e.g. 5 control periods at 10 Hz), which
the runner flies through the same low-level controller, period by period, with the same end
rules the environment applies; so an episode flown through the runner is bit-identical to the
environment's (tests/rl/pilots/test_learned_pilot.py).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rl.policies.flights import TrainingFlights, checkpoint_file
from rl.policies.folder import PolicyFolder
from rl.policies.reader import ObsNorm, load_network
from rl.sensing.lidar_view import LidarView
from rl.sensing.observation import (
    TURBULENCE_VALUE,
    PilotMemory,
    Surroundings,
    goal_heading,
    obs_size,
    velocity_command,
)
from rl.sensing.perception import Perception
from rl.sensing.route import RouteBank, grid_shape
from rl.sensing.route_refresh import RouteRefresh
from rl.sensing.senses import clearance_sensor, nearest_surface, observe_slots, route_for
from rl.task.cities import boxes_only
from rl.task.config import NavConfig, learned_lidar
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Observation, ResetInfo, Task, VelocityCommand, World
from uam_fdm.renamed import renamed
from uam_fdm.sensing.batch_onboard import N_ESTIMATED, SlotEstimates
from uam_fdm.sensing.specs import SensingConfig
from uam_fdm.vehicle.params import VehicleParams, load_vehicle

if TYPE_CHECKING:  # the network's module pulls in PyTorch, loaded only with a network
    from rl.policies.network import ActorCritic


@dataclass
class Policy:
    """A trained policy: its network, its observation statistics and the task it was trained on."""

    folder: Path
    network: ActorCritic
    obs_norm: ObsNorm
    nav: NavConfig

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (N, 3) in [-1, 1] for raw observations (N, obs)."""
        act = self.network.act(self.obs_norm.normalize(np.asarray(obs, dtype=np.float64)))
        return np.asarray(act, dtype=np.float64)


def load_policy(folder: Path | str | None = None, vehicle: VehicleParams | None = None) -> Policy:
    """Load a policy folder (default: the shipped small-quad policy) from plain data only
    (`rl.policies.reader`): nothing in the folder is unpickled or executed.

    `vehicle`: the vehicle it is to fly; a policy trained for another vehicle (another preset, or the
    same name with other parameters) is refused.

    Torch's thread count is left to the caller (a process-wide setting): one thread is several times
    faster than two for this small network; the CLI and the run's worker processes set it.

    Raises:
        ValueError: the folder or one of its files is missing, unreadable, holds code, or does not
            fit the task in its config.json, naming the file; or it was trained for another
            vehicle than `vehicle` (naming the file, both vehicles).
    """
    pf = PolicyFolder.open(folder)
    cfg = pf.config()
    nav = cfg.nav
    if vehicle is not None:
        check_vehicle(pf.path, nav, vehicle)
    n_obs = obs_size(nav.perception, nav.observe)
    stats = ObsNorm.load(pf.obs_norm)
    if stats.mean.shape != (n_obs,) or stats.var.shape != (n_obs,):
        raise ValueError(f"{pf.obs_norm}: statistics for {stats.mean.size} observations; "
                         f"config.json's task gives {n_obs}")
    return Policy(pf.path, load_network(pf.model, n_obs, cfg.network), stats, nav)


def load_checkpoint_policy(folder: Path | str, timesteps: int) -> Policy:
    """The policy that flew the training flights recorded at `timesteps` (`rl.policies.flights`): its actor's
    weights and statistics from the checkpoint file, its task from the folder's config.json; plain data only.

    Raises:
        ValueError: no such recorded checkpoint, or it stores no weights or weights that do not fit the
            network of config.json (naming the file).
    """
    import torch  # PyTorch only with a network

    from rl.policies.network import ActorCritic

    pf = PolicyFolder.open(folder)
    cfg = pf.config()
    ckpt = TrainingFlights.open(pf.path).checkpoint(timesteps)
    path = checkpoint_file(pf.path, timesteps)
    n_obs = obs_size(cfg.nav.perception, cfg.nav.observe)
    if not ckpt.actor or ckpt.obs_norm is None:
        raise ValueError(f"{path}: stores no weights to fly")
    if ckpt.obs_norm.mean.shape != (n_obs,):
        raise ValueError(f"{path}: statistics for {ckpt.obs_norm.mean.size} observations; config.json gives {n_obs}")
    net = ActorCritic(n_obs, cfg.network)
    try:  # the actor only: the critic is not stored (flying never evaluates it)
        missing, unexpected = net.load_state_dict({k: torch.from_numpy(v) for k, v in ckpt.actor.items()},
                                                  strict=False)
    except RuntimeError as exc:
        raise ValueError(f"{path}: weights do not fit the network of config.json ({exc})") from None
    if unexpected or any(not k.startswith(("value_net.", "mlp_extractor.value_net.")) for k in missing):
        raise ValueError(f"{path}: weights do not fit the network of config.json "
                         f"(missing {missing[:3]}, unexpected {unexpected[:3]})")
    return Policy(pf.path, net.eval(), ckpt.obs_norm, cfg.nav)


def check_vehicle(folder: Path, nav: NavConfig, vehicle: VehicleParams) -> None:
    """Raise ValueError unless the policy in `folder` (task `nav`) was trained for `vehicle`."""
    trained = load_vehicle(nav.vehicle)
    if trained.fingerprint() != vehicle.fingerprint():
        same = " (the same name with other parameters)" if trained.name == vehicle.name else ""
        raise ValueError(f"{PolicyFolder(folder).config_file}: the policy was trained for vehicle "
                         f"{nav.vehicle!r} (nav.vehicle); it cannot fly vehicle {vehicle.name!r}{same}: use "
                         f"a policy trained for {vehicle.name!r} (uam-compare train --vehicle)")


class _CitySenses:
    """The environment's sensors for one city (box buildings): clearance and perception."""

    def __init__(self, city: BuildingMap, nav: NavConfig, radius_m: float) -> None:
        self.city = city
        self.clearance = clearance_sensor([city], nav.scales, radius_m)
        self.perception = Perception([city], radius_m, nav.perception)
        self.route_cells = grid_shape(city, nav.route.cell_m)


class PolicyPilot:
    """The learned pilot (implements `uam_fdm.pilot.Pilot`).

    Args:
        policy: a loaded `Policy`, a policy folder, or None for the shipped policy.
    """

    name = "ppo"
    _SLOT = np.zeros(1, dtype=np.int64)
    _CITY = np.zeros(1, dtype=np.int64)

    def __init__(self, policy: Policy | Path | str | None = None) -> None:
        self.policy = policy if isinstance(policy, Policy) else load_policy(policy)
        self._senses: _CitySenses | None = None
        self._world: World | None = None
        self._trained_fingerprint = load_vehicle(self.policy.nav.vehicle).fingerprint()

    def sensing_flown(self, scenario: SensingConfig) -> SensingConfig:
        """The sensors the learned pilot flies with where a scenario states `scenario`: its sensors with the
        reduced lidar the policy was trained on (`rl.task.config.learned_lidar`, as the training env's slots carry;
        `uam_fdm.pilot.ChoosesSensors`)."""
        return learned_lidar(scenario)

    def reset(self, world: World, task: Task, seed: int) -> ResetInfo:
        """Prepare for `task`: sensors for the city, the route field (timed), fresh memory and, below perfect
        sensing (`world.sensing`), an empty lidar view.

        Deterministic, so `seed` is unused. Refuses (ResetInfo not ok) a vehicle or control rate
        other than the policy's, and maps with non-box obstacles (the perception needs boxes).
        """
        nav = self.policy.nav
        p = world.vehicle
        if p.fingerprint() != self._trained_fingerprint:
            return ResetInfo(False, "unsupported_vehicle", 0.0,
                             f"the policy was trained for {nav.vehicle!r}; {p.name!r} has other parameters")
        if abs(world.dynamics.control_hz - nav.control_hz) > 1e-9:
            return ResetInfo(False, "unsupported_rate", 0.0,
                             f"the policy was trained with a {nav.control_hz:g} Hz control period; "
                             f"this world runs {world.dynamics.control_hz:g} Hz")
        if not boxes_only(world.city):
            return ResetInfo(False, "unsupported_map", 0.0,
                             f"map {world.city.name!r} has non-box obstacles; "
                             "the learned pilot's perception needs boxes")
        t0 = time.perf_counter()
        radius = p.collision_radius_m
        if self._senses is None or self._senses.city is not world.city:
            self._senses = _CitySenses(world.city, nav, radius)
        self._world = world
        self._task = task
        self._goal = np.asarray(task.goal_m, dtype=float)[None]
        route = route_for(world.city, task, radius, nav.route)
        self._routes = RouteBank(1, self._senses.route_cells, nav.route.climb_weight, len(route.fields))
        self._routes.set(0, route)
        # started at the first decision, where the state it sees is known (the estimate's, below perfect sensing)
        self._memory = PilotMemory.empty(1, nav.decision_hz, nav.observe.history)
        self._last_action: np.ndarray | None = None
        self._view: LidarView | None = None
        self._sigma_m = np.zeros(1)  # the estimate's position sigma at the last decision [m] (`_integrate`)
        if world.sensing is not None and not world.sensing.perfect:
            # the prior map's height maps, max'ed with what the lidar senses (the env's `OnboardSlots` view)
            lidar = self.sensing_flown(world.sensing).lidar
            self._view = LidarView(self._senses.perception, 1, lidar, nav.scales.clearance_m)
            self._view.reset(self._SLOT, self._CITY)
        self._refresh: RouteRefresh | None = None
        if self._view is not None and nav.route.refresh_s > 0.0:  # its route redrawn around what it senses
            self._refresh = RouteRefresh(1, nav.route, nav.decision_hz, radius)
            self._refresh.start(0, world.city, task, route)
        return ResetInfo(True, plan_time_s=time.perf_counter() - t0)

    def observe(self, obs: Observation) -> np.ndarray:
        """The raw observation (1, obs) of decision `obs` (what the environment would return): at its state
        `obs.x` (the truth at perfect sensing, else the estimate), with the prior map's exact senses at perfect
        sensing, else its lidar view after `obs`'s scans are integrated into it (call once per decision: scans
        are integrated once).

        Starts the memory at the first decision and advances it at every later one (as the environment does after
        a step).
        """
        nav, m = self.policy.nav, self._memory
        senses, world = self._flying()
        xs = np.asarray(obs.x, dtype=float)[None]
        pos = xs[:, 0:3]
        if self._view is not None:
            self._integrate(obs, xs)
            if self._refresh is not None:  # as the env's sensing slots, after the scans are in the view
                for _, redrawn in self._refresh.decide(self._SLOT, self._view, self._SLOT, pos, self._sigma_m):
                    self._routes.set(0, redrawn)
        route = self._routes.potential(pos, self._SLOT)
        if self._last_action is None:
            m.start(self._SLOT, pos, self._goal, route)
        else:
            m.record(self._SLOT, self._last_action, route, xs[:, 3:6])
            m.heading_rad[:] = goal_heading(pos, self._goal, m.heading_rad)
        reading = None
        if self._view is None:
            clear, nearest = nearest_surface(senses.clearance, pos, self._CITY)
        else:
            sensed = self._view.read(self._SLOT, xs, m.heading_rad[self._SLOT])
            clear, nearest, reading = sensed.clearance_m, sensed.nearest_m, sensed.reading
        t_frac = np.array([obs.t_s / self._task.timeout_s])
        around = None
        if nav.observe.size():  # what the pilot interface states: the air, the forecast, the flight volume
            city = world.city
            around = Surroundings(np.asarray(world.atmosphere.density_ratio_clamped(xs[:, 2]), dtype=float),
                                  np.array([TURBULENCE_VALUE[world.turbulence]]),
                                  np.asarray(city.bounds_min_m, dtype=float)[None],
                                  np.asarray(city.bounds_max_m, dtype=float)[None])
        return observe_slots(self._SLOT, xs, self._goal, route, clear, nearest, t_frac, self._CITY,
                             senses.perception, self._routes, m, nav.perception, nav.scales, nav.decision_hz,
                             world.vehicle, nav.observe, around, reading, None if self._view is None else self._sigma_m)

    def _integrate(self, obs: Observation, xs: np.ndarray) -> None:
        """Place decision `obs`'s lidar scans on its estimate xs (1, nx) with the estimate's position sigma along
        its covariance's longest axis, as the env's `OnboardSlots.decide` does (`SlotEstimates.sigma_max_m`)."""
        assert self._view is not None
        if obs.covariance is None:
            raise ValueError("the learned pilot flies on its sensors here: a decision needs the estimate's covariance")
        cov = np.asarray(obs.covariance, dtype=float)[None, 0:3, 0:3]
        t = obs.t_s if obs.estimate_t_s is None else obs.estimate_t_s
        est = SlotEstimates(np.array([t]), xs[:, 0:N_ESTIMATED], cov)
        self._sigma_m = est.sigma_max_m
        self._view.integrate(self._SLOT, [obs.sensors.lidar], est.state, self._sigma_m)

    def act(self, obs: Observation) -> VelocityCommand:
        nav = self.policy.nav
        action = self.policy.act_batch(self.observe(obs))
        self._last_action = np.clip(action, -1.0, 1.0)
        _, world = self._flying()
        return velocity_command(action, self._memory.heading_rad, world.vehicle, self._task.start_yaw_rad,
                                nav.action_repeat)

    def _flying(self) -> tuple[_CitySenses, World]:
        """The city's sensors and the episode's world (both set by `reset`)."""
        if self._senses is None or self._world is None:
            raise RuntimeError("the learned pilot flies only after reset()")
        return self._senses, self._world

    def episode_report(self) -> None:
        """Nothing beyond the trajectory (its route field's time is the reset's planning time)."""


if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names
    def __getattr__(name: str) -> Any:
        """The old name `PolicyAgent` (kept for one release, for code written against it): `PolicyPilot`, with a
        warning (`uam_fdm.renamed`)."""
        return renamed(__name__, name, {"PolicyAgent": "PolicyPilot"})
