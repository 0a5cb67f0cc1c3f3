"""The maps a sensing slot of the training batch needs beyond the world's sensors: a ray caster over its TRUE world
(what its lidar and, in an urban canyon, its GNSS receiver see) and the height maps of its PRIOR map (what its
lidar view starts from, `rl.sensing.lidar_view.PriorRoofs`).

Both are built when an episode first needs them and kept in small caches, so a world of a thousand cities and
their map-error draws holds only what the slots fly in now and what they flew in recently:

* `TrueWorlds` numbers the true worlds as the world's truth sensing does (`rl.sensing.truth.MapDraw.geometry`: a
  city as it stands by its index, a draw that adds obstacles after the cities) and hands `BatchOnboard` one stand-in
  per number (`casters`, `cities`) that reaches the real caster or map only when the sensors use it. It keeps the
  maps and casters of the worlds some slot flies in, and the casters of the `CACHED_CASTERS` worlds left most
  recently (a caster is a pure function of its map: one built again gives the same numbers).
* `PriorRoofBank` holds each slot's prior height maps: the world's own `Perception` when the prior is the city as
  it stands, else a `Perception` over the drawn prior (one per (city, level, draw), cached); rows are read by slot.

Frames and units: world ENU metres.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from typing import Generic, TypeVar, cast

import numpy as np

from rl.sensing.perception import Perception, PerceptionConfig
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.sensing.raycast import RayCaster

CACHED_CASTERS = 64  # true worlds' ray casters kept beyond those flown in (~0.3 MB and ~1 ms to build each)
CACHED_PRIORS = 64  # drawn priors' height maps kept beyond those in flight (~0.1 MB and ~3 ms each)

_V = TypeVar("_V")


class _Recent(Generic[_V]):
    """The `size` most recently used values by key, each made by `make` when missing."""

    def __init__(self, size: int) -> None:
        self.size = int(size)
        self._items: OrderedDict[Hashable, _V] = OrderedDict()

    def get(self, key: Hashable, make: Callable[[], _V]) -> _V:
        """The value of `key`, made now when missing (it becomes the most recent)."""
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        value = make()
        self.put(key, value)
        return value

    def put(self, key: Hashable, value: _V) -> None:
        """Keep `value` as `key`'s, the most recent (the least recent beyond `size` is dropped)."""
        self._items[key] = value
        self._items.move_to_end(key)
        if len(self._items) > self.size:
            self._items.popitem(last=False)

    def pop(self, key: Hashable) -> _V | None:
        """Take `key`'s value out (None: not kept)."""
        return self._items.pop(key, None)

    def __len__(self) -> int:
        return len(self._items)


class TrueWorlds:
    """The true worlds of N slots, by geometry index: their maps (as the slots fly them) and ray casters.

    Args:
        n_worlds: how many geometry indices there are (the world's cities plus its truths that add obstacles).
        n: slots.
    """

    def __init__(self, n_worlds: int, n: int) -> None:
        self.n_worlds = int(n_worlds)
        self._geometry = np.full(int(n), -1, dtype=np.int64)  # each slot's world (-1: none, it senses nothing)
        # the worlds some slot flies in: how many slots, their maps, their casters once built
        self._users: dict[int, int] = {}
        self._maps: dict[int, BuildingMap] = {}
        self._flying: dict[int, RayCaster] = {}
        self._recent: _Recent[RayCaster] = _Recent(CACHED_CASTERS)  # the casters of worlds no slot flies in now

    def assign(self, slot: int, geometry: int, truth: BuildingMap) -> None:
        """Slot `slot` flies in true world `geometry` (an index below `n_worlds`), whose map is `truth`."""
        if not 0 <= geometry < self.n_worlds:
            raise ValueError(f"geometry {geometry} is not a true world (0 to {self.n_worlds - 1})")
        self.release(slot)
        self._geometry[slot] = geometry
        self._users[geometry] = self._users.get(geometry, 0) + 1
        self._maps[geometry] = truth

    def release(self, slot: int) -> None:
        """Slot `slot` no longer senses its world (a new episode, or one flying on the truth)."""
        g = int(self._geometry[slot])
        if g < 0:
            return
        self._geometry[slot] = -1
        self._users[g] -= 1
        if not self._users[g]:
            del self._users[g], self._maps[g]
            caster = self._flying.pop(g, None)
            if caster is not None:
                self._recent.put(g, caster)

    def truth(self, geometry: int) -> BuildingMap:
        """The map of true world `geometry`, as the slots flying in it have it.

        Raises:
            LookupError: no slot flies in it.
        """
        if geometry not in self._maps:
            raise LookupError(f"no slot flies in true world {geometry}")
        return self._maps[geometry]

    def caster(self, geometry: int) -> RayCaster:
        """The ray caster over true world `geometry` (buildings, the obstacles the prior lacks, the ground), where
        some slot flies."""
        caster = self._flying.get(geometry)
        if caster is None:
            caster = self._recent.pop(geometry) or RayCaster(self.truth(geometry))
            self._flying[geometry] = caster
        return caster

    @property
    def kept(self) -> int:
        """Ray casters held: those of the worlds flown in now and the recent others."""
        return len(self._flying) + len(self._recent)

    @property
    def casters(self) -> Sequence[RayCaster]:
        """One stand-in per geometry index for `BatchOnboard`'s `casters` and `lidar_casters`."""
        return cast(Sequence[RayCaster], [_WorldCaster(self, g) for g in range(self.n_worlds)])

    @property
    def cities(self) -> Sequence[BuildingMap]:
        """One stand-in per geometry index for `BatchOnboard`'s `cities` (an urban canyon's walls)."""
        return cast(Sequence[BuildingMap], [_WorldMap(self, g) for g in range(self.n_worlds)])


class _WorldCaster:
    """Stands in for the ray caster of one true world: the calls the sensors make, passed to the real one."""

    def __init__(self, worlds: TrueWorlds, geometry: int) -> None:
        self.worlds, self.geometry = worlds, geometry

    def ranges_m(self, origins_m: np.ndarray, directions: np.ndarray, max_range_m: float, *,
                 exact: bool = False) -> np.ndarray:
        return self.worlds.caster(self.geometry).ranges_m(origins_m, directions, max_range_m, exact=exact)

    def hits_any(self, origins_m: np.ndarray, directions: np.ndarray, max_range_m: float = np.inf) -> np.ndarray:
        return self.worlds.caster(self.geometry).hits_any(origins_m, directions, max_range_m)


class _WorldMap:
    """Stands in for the map of one true world: what an urban-canyon receiver reads of it (its walls)."""

    def __init__(self, worlds: TrueWorlds, geometry: int) -> None:
        self.worlds, self.geometry = worlds, geometry

    @property
    def building_ids(self) -> np.ndarray:
        return self.worlds.truth(self.geometry).building_ids

    def nearest_obstacles_batch(self, points_m: np.ndarray, k: int, radius_m: float = 0.0,
                                pad_distance_m: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.worlds.truth(self.geometry).nearest_obstacles_batch(points_m, k, radius_m, pad_distance_m)


class PriorRoofBank:
    """The prior maps' height maps of N slots (`PriorRoofs`; the city index `roofs` takes is the SLOT).

    Args:
        perception: the world's perception over its cities as they stand (the prior of the exact level).
        n: slots.
    """

    def __init__(self, perception: Perception, n: int) -> None:
        self.perception = perception
        self.radius_m: float = perception.radius_m
        self.config: PerceptionConfig = perception.config
        self._of_slot: list[tuple[Perception, int]] = [(perception, 0)] * int(n)
        self._drawn: _Recent[Perception] = _Recent(CACHED_PRIORS)

    def assign(self, slot: int, ci: int, prior: BuildingMap, key: Hashable) -> None:
        """Slot `slot`'s prior: city `ci` as it stands when `prior` is that city, else the drawn map `prior`,
        cached under `key` (e.g. its city, level and draw)."""
        if prior is self.perception.cities[ci]:
            self._of_slot[slot] = (self.perception, ci)
        else:
            self._of_slot[slot] = (self._drawn.get(key, lambda: Perception([prior], self.radius_m, self.config)), 0)

    def release(self, slot: int) -> None:
        """Slot `slot` reads no prior now (its episode flies on the truth): its drawn prior is no longer held."""
        self._of_slot[slot] = (self.perception, 0)

    def roofs(self, points_m: np.ndarray, heading_rad: np.ndarray, city: np.ndarray) -> np.ndarray:
        """Height maps (N, grid_cells**2) [m] around points (N, 3) [m, world] in goal frames at headings (N,)
        [rad], each in the prior of its slot `city` (N,)."""
        slots = np.asarray(city, dtype=np.int64).reshape(-1)
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        h = np.asarray(heading_rad, dtype=float).reshape(-1)
        owners = [self._of_slot[s] for s in slots.tolist()]
        if all(o[0] is self.perception for o in owners):  # the common case: one call
            return self.perception.roofs(p, h, np.array([o[1] for o in owners], dtype=np.int64))
        out = np.empty((len(slots), self.config.grid_cells ** 2))
        groups: dict[int, tuple[Perception, list[int]]] = {}  # rows by source, in one pass (not one per source)
        for k, (source, _) in enumerate(owners):
            groups.setdefault(id(source), (source, []))[1].append(k)
        for source, rows in groups.values():
            out[rows] = source.roofs(p[rows], h[rows], np.array([owners[k][1] for k in rows]))
        return out
