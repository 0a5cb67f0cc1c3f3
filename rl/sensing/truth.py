"""Map error in the learned pilot's world: per city a bank of (truth, prior) draws, and the truth's sensing.

An episode flies in the TRUTH (it collides with it and senses it: clearance, rays, height map) and follows a
route field drawn from the PRIOR map (`uam_fdm.city.map_error.apply_map_error`: buildings missing, heights and
footprints off, no cranes or masts). Each configured level (`NavConfig.map_error`) holds `map_error_draws` draws
per city, draw d of city seed s at the seed `draw_seed(s, d)`; `exact` holds one (prior = truth = the city).

Memory: a draw's prior and truth are not kept (they are a pure function of city, level and seed, re-made when an
episode draws them; a small cache keeps the latest). What the batched sensing needs is kept: the obstacles the
truth adds to the city (a `wrong` draw's cranes and masts), each as its own small "city" (its footprint's box plus
a metre), so their sensors hold a few kB per obstacle instead of a second copy of every city.

Frames and units: world ENU metres.
"""
from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rl.sensing.observation import ObservationScales
from rl.sensing.perception import Perception, PerceptionConfig, PerceptionReading
from rl.sensing.sensor import BoxSensor, SensorReading
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.map_error import MapErrorResult, apply_map_error, map_error_preset

_DRAW_TAG = 0x4D45_4452  # mixed into a draw's seed: apart from every other stream of the city seed
_CACHE = 256  # draws' (truth, prior) kept for episodes drawing them again
_MARGIN_M = 1.0  # an added obstacle's own "city" reaches this far beyond its footprint [m]


def draw_seed(city_seed: int, draw: int) -> int:
    """The `apply_map_error` seed of draw `draw` of city `city_seed` (a 32-bit integer, same on any machine)."""
    return int(np.random.SeedSequence([int(city_seed), int(draw), _DRAW_TAG]).generate_state(1)[0])


@dataclass(frozen=True)
class MapDraw:
    """The map of one episode.

    Attributes:
        level: index of the level in the bank's `levels`; draw: the draw within it.
        truth: what the vehicle collides with and senses; prior: what its route field is drawn from.
        geometry: the truth's index in the world's sensing (the city's index when the truth adds nothing to it).
    """

    level: int
    draw: int
    truth: BuildingMap
    prior: BuildingMap
    geometry: int


class MapErrorBank:
    """Draws of (truth, prior) per city for the configured map-error levels.

    Args:
        cities: the world's cities (as they stand: the exact level's truth and prior).
        city_seeds: one seed per city (the generator seed, or its index for scenario cities).
        levels: map-error presets ("exact", "outdated", "wrong").
        draws: draws per city of each level that is not exact.
    """

    def __init__(self, cities: Sequence[BuildingMap], city_seeds: Sequence[int], levels: Sequence[str],
                 draws: int) -> None:
        if len(cities) != len(city_seeds) or not levels or draws < 1:
            raise ValueError(f"need one seed per city, a level and draws >= 1; got {len(cities)} cities, "
                             f"{len(city_seeds)} seeds, levels {tuple(levels)}, {draws} draws")
        self.cities, self.seeds = list(cities), [int(s) for s in city_seeds]
        self.levels = tuple(levels)
        self.presets = tuple(map_error_preset(level) for level in self.levels)
        self.draws = int(draws)
        self.result = functools.lru_cache(maxsize=_CACHE)(self._result)
        # the truths that add obstacles to their city: geometry index len(cities) + j
        self._geometry: dict[tuple[int, int, int], int] = {}
        self.added: list[tuple[int, tuple[Building, ...]]] = []  # (city, the obstacles the truth adds)
        for ci in range(len(self.cities)):
            for k, preset in enumerate(self.presets):
                if not (preset.cranes or preset.masts):
                    continue
                for d in range(self.draws_of(k)):
                    r = self._result(ci, k, d)
                    generated = set(r.generated_ids)  # cranes and masts: boxes (`map_error._crane`, `_mast`)
                    extra = tuple(b for b in r.truth.buildings if isinstance(b, Building) and b.id in generated)
                    if extra:
                        self._geometry[(ci, k, d)] = len(self.cities) + len(self.added)
                        self.added.append((ci, extra))

    def draws_of(self, level: int) -> int:
        """Draws banked for level index `level` (1 for an exact level)."""
        return 1 if self.presets[level].exact else self.draws

    def _result(self, ci: int, level: int, draw: int) -> MapErrorResult:
        """`apply_map_error` of city ci at level index `level`, draw `draw` (no keep-clear points: tasks are drawn
        free in both maps afterwards)."""
        city = self.cities[ci]
        preset = self.presets[level]
        if preset.exact:
            return MapErrorResult(truth=city, prior=city, unmapped_ids=())
        return apply_map_error(city, (), preset, draw_seed(self.seeds[ci], draw), np.zeros((0, 3)), 0.0)

    def draw(self, ci: int, level: int, draw: int) -> MapDraw:
        """The map of city ci at level index `level`, draw `draw`."""
        r = self.result(ci, level, draw)
        return MapDraw(level, draw, r.truth, r.prior, self._geometry.get((ci, level, draw), ci))

    def exact(self, ci: int) -> MapDraw:
        """City ci as it stands (prior = truth), for episodes placed without a draw (at the `exact` level's index, or
        the first level's in a bank without one)."""
        city = self.cities[ci]
        return MapDraw(self.levels.index("exact") if "exact" in self.levels else 0, 0, city, city, ci)


class TruthSensing:
    """Clearance sensor and perception of the truths: the cities' own, and for a truth that adds obstacles the
    nearer (rays, clearance) or higher (height map) of its city's reading and its obstacles' readings.

    Query methods take geometry indices (`MapDraw.geometry`) where `BoxSensor` and `Perception` take city indices;
    a row in a city as it stands gets the city's sensors' numbers unchanged. Added obstacles are exact in the
    clearance (raised boxes too, `BoxSensor`) and, like every box, columns from the ground in the rays and the
    height map (`Perception`: conservative for a crane's jib).

    Args:
        sensor, perception: the cities' (`rl.sensing.senses.clearance_sensor`, `Perception`).
        added: per added geometry (index len(cities) + j): its city and the obstacles the truth adds.
        scales, radius_m, config: as the cities' sensors were built (range, vehicle collision radius [m], rays).
    """

    def __init__(self, sensor: BoxSensor, perception: Perception, added: Sequence[tuple[int, Sequence[Building]]],
                 scales: ObservationScales, radius_m: float, config: PerceptionConfig) -> None:
        self.sensor, self.perception = sensor, perception
        self.radius_m, self.range_m, self.k = sensor.radius_m, sensor.range_m, sensor.k
        n_city = len(sensor.cities)
        self._city = np.concatenate([np.arange(n_city), np.array([ci for ci, _ in added], dtype=np.int64)])
        self._n_city = n_city
        pieces: list[_Piece] = []  # one small city per added obstacle id (a crane's mast and jib together)
        counts = []
        for _, boxes in added:
            ids = sorted({b.id for b in boxes})
            counts.append(len(ids))
            pieces += [_piece([b for b in boxes if b.id == i]) for i in ids]
        self._count = np.array(counts, dtype=np.int64)
        self._start = np.cumsum(self._count) - self._count
        rng = scales.clearance_m
        # (the pieces read as cities: boxes, bounds and a name are all the sensors take from a map)
        self.added_sensor = BoxSensor(pieces, 1, rng, radius_m, cell_m=max(10.0, rng / 3.0)) if pieces else None  # type: ignore[arg-type]
        self.added_perception = Perception(pieces, radius_m, config) if pieces else None  # type: ignore[arg-type]

    @property
    def nbytes(self) -> int:
        """Bytes held for the added obstacles' sensing (the cities' own sensors are not counted)."""
        if self.added_perception is None or self.added_sensor is None:
            return 0
        s = self.added_sensor
        return self.added_perception.nbytes + sum(a.nbytes for a in (s._tab, s._cand, s._id, s._origin, s._dims))

    def _split(self, geometry: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """City indices (N,); rows with added obstacles (S,); their repeated row per obstacle (R,), the obstacles'
        pieces (R,) and each row's first entry in those (S,)."""
        g = np.asarray(geometry, dtype=np.int64).reshape(-1)
        sel = np.flatnonzero(g >= self._n_city)
        j = g[sel] - self._n_city
        cnt = self._count[j]
        seg = np.cumsum(cnt) - cnt
        rows = np.repeat(sel, cnt)
        piece = np.arange(int(cnt.sum())) - np.repeat(seg, cnt) + np.repeat(self._start[j], cnt)
        return self._city[g], sel, rows, piece, seg

    def query(self, points_m: np.ndarray, geometry: np.ndarray) -> SensorReading:
        """`BoxSensor.query` (k = 1) of points (N, 3) [m] in their truths (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        ci, sel, rows, piece, seg = self._split(geometry)
        r = self.sensor.query(p, ci)
        if not len(sel) or self.added_sensor is None:
            return r
        e = self.added_sensor.query(p[rows], piece)
        best = seg + _segment_argmin(e.distance_m[:, 0], seg)
        nearer = e.distance_m[best, 0] < r.distance_m[sel, 0]
        s, b = sel[nearer], best[nearer]
        r.nearest_m[s], r.distance_m[s], r.building_id[s] = e.nearest_m[b], e.distance_m[b], e.building_id[b]
        r.clearance_m[sel] = np.minimum(r.clearance_m[sel], e.clearance_m[best])
        return r

    def clearance(self, points_m: np.ndarray, geometry: np.ndarray) -> np.ndarray:
        """`BoxSensor.clearance` (N,) [m] of spheres at points (N, 3) [m] in their truths (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        ci, sel, rows, piece, seg = self._split(geometry)
        c = self.sensor.clearance(p, ci)
        if len(sel) and self.added_sensor is not None:
            c[sel] = np.minimum(c[sel], np.minimum.reduceat(self.added_sensor.clearance(p[rows], piece), seg))
        return c

    def observe(self, points_m: np.ndarray, heading_rad: np.ndarray, geometry: np.ndarray) -> PerceptionReading:
        """`Perception.observe` of points (N, 3) [m] at headings (N,) [rad] in their truths (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        h = np.asarray(heading_rad, dtype=float).reshape(-1)
        ci, sel, rows, piece, seg = self._split(geometry)
        r = self.perception.observe(p, h, ci)
        if not len(sel) or self.added_perception is None:
            return r
        e = self.added_perception.observe(p[rows], h[rows], piece)
        r.ray_m[sel] = np.minimum(r.ray_m[sel], np.minimum.reduceat(e.ray_m, seg, axis=0))
        r.roof_m[sel] = np.maximum(r.roof_m[sel], np.maximum.reduceat(e.roof_m, seg, axis=0))
        return r

    def free_distance(self, points_m: np.ndarray, bearing_rad: np.ndarray, geometry: np.ndarray) -> np.ndarray:
        """`Perception.free_distance` (N,) [m] of points (N, 3) [m] along bearings (N,) [rad] in their truths (N,)."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        b = np.asarray(bearing_rad, dtype=float).reshape(-1)
        ci, sel, rows, piece, seg = self._split(geometry)
        d = self.perception.free_distance(p, b, ci)
        if len(sel) and self.added_perception is not None:
            e = self.added_perception.free_distance(p[rows], b[rows], piece)
            d[sel] = np.minimum(d[sel], np.minimum.reduceat(e, seg))
        return d


@dataclass(frozen=True)
class _Piece:
    """One added obstacle as its own small city, as the sensors read a `BuildingMap` (its boxes, bounds [m] and
    name) without a map's collision structures (tens of thousands of pieces in a large world)."""

    buildings: tuple[Building, ...]
    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]
    name: str


def _piece(boxes: Sequence[Building]) -> _Piece:
    """One added obstacle's boxes; bounds: their footprints' box plus `_MARGIN_M`."""
    xy = np.concatenate([np.asarray(b.footprint_xy_m()) for b in boxes])
    lo, hi = xy.min(axis=0) - _MARGIN_M, xy.max(axis=0) + _MARGIN_M
    top = max(b.height_m for b in boxes) + _MARGIN_M
    return _Piece(tuple(boxes), (float(lo[0]), float(lo[1]), 0.0), (float(hi[0]), float(hi[1]), top),
                  f"added-{boxes[0].id}")


def _segment_argmin(values: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Per segment (starts `seg`, contiguous, non-empty, covering `values`) the offset of its least value."""
    cnt = np.diff(np.append(seg, len(values)))
    pad = np.full((len(seg), int(cnt.max())), np.inf)
    pad[np.repeat(np.arange(len(seg)), cnt), np.arange(len(values)) - np.repeat(seg, cnt)] = values
    return pad.argmin(axis=1)
