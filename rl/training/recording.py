"""Recording the flights of training's checkpoints (`rl.policies.flights` is the format and its reader).

At step 0 and at every validation evaluation, the current deterministic policy flies a fixed set of
validation tasks; each flight is kept at the control rate (float32) with its outcome, least clearance and
time, together with the actor's weights and normalisation statistics that flew it.

It cannot change what is learned: the recorder flies its own world and batch (validation cities, never the
training environment), draws its tasks from its own generator (`PCG64([seed, RECORDING_STREAM])`, drawn
once, so every checkpoint flies the same tasks in the same air), and asks the model only for deterministic
actions (no sampling, no update of the normalisation statistics). tests/rl/training check that a run's final
weights are bit-identical with and without it, and that its files are the same bytes twice.

How the tasks are chosen (`fixed_tasks`; the words are in tasks.json): task k flies in validation city k;
legs are short (the task distribution's distance range shrunk to its lowest `SHORT_DIFFICULTY`) or long
(the longest of `LONG_DRAWS` draws over the full range), alternating every L tasks, where L is the number
of turbulence levels; task k flies level k mod L and atmosphere field (k div 2L) mod F of the task's F fields
(the densest and the thinnest come first), so short and long legs meet each level and both ends of the air.
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rl.env.held_out import BatchedPilot
from rl.env.world import NavBatch, NavWorld, SlotAir
from rl.policies.flights import (
    TASKS_FILE,
    CheckpointFlights,
    CityBoxes,
    Flight,
    FlightTasks,
    RecordedTask,
    TrainingFlights,
    checkpoint_file,
    flights_dir,
    tasks_text,
    write_checkpoint,
    write_tasks,
)
from rl.policies.reader import ObsNorm
from rl.task.config import NavConfig
from rl.training.evaluation import eval_config
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.pilot import Task

RECORDING_STREAM = 0x7EC  # PCG64 stream tag of the recorder's draws: no other generator of the run uses it
SHORT_DIFFICULTY = 0.1
LONG_DRAWS = 4


@dataclass(frozen=True)
class FixedEpisode:
    """One fixed task as the batch flies it: its city (an index of the recorder's world), task and air."""

    city: int
    task: Task
    air: SlotAir
    leg: str


def fixed_tasks(batch: NavBatch, n: int, seed: int) -> list[FixedEpisode]:
    """The `n` fixed tasks of a recorder's batch (see the module docstring), drawn from `seed` alone."""
    w = batch.world
    cfg, p = w.config, w.vehicle
    rng = np.random.Generator(np.random.PCG64([int(seed), RECORDING_STREAM]))
    n_levels, n_fields = len(w.levels), len(w.atmospheres)
    out = []
    for k in range(n):
        ci = k % len(w.cities)

        def draw(difficulty: float, city: BuildingMap = w.cities[ci]) -> Task:
            return cfg.tasks.sample(city, rng, p.collision_radius_m, p.controller.max_speed_m_s,
                                    difficulty=difficulty, max_vertical_speed_m_s=p.controller.max_vertical_speed_m_s)

        leg = "short" if (k // n_levels) % 2 == 0 else "long"
        if leg == "short":
            task = draw(SHORT_DIFFICULTY)
        else:
            task = max((draw(1.0) for _ in range(LONG_DRAWS)), key=lambda t: math.dist(t.start_m, t.goal_m))
        level = k % n_levels
        field = (k // (2 * n_levels)) % n_fields
        speed = rng.uniform(0.0, cfg.air.steady_wind_max_m_s)
        heading = rng.uniform(-np.pi, np.pi)
        stacks = w.level_stacks[level] if w.turbulent else []
        series = stacks[int(rng.integers(len(stacks)))] if stacks else 0
        start = int(rng.integers(batch.wind_start_span(task))) if w.turbulent else 0
        wind = (float(speed * np.cos(heading)), float(speed * np.sin(heading)), 0.0)
        out.append(FixedEpisode(ci, task, SlotAir(wind, series, start, level, field), leg))
    return out


def city_boxes(city: BuildingMap) -> CityBoxes:
    """A city as boxes (a prism part as its footprint's bounding box: training cities are boxes)."""
    rows = []
    for b in city.buildings:
        if isinstance(b, Building):
            rows.append([*b.center_xy_m, *b.size_xy_m, b.height_m, b.yaw_rad])
        else:
            fp = b.footprint_xy_m()
            lo, hi = fp.min(axis=0), fp.max(axis=0)
            rows.append([*(0.5 * (lo + hi)), *(hi - lo), b.height_m, 0.0])
    lo_m, hi_m = (tuple(float(v) for v in a) for a in (city.bounds_min_m, city.bounds_max_m))
    return CityBoxes(city.name, lo_m, hi_m, np.array(rows, dtype=float).reshape(-1, 6))  # type: ignore[arg-type]


class FlightRecorder:
    """Flies the fixed tasks with a pilot and writes each checkpoint's flights into a policy folder.

    Args:
        nav: the task; n_tasks: how many fixed tasks; seed: the run's seed; folder: the policy folder.
        dynamics_from: a world whose compiled dynamics, atmospheres and turbulence stacks are shared (built once).
        history: a policy folder whose recorded checkpoints up to `up_to` timesteps this run continues (a resumed
            run): kept (or copied into `folder`) when they flew the same tasks. Anything else already in `folder`'s
            training flights belongs to a policy being replaced and is removed.
        up_to: the timesteps the run resumes from.
        world: the world whose cities the tasks are drawn in (e.g. a scenario's validation world, `rl.env.ground`);
            default: the first `n_tasks` validation cities.
    """

    def __init__(self, nav: NavConfig, n_tasks: int, seed: int, folder: Path, dynamics_from: NavWorld,
                 history: Path | None = None, up_to: int = 0, world: NavWorld | None = None) -> None:
        self.folder = Path(folder)
        self.world = world or NavWorld(eval_config(nav, n_tasks, pool="validation"), dynamics=dynamics_from.dynamics,
                                       atmosphere=dynamics_from.atmospheres, wind_from=dynamics_from)
        self.batch = NavBatch(self.world, n_tasks)
        self.episodes = fixed_tasks(self.batch, n_tasks, seed)
        self.tasks = self._describe(seed)
        earlier = self._history(history, up_to)
        for old in (flights_dir(self.folder).glob("step_*.npz") if flights_dir(self.folder).is_dir() else ()):
            if old not in earlier.values():
                old.unlink()
        write_tasks(self.folder, self.tasks)
        for step, src in sorted(earlier.items()):
            dst = checkpoint_file(self.folder, step)
            if src != dst:
                shutil.copyfile(src, dst)

    def _history(self, history: Path | None, up_to: int) -> dict[int, Path]:
        """The checkpoint files of `history` up to `up_to` timesteps that flew these same tasks, by timesteps."""
        if history is None:
            return {}
        try:
            past = TrainingFlights.open(history)
            same = (flights_dir(history) / TASKS_FILE).read_text(encoding="utf-8") == tasks_text(self.tasks)
        except (ValueError, OSError):
            return {}  # nothing recorded there (an older run): the record starts at the resume
        if not same:
            return {}
        return {s: checkpoint_file(history, s) for s in past.steps if s <= up_to}

    def _describe(self, seed: int) -> FlightTasks:
        w = self.world
        air = w.config.air
        fields = air.fields() if len(air.fields()) == len(w.atmospheres) else None
        n_levels, n_fields = len(w.levels), len(w.atmospheres)
        where = "task k in validation city k" if w.fixed is None else "in the scenario's map"
        rule = (f"{len(self.episodes)} validation tasks drawn once from the run's seed {seed} (PCG64 stream "
                f"{RECORDING_STREAM:#x}), {where}; legs short (the shortest "
                f"{SHORT_DIFFICULTY:.0%} of the distance range) or long (the longest of {LONG_DRAWS} draws), "
                f"alternating every {n_levels} task(s); task k flies turbulence level k mod {n_levels} "
                f"({', '.join(str(lv.value) for lv in w.levels)}) and field (k div {2 * n_levels}) mod {n_fields} "
                f"of the task's {n_fields}; steady wind drawn as in training")
        tasks = []
        for e in self.episodes:
            cond = fields[e.air.field] if fields is not None else None
            t = e.task
            tasks.append(RecordedTask(
                e.city, e.leg, t.start_m, t.goal_m, t.goal_radius_m, t.timeout_s, t.start_yaw_rad,
                str(w.levels[e.air.level].value), cond.elevation_m if cond else float("nan"),
                cond.isa_offset_k if cond else float("nan"), e.air.wind_m_s))
        used = sorted({e.city for e in self.episodes})
        return FlightTasks(rule, int(seed), float(w.config.control_hz), w.vehicle.name,
                           float(w.vehicle.collision_radius_m),
                           tuple(RecordedTask(**{**vars(t), "city": used.index(t.city)}) for t in tasks),
                           tuple(city_boxes(w.cities[c]) for c in used))

    def has(self, timesteps: int) -> bool:
        """Whether the checkpoint at `timesteps` is recorded already (a final evaluation repeats the last)."""
        return checkpoint_file(self.folder, timesteps).is_file()

    def fly(self, pilot: BatchedPilot) -> tuple[Flight, ...]:
        """Fly every fixed task once with `pilot` (deterministic); the flights in task order."""
        b, w = self.batch, self.world
        n = b.n
        hz = w.config.control_hz
        cap = int(math.ceil(max(e.task.timeout_s for e in self.episodes) * hz)) + 2
        states = np.zeros((n, cap, 6))
        count = np.zeros(n, dtype=np.int64)
        done = np.zeros(n, dtype=bool)

        def keep(idx: np.ndarray) -> None:
            sel = idx[~done[idx] & (count[idx] < cap)]
            states[sel, count[sel]] = b.x[sel, 0:6]
            count[sel] += 1

        b.place([(i, e.city, e.task, e.air) for i, e in enumerate(self.episodes)])
        states[:, 0] = b.x[:, 0:6]
        count[:] = 1
        outcome, ended = [""] * n, np.zeros(n)
        b.on_period = keep
        try:
            obs = b.observations.copy()
            while not done.all():
                obs, _, term, trunc, infos = b.step(pilot(obs, b))
                for j in np.flatnonzero((term | trunc) & ~done):
                    outcome[j], ended[j] = str(infos[j]["outcome"]), infos[j]["t_s"]
                    done[j] = True
        finally:
            b.on_period = None
        pos = states[:, :, 0:3]
        clear = w.clearance_sensor.clearance(pos.reshape(-1, 3), np.repeat(b.city, cap)).reshape(n, cap)
        flights = []
        for i in range(n):
            k = int(count[i])
            c = clear[i, :k]
            flights.append(Flight(i, outcome[i], float(ended[i]), float(c.min()), pos[i, :k].astype(np.float32),
                                  states[i, :k, 3:6].astype(np.float32), c.astype(np.float32)))
        return tuple(flights)

    def record(self, timesteps: int, pilot: BatchedPilot, actor: dict[str, np.ndarray], obs_norm: ObsNorm) -> Path:
        """Fly the fixed tasks and write the checkpoint at `timesteps` (its file's path)."""
        norm = ObsNorm(np.array(obs_norm.mean, dtype=float), np.array(obs_norm.var, dtype=float), obs_norm.count,
                       obs_norm.epsilon, obs_norm.clip_obs)  # a copy: training updates the running statistics
        return write_checkpoint(self.folder, CheckpointFlights(int(timesteps), self.fly(pilot), actor, norm))

