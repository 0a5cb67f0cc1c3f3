"""A run's cells and how one is flown: the part of a run every backend's worker shares.

A `Cell` is one episode to fly (scenario, episode, seed, pilot); `CellRunner` flies cells in one process
and writes (or returns) each one's part of the run store (`compare.results.store`), seeded from the cell alone
(`compare.flying.seeding`), so a cell flies the same wherever it flies. The cell scores its episode from the
physics-rate flight before the store thins it to the control rate: the metrics never depend on what is kept.
The campaign (`compare.run.campaign`) plans the cells and the backends (`compare.run.backends`) carry them to their
workers; both import this module, which imports neither.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compare.flying import pilots
from compare.flying.episode_loop import Trajectory, run_episode
from compare.flying.promise import scored_report
from compare.flying.seeding import cell_seed
from compare.results.difficulty import building_coverage
from compare.results.metrics import episode_metrics
from compare.results.store import part_bytes, part_path, write_part
from compare.results.tables import EpisodeConditions, episode_row, kept_rows, samples_table
from compare.results.trajectory import EpisodeKey, EpisodeMeta, SavedEpisode, xyz
from compare.scenarios.scenario import Scenario
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.air.wind import WindField, probe_heights_up_to, turbulence_airspeed_m_s
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Pilot, Truth, World
from uam_fdm.vehicle.dynamics import VehicleDynamics


@dataclass(frozen=True)
class Cell:
    """One episode to fly: scenario (index into the run's list), episode index, seed and pilot (its name)."""

    scenario: int
    episode: int
    seed: int
    pilot: str


def cell_key(scenarios: Sequence[Scenario], c: Cell) -> EpisodeKey:
    """The episode key (and so the episode file's name) of cell `c` of a run of `scenarios`."""
    return EpisodeKey(scenarios[c.scenario].name, c.episode, c.pilot, c.seed)


class CellRunner:
    """Flies cells; holds per-process caches (worlds per scenario, one pilot per name, or per name and
    vehicle for a pilot that flies a policy)."""

    def __init__(self, scenarios: Sequence[Scenario], out_dir: Path, policies: Mapping[str, Path],
                 store: str = "control") -> None:
        """`policies`: the policy folder of the pilots that need one, by vehicle fingerprint; `store`: the samples
        kept, "control" or "full" (`compare.results.tables.kept_rows`)."""
        self.scenarios, self.out_dir, self.policies = list(scenarios), Path(out_dir), dict(policies)
        self.store = store
        self._conditions: dict[int, EpisodeConditions] = {}
        self._worlds: dict[int, World] = {}
        self._truths: dict[int, Truth] = {}
        self._dynamics: dict[tuple, VehicleDynamics] = {}
        self._pilots: dict[tuple[str, str], Pilot] = {}

    def world(self, si: int) -> World:
        """What the pilots of scenario `si` are given at take-off (one flight model per vehicle and rates)."""
        if si not in self._worlds:
            sc = self.scenarios[si]
            key = (sc.vehicle.fingerprint(), sc.physics_hz, sc.control_hz)
            if key not in self._dynamics:
                self._dynamics[key] = VehicleDynamics(sc.vehicle, sc.physics_hz, sc.control_hz)
            # the forecast turbulence level (a category) is the pilots' to know; its gusts are not; the prior map is
            # theirs, the city as it stands is not
            sensing = None if sc.sensing.perfect else sc.sensing
            self._worlds[si] = World(sc.vehicle, self._dynamics[key], sc.prior_map, sc.air, sc.wind.turbulence,
                                     sensing=sensing)
        return self._worlds[si]

    def truth(self, si: int, sensing_seed: int) -> Truth:
        """What the simulator holds in scenario `si` (one ray caster and one map of the unmapped per scenario)."""
        if si not in self._truths:
            sc = self.scenarios[si]
            ids = set(sc.unmapped_ids)
            unmapped = [b for b in sc.city.buildings if b.id in ids]
            near = (BuildingMap(unmapped, sc.city.bounds_min_m, sc.city.bounds_max_m, name="unmapped")
                    if unmapped else None)
            self._truths[si] = Truth(sc.city, sc.sensing, 0, near)
        base = self._truths[si]
        if not base.perfect:
            base.ray_caster()  # built once, shared by the scenario's cells
        return Truth(base.city, base.sensing, sensing_seed, base.unmapped, base.caster)

    def pilot(self, name: str, sc: Scenario) -> Pilot:
        """The pilot `name` flying in scenario `sc` (a pilot that flies a policy: the one for its vehicle)."""
        fp = sc.vehicle.fingerprint() if pilots.pilot(name).needs_policy else ""
        if (name, fp) not in self._pilots:
            request = pilots.BuildRequest(sc.vehicle, sc.vehicle_name, sc.source, self.policies.get(fp) if fp else None)
            self._pilots[name, fp] = pilots.build(name, request)
        return self._pilots[name, fp]

    def conditions(self, si: int) -> EpisodeConditions:
        """The air and city of scenario `si` (the episode table's condition columns; the density rounded as
        run.json records it, so a query bins as the report does)."""
        if si not in self._conditions:
            sc = self.scenarios[si]
            rho = round(float(sc.air.density_kg_m3(0.0)), 4)
            self._conditions[si] = EpisodeConditions(rho, density_altitude_m(rho), sc.wind.turbulence.value,
                                                     xyz(sc.wind.steady_enu_m_s), building_coverage(sc.city))
        return self._conditions[si]

    def run(self, c: Cell) -> Path:
        """Fly cell `c` and write its part of the run store; returns the file."""
        key, data = self.part(c)
        return write_part(part_path(self.out_dir, key), data, root=self.out_dir)

    def part(self, c: Cell) -> tuple[EpisodeKey, bytes]:
        """Fly cell `c`: its key and its part's content (`compare.results.store.part_bytes`), scored first."""
        meta, traj = self.fly(c)
        return meta.key, self.stored(c, meta, traj)

    def stored(self, c: Cell, meta: EpisodeMeta, traj: Trajectory) -> bytes:
        """The part of a flown cell: its metrics from the physics-rate flight, then its samples as kept."""
        sc = self.scenarios[c.scenario]
        metrics = episode_metrics(SavedEpisode(meta, traj))
        period_rows = max(1, round(sc.physics_hz / sc.control_hz))
        samples = samples_table(meta.key, traj, meta.n_rotors, self.store, period_rows)
        row = episode_row(meta, metrics, self.conditions(c.scenario), self.store,
                          len(kept_rows(traj, self.store, period_rows)))
        return part_bytes(row, samples)

    def fly(self, c: Cell) -> tuple[EpisodeMeta, Trajectory]:
        """Fly cell `c`: what its episode file holds (nothing is written)."""
        sc = self.scenarios[c.scenario]
        ep = sc.episodes[c.episode]
        task = ep.task
        world = self.world(c.scenario)
        p = sc.vehicle
        wind_seed = cell_seed(sc.name, c.episode, c.seed, "wind")
        agent_seed = cell_seed(sc.name, c.episode, c.seed, "agent")
        sensing_seed = cell_seed(sc.name, c.episode, c.seed, "sensing")
        # one reference probe airspeed per episode; turbulence rungs up to the flight volume's ceiling
        wind_speed = float(np.linalg.norm(sc.wind.steady_enu_m_s))
        airspeed = turbulence_airspeed_m_s(p.controller.max_speed_m_s, wind_speed)
        heights = probe_heights_up_to(float(sc.city.bounds_max_m[2]))
        wind = WindField.from_conditions(sc.wind, wind_seed, task.timeout_s + 1.0, airspeed, heights)
        pilot = self.pilot(c.pilot, sc)
        traj = run_episode(world, pilot, task, wind, agent_seed, pilot_name=c.pilot,
                           truth=self.truth(c.scenario, sensing_seed))
        # e.g. what the classical pilot's tracker did (columns of metrics.csv), its promise measured on the truth
        report = scored_report(pilot, traj)
        key = EpisodeKey(sc.name, c.episode, c.pilot, c.seed)
        meta = EpisodeMeta(key=key, map_name=sc.city.name or sc.name, vehicle=sc.vehicle_name,
                           vehicle_fingerprint=sc.vehicle.fingerprint(),
                           start_m=xyz(task.start_m), goal_m=xyz(task.goal_m), goal_radius_m=task.goal_radius_m,
                           timeout_s=task.timeout_s, collision_radius_m=p.collision_radius_m, n_rotors=p.n_rotors,
                           energy_J=float(traj.energy_J), outcome=traj.outcome,
                           # planning at reset plus every replan, when the pilot reports it
                           plan_time_s=float(traj.plan_time_s if report is None else report.plan_time_s),
                           detail=traj.detail, wind_seed=wind_seed, agent_seed=agent_seed,
                           mean_decision_ms=float(np.mean(traj.compute_s) * 1e3) if len(traj.compute_s) else None,
                           failure_reason=None if report is None else report.failure_reason(traj.outcome),
                           report=report, sensing=sc.sensing.label, map_error=sc.map_error.label)
        return meta, traj
