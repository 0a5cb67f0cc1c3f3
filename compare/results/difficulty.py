"""How hard each episode's task was, from a run folder's saved files, and success binned along it.

The axes along which the report asks where each pilot breaks:

* leg length: the straight-line start-goal distance of the episode (metrics.csv's `straight_line_m`) [m];
* building coverage: the share of the scenario's map area under building footprints (RUN_DIR/maps/*.yaml);
* turbulence: the scenario's turbulence level (run.json);
* air density at the field (run.json) [kg/m³], also given as a density altitude (the ISA altitude where
  the standard atmosphere has that density) [m].

`success_by_difficulty` bins one vehicle's episodes along each axis (the same bins for every pilot)
and gives each pilot's success rate per bin with its Wilson interval: a bin of 3 episodes shows as
what it is, an interval most of [0, 1] wide.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon, box

from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import ScenarioInfo
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.air.wind import TurbulenceLevel
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.stats import wilson_interval

MAX_BINS = 4
"""Bins per axis: an axis with at most this many distinct values gets one bin per value, else equal-count bins."""

def building_coverage(bmap: BuildingMap) -> float:
    """Share of the map's ground area (its x-y bounds) under building footprints, overlaps counted once, in [0, 1]."""
    lo, hi = bmap.bounds_min_m, bmap.bounds_max_m
    ground = box(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    if ground.area <= 0.0:
        return 0.0
    footprints = [Polygon(b.footprint_xy_m()) for b in bmap.buildings]
    covered = shapely.union_all(footprints).intersection(ground) if footprints else None
    return 0.0 if covered is None else float(covered.area / ground.area)


@dataclass(frozen=True)
class ScenarioConditions:
    """What made one scenario hard (None: not recorded).

    Attributes:
        scenario: its name. vehicle: the vehicle flown.
        building_coverage: share of the map area under building footprints, in [0, 1].
        turbulence: the turbulence level's name. density_kg_m3: the air density at the field [kg/m³].
    """

    scenario: str
    vehicle: str
    building_coverage: float | None
    turbulence: str | None
    density_kg_m3: float | None

    @property
    def density_altitude_m(self) -> float | None:
        """The field's density altitude [m] (None where the density was not recorded)."""
        return None if self.density_kg_m3 is None else density_altitude_m(self.density_kg_m3)


def scenario_conditions(info: ScenarioInfo, bmap: BuildingMap | None) -> ScenarioConditions:
    """The conditions of a scenario from its run.json entry and its saved map (None: the map file is missing)."""
    return ScenarioConditions(info.name, info.vehicle, None if bmap is None else building_coverage(bmap),
                              info.wind.turbulence, info.atmosphere.density_kg_m3)


@dataclass(frozen=True)
class RateBin:
    """One pilot's success in one bin: successes of n episodes, the rate and its Wilson interval (None for n = 0)."""

    successes: int
    n: int
    rate: float | None
    low: float | None
    high: float | None


@dataclass(frozen=True)
class DifficultyAxis:
    """Success along one difficulty axis, for one vehicle.

    Attributes:
        name: the axis with its unit, e.g. "leg length [m]".
        bins: the bins' labels, easiest first where the axis has an order.
        rates: per pilot (in the order asked), one `RateBin` per bin.
        left_out: episodes without a value on this axis (the scenario did not record it).
    """

    name: str
    bins: tuple[str, ...]
    rates: Mapping[str, tuple[RateBin, ...]]
    left_out: int = 0


def success_by_difficulty(rows: Sequence[EpisodeMetrics], conditions: Mapping[str, ScenarioConditions],
                          pilots: Sequence[str], confidence: float = 0.95) -> tuple[DifficultyAxis, ...]:
    """Each pilot's success rate binned along each difficulty axis (leg length, building coverage, turbulence,
    air density), from one vehicle's rows.

    Bins are shared by the pilots: they are made over the distinct cells (scenario, episode, seed), at most
    `MAX_BINS` per axis (one per value where there are that few, else about equal counts of cells).

    Args:
        rows: one vehicle's metrics rows.
        conditions: the scenarios' conditions, by scenario name (a scenario absent: its values are unknown).
        pilots: the pilots to give rates for, in order.
        confidence: the Wilson intervals' level.
    """
    def cond(r: EpisodeMetrics) -> ScenarioConditions | None:
        return conditions.get(r.scenario)

    def coverage(r: EpisodeMetrics) -> float | None:
        c = cond(r)
        return None if c is None else c.building_coverage

    def density(r: EpisodeMetrics) -> float | None:
        c = cond(r)
        return None if c is None else c.density_kg_m3

    def turbulence(r: EpisodeMetrics) -> str | None:
        c = cond(r)
        return None if c is None else c.turbulence

    def leg(r: EpisodeMetrics) -> float | None:
        return r.straight_line_m if math.isfinite(r.straight_line_m) else None

    return (_numeric_axis("leg length [m]", rows, pilots, leg, lambda v: f"{v:.0f}", confidence),
            _numeric_axis("building coverage of the map [%]", rows, pilots, coverage,
                          lambda v: f"{100.0 * v:.0f}", confidence),
            _category_axis("turbulence", rows, pilots, turbulence, confidence),
            _numeric_axis("air density at the field [kg/m³] (DA: density altitude)", rows, pilots, density,
                          lambda v: f"{v:.3f} (DA {density_altitude_m(v):.0f} m)", confidence, harder_when_low=True,
                          fmt_range=lambda lo, hi: (f"{lo:.3f}–{hi:.3f} (DA {density_altitude_m(hi):.0f}–"
                                                    f"{density_altitude_m(lo):.0f} m)")))


def _cell(r: EpisodeMetrics) -> tuple[str, int, int]:
    return (r.scenario, r.episode, r.seed)


def _numeric_axis(name: str, rows: Sequence[EpisodeMetrics], pilots: Sequence[str],
                  value: Callable[[EpisodeMetrics], float | None], fmt: Callable[[float], str], confidence: float,
                  harder_when_low: bool = False, fmt_range: Callable[[float, float], str] | None = None
                  ) -> DifficultyAxis:
    """Bins of a numeric axis: one per distinct value when there are at most `MAX_BINS`, else quantile bins
    (labelled `fmt_range(low, high)`, by default "fmt(low)–fmt(high)"); harder (higher, or lower with
    `harder_when_low`) to the right."""
    if fmt_range is None:
        def fmt_range(lo: float, hi: float) -> str:
            return f"{fmt(lo)}–{fmt(hi)}"
    cells = {_cell(r): v for r in rows if (v := value(r)) is not None}
    distinct = sorted(set(cells.values()), reverse=harder_when_low)
    if len(distinct) <= MAX_BINS:
        labels = tuple(fmt(v) for v in distinct)
        index = {v: k for k, v in enumerate(distinct)}

        def which(v: float) -> int:
            return index[v]
    else:
        values = np.array(sorted(cells.values()))
        edges = np.unique(np.quantile(values, np.linspace(0.0, 1.0, MAX_BINS + 1)))
        inner = edges[1:-1]
        # bin k holds values in (edges[k], edges[k + 1]], the first also its low end
        counts = np.bincount(np.searchsorted(inner, values, side="left"), minlength=len(edges) - 1)
        keep = [k for k in range(len(edges) - 1) if counts[k]]
        labels = tuple(fmt_range(float(edges[k]), float(edges[k + 1])) for k in keep)
        slot = {k: i for i, k in enumerate(keep)}
        if harder_when_low:
            labels = labels[::-1]
            slot = {k: len(keep) - 1 - i for k, i in slot.items()}

        def which(v: float) -> int:
            return slot[int(np.searchsorted(inner, v, side="left"))]
    return _axis(name, labels, rows, pilots, lambda r: None if (v := value(r)) is None else which(v), confidence)


def _category_axis(name: str, rows: Sequence[EpisodeMetrics], pilots: Sequence[str],
                   value: Callable[[EpisodeMetrics], str | None], confidence: float) -> DifficultyAxis:
    """Bins of a named level (turbulence): one per level present, in the levels' order (unknown names last)."""
    order = [level.value for level in TurbulenceLevel]
    present = {v for r in rows if (v := value(r)) is not None}
    labels = tuple(sorted(present, key=lambda v: (order.index(v) if v in order else len(order), v)))
    return _axis(name, labels, rows, pilots, lambda r: None if (v := value(r)) is None else labels.index(v),
                 confidence)


def _axis(name: str, labels: tuple[str, ...], rows: Sequence[EpisodeMetrics], pilots: Sequence[str],
          which: Callable[[EpisodeMetrics], int | None], confidence: float) -> DifficultyAxis:
    """Count each pilot's successes per bin (`which` gives a row's bin, None: left out) into `RateBin`s."""
    wins = {m: [0] * len(labels) for m in pilots}
    total = {m: [0] * len(labels) for m in pilots}
    left_out: set[tuple[str, int, int]] = set()
    for r in rows:
        k = which(r)
        if k is None:
            left_out.add(_cell(r))
        elif r.method in total:
            total[r.method][k] += 1
            wins[r.method][k] += int(r.success)
    return DifficultyAxis(name, labels, {m: tuple(_rate(wins[m][k], total[m][k], confidence)
                                                  for k in range(len(labels))) for m in pilots}, len(left_out))


def _rate(successes: int, n: int, confidence: float) -> RateBin:
    if n == 0:
        return RateBin(0, 0, None, None, None)
    low, high = wilson_interval(successes, n, confidence)
    return RateBin(successes, n, successes / n, low, high)
