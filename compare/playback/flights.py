"""The flights of a run folder grouped for playback: every pilot that flew one (scenario, episode, seed).

The animation (`compare.playback.animate`) and the HTML viewer (`compare.pages.viewer`) both show the pilots of
one comparison cell together, on one clock. This module loads a run folder's saved episodes
(`compare.results.episodes`: the run store, or an older folder's `.npz` files) into
`FlightGroup`s, picks one from a user's `SCENARIO:EPISODE[:SEED]` spec, and samples each pilot's
flight on a shared time grid (`sample_flight`), holding a pilot that has already ended where it ended.
"""
from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from compare.report.figures import crop_map, flight_region, pilot_colors, trace_from_episode
from compare.results.episodes import EpisodeEntry, RunEpisodes, open_episodes
from compare.results.run_info import PRIOR_MAPS, WindInfo, read_run_info
from compare.results.trajectory import SavedEpisode
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.city.mapfile import load_map_file
from uam_fdm.episode import Outcome

logger = logging.getLogger(__name__)

# Words for an ended flight, by outcome.
OUTCOME_WORDS: dict[Outcome, str] = {
    Outcome.SUCCESS: "arrived", Outcome.COLLISION: "collided", Outcome.OUT_OF_BOUNDS: "left the volume",
    Outcome.NONFINITE: "diverged", Outcome.TIMEOUT: "timed out", Outcome.PLANNER_FAILURE: "no plan",
    Outcome.SOLVER_FAILURE: "solver failed",
}


@dataclass(frozen=True)
class Flight:
    """One pilot's flight in a group, with how to show it: `label` (e.g. "PPO policy") and `color` (matplotlib).

    The flight itself is read when asked for (`episode`, a few kept at a time by `RunEpisodes.load_recent`), so
    the groups of a whole run hold no trajectory: the viewer and the animation take one cell at a time.

    Attributes:
        entry: where the episode is; source: the run's episodes that read it.
        end_t_s: time the flight ended [s] (0 for a flight that never started). outcome: how it ended.
    """

    entry: EpisodeEntry
    source: RunEpisodes
    label: str
    color: str
    end_t_s: float
    outcome: Outcome

    @property
    def episode(self) -> SavedEpisode:
        """The saved flight (read again if it is not among the last few read)."""
        return self.source.load_recent(self.entry)

    @property
    def pilot(self) -> str:
        return self.entry.key.method

    @property
    def outcome_words(self) -> str:
        return OUTCOME_WORDS[self.outcome]


@dataclass(frozen=True)
class FlightGroup:
    """The flights of one comparison cell, one per pilot that flew it, in the run's pilot order.

    Attributes:
        scenario, episode, seed: the cell.
        flights: one per pilot that flew it.
        city: the scenario's map, the city as it stands (from the run folder's `maps/<scenario>.yaml`).
        description: the scenario's one-line description (may be empty).
        wind: the scenario's wind as run.json records it (None when it does not).
        prior: the pilots' prior map where it differs from `city` (`maps/prior/<scenario>.yaml`), else None.
    """

    scenario: str
    episode: int
    seed: int
    flights: tuple[Flight, ...]
    city: BuildingMap
    description: str = ""
    wind: WindInfo | None = None
    prior: BuildingMap | None = None

    @property
    def unmapped_ids(self) -> frozenset[int]:
        """Ids of the true city's obstacles the prior map lacks (unmapped, missing, cranes and masts)."""
        if self.prior is None:
            return frozenset()
        return frozenset(int(i) for i in self.city.building_ids) - {int(i) for i in self.prior.building_ids}

    @property
    def spec(self) -> str:
        """The `--episode` spelling of this group: `SCENARIO:EPISODE:SEED`."""
        return f"{self.scenario}:{self.episode}:{self.seed}"

    @property
    def stem(self) -> str:
        """File stem for outputs of this group, e.g. `suburb-quad__ep000__s0`."""
        return f"{self.scenario}__ep{self.episode:03d}__s{self.seed}"

    @property
    def duration_s(self) -> float:
        """Time until the last pilot's flight ended [s]."""
        return max((p.end_t_s for p in self.flights), default=0.0)

    def region(self) -> tuple[BuildingMap, np.ndarray, np.ndarray]:
        """The city cropped to the flights (start and goal included) plus a margin, and that box (lo, hi) ENU [m].

        The same region as the report's episode pages (`compare.report.figures.flight_region`, `crop_map`).
        """
        lo, hi = flight_region([trace_from_episode(p.episode, p.label, p.color) for p in self.flights])
        return crop_map(self.city, lo, hi), lo, hi

    @property
    def meta(self):
        """The first pilot's episode metadata (task, vehicle and map are the same for every pilot)."""
        return self.flights[0].episode.meta


def flight_groups(run_dir: Path, *, warn_unreadable: bool = True, warn_undrawable: bool = True,
                  warned: Collection[str] = ()) -> list[FlightGroup]:
    """Load every saved episode of a run folder, grouped by (scenario, episode, seed), in run order.

    An episode file the listing finds unreadable (corrupt, truncated) is left out and logged, as a warning unless
    `warn_unreadable` is False (the caller has already warned about it); a flight that does not load or draw
    (`compare.results.episodes.RunEpisodes.load`) likewise, one warning line each unless `warn_undrawable` is False.

    Raises:
        ValueError: not a run folder, no readable saved episodes, or a scenario's map is missing or
            unreadable, naming the folder or file.
    """
    run_dir = Path(run_dir)
    info = read_run_info(run_dir)
    episodes = open_episodes(run_dir)
    if not episodes.entries and not episodes.unreadable:
        raise ValueError(f"{run_dir}: no saved episodes (store/ or episodes/*.npz) to show")
    scen_order = {s.name: i for i, s in enumerate(info.scenarios)}
    pilot_order = {m: i for i, m in enumerate(info.pilots)}
    by_cell: dict[tuple[str, int, int], list[Flight]] = {}
    level = logging.WARNING if warn_unreadable else logging.INFO
    level_undrawable = logging.WARNING if warn_undrawable else logging.INFO
    unreadable = []
    for bad in episodes.unreadable:
        logger.log(level, "skipping unreadable episode file %s", bad.reason)  # the reason names the file
        unreadable.append(bad.path.name)
    for entry in episodes.entries:
        try:  # read once here (then let go): an unreadable one is left out before anything is drawn
            ep = episodes.load(entry)
        except ValueError as exc:  # one bad file must not cost the flights of the rest
            # the message names the file; one the caller has named (`warned`, file names) is not warned twice
            quiet = entry.name in warned
            logger.log(logging.INFO if quiet else level_undrawable, "skipping unreadable episode file %s", exc)
            unreadable.append(entry.name)
            continue
        k = ep.meta.key
        t = np.asarray(ep.trajectory.t_s, float)
        by_cell.setdefault((k.scenario, k.episode, k.seed), []).append(
            Flight(entry, episodes, "", "", float(t[-1]) if len(t) else 0.0, ep.meta.outcome))
    if not by_cell:
        raise ValueError(f"{run_dir}: no readable saved episodes to show (unreadable: {', '.join(unreadable)})")
    all_pilots = sorted({p.pilot for found in by_cell.values() for p in found},
                        key=lambda m: (pilot_order.get(m, len(pilot_order)), m))
    colors = pilot_colors(all_pilots, info.colors())
    maps: dict[str, BuildingMap] = {}
    priors: dict[str, BuildingMap | None] = {}
    groups = []
    for (scenario, episode, seed) in sorted(by_cell, key=lambda c: (scen_order.get(c[0], len(scen_order)), c)):
        if scenario not in maps:
            maps[scenario] = load_map_file(run_dir / "maps" / f"{scenario}.yaml")
            prior = run_dir / "maps" / PRIOR_MAPS / f"{scenario}.yaml"
            priors[scenario] = load_map_file(prior) if prior.is_file() and not prior.is_symlink() else None
        found = sorted(by_cell[(scenario, episode, seed)],
                       key=lambda p: (pilot_order.get(p.pilot, len(pilot_order)), p.pilot))
        flights = tuple(replace(p, label=info.label(p.pilot), color=colors[p.pilot]) for p in found)
        sc = info.scenario(scenario)
        groups.append(FlightGroup(scenario, episode, seed, flights, maps[scenario],
                                  description=sc.description if sc else "", wind=sc.wind if sc else None,
                                  prior=priors[scenario]))
    return groups


def select_group(groups: Sequence[FlightGroup], spec: str) -> FlightGroup:
    """The group named by `spec`: `SCENARIO:EPISODE[:SEED]` (seed optional when the cell has one seed).

    Raises:
        ValueError: malformed spec or no such group, listing the groups there are.
    """
    parts = spec.split(":")
    known = ", ".join(g.spec for g in groups[:12]) + (" ..." if len(groups) > 12 else "")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        scenario, episode = parts[0], int(parts[1])
        seed = int(parts[2]) if len(parts) == 3 else None
    except ValueError:
        raise ValueError(f"--episode {spec!r}: expected SCENARIO:EPISODE[:SEED], e.g. {groups[0].spec}") from None
    hits = [g for g in groups if g.scenario == scenario and g.episode == episode and (seed is None or g.seed == seed)]
    if not hits:
        raise ValueError(f"--episode {spec!r}: no such flight in this run; there are: {known}")
    if len(hits) > 1:
        raise ValueError(f"--episode {spec!r}: flown with several seeds; add one: "
                         + ", ".join(g.spec for g in hits))
    return hits[0]


@dataclass(frozen=True)
class SampledFlight:
    """One pilot sampled on a time grid; after its flight ended it stays at its last known position.

    Attributes:
        t_s: (K,) the grid [s].
        pos_m: (K, 3) position, world ENU [m].
        speed_m_s: (K,) ground speed [m/s] (0 once ended).
        clearance_m: (K,) signed clearance of the collision sphere [m] (last value once ended).
        ended: (K,) True where t > the flight's end time.
    """

    t_s: np.ndarray
    pos_m: np.ndarray
    speed_m_s: np.ndarray
    clearance_m: np.ndarray
    ended: np.ndarray


def sample_flight(ep: SavedEpisode, t_s: np.ndarray) -> SampledFlight:
    """Sample a saved flight at times `t_s` [s] by linear interpolation of its saved rows (control or physics rate).

    Rows with a non-finite position (a diverged flight) are dropped first, so the vehicle stops
    where it was last known.
    """
    tr = ep.trajectory
    t_s = np.asarray(t_s, float)
    x = np.asarray(tr.states, float)
    t = np.asarray(tr.t_s, float)
    rows = np.flatnonzero(np.all(np.isfinite(x[:, 0:6]), axis=1)) if len(x) else np.arange(0)
    if len(rows) == 0:  # nothing flown (e.g. no plan): the vehicle sits at the start
        start = np.asarray(ep.meta.start_m, float)
        k = len(t_s)
        return SampledFlight(t_s, np.tile(start, (k, 1)), np.zeros(k), np.full(k, np.nan), np.ones(k, bool))
    t, x = t[rows], x[rows]
    clear = np.asarray(tr.clearance_m, float)[rows]
    pos = np.column_stack([np.interp(t_s, t, x[:, i]) for i in range(3)])
    speed = np.interp(t_s, t, np.linalg.norm(x[:, 3:6], axis=1))
    ended = t_s > t[-1]
    speed[ended] = 0.0
    return SampledFlight(t_s, pos, speed, np.interp(t_s, t, clear), ended)
