"""The air a task's episodes fly in: field elevation and temperature (density), turbulence and steady wind.

Each episode of a task flies one field of a pool (`AirDistribution.fields`: elevation and ISA offset drawn
from the task's ranges at fixed seeds, each tabulated once from JSBSim's standard atmosphere), one
turbulence level (drawn uniformly from the task's levels) and a steady horizontal wind of uniform speed
in [0, `steady_wind_max_m_s`] and uniform heading. Thin air is thrust-to-weight: a density altitude of
3 km is sigma ~0.74, 26 % less thrust at the same rotor speed.

`AIR_LEVELS` are the benchmark's levels of the air (compare.scenarios.benchmark): the same names serve
`uam-compare evaluate-policy --air` and the robustness sweep.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uam_fdm.air.atmosphere import AtmosphereConditions
from uam_fdm.air.wind import TurbulenceLevel

_POOL_STREAM = 0xA12  # PCG64 stream tag of the pool's draws (independent of every episode's generator)


@dataclass(frozen=True)
class AirLevel:
    """A level of the air: field elevation [m MSL] and ISA temperature offset [K], each uniform in its range."""

    name: str
    elevation_m: tuple[float, float]
    isa_offset_k: tuple[float, float]


AIR_LEVELS: dict[str, AirLevel] = {level.name.replace(" ", "-"): level for level in (
    AirLevel("sea level", (0.0, 0.0), (0.0, 0.0)),  # a standard day
    AirLevel("warm and raised", (600.0, 1200.0), (10.0, 20.0)),
    AirLevel("hot and high", (1800.0, 2600.0), (20.0, 30.0)),
)}
"""The benchmark's air levels by their option names: sea-level, warm-and-raised, hot-and-high."""


@dataclass(frozen=True)
class AirDistribution:
    """The air of a task's episodes (defaults: the shipped policies' training air).

    Attributes:
        elevation_m: field elevation range [m above mean sea level] of the pool's fields (uniform).
        isa_offset_k: ISA temperature offset range [K] of the pool's fields (uniform).
        turbulence: turbulence levels (none/light/moderate/severe); each episode draws one uniformly.
        steady_wind_max_m_s: each episode's steady horizontal wind speed is uniform in [0, this] [m/s].
        pool_size: fields tabulated once per world, each episode flying one drawn uniformly: the densest
            (lowest, coldest) and the thinnest (highest, hottest) corner of the ranges, so both ends of the
            envelope are flown, and the rest drawn uniformly in the ranges at fixed seeds. One field when both
            ranges are a single value.
    """

    elevation_m: tuple[float, float] = (0.0, 0.0)
    isa_offset_k: tuple[float, float] = (0.0, 0.0)
    turbulence: tuple[str, ...] = ("light",)
    steady_wind_max_m_s: float = 3.0
    pool_size: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "elevation_m", tuple(float(v) for v in self.elevation_m))
        object.__setattr__(self, "isa_offset_k", tuple(float(v) for v in self.isa_offset_k))
        object.__setattr__(self, "turbulence", tuple(self.turbulence))
        for name in ("elevation_m", "isa_offset_k"):
            lo_hi = getattr(self, name)
            if len(lo_hi) != 2 or not lo_hi[0] <= lo_hi[1]:
                raise ValueError(f"air.{name} must be a range [low, high] with low <= high, got {list(lo_hi)}")
        AtmosphereConditions(self.elevation_m[0], self.isa_offset_k[0])  # each end within the accepted range
        AtmosphereConditions(self.elevation_m[1], self.isa_offset_k[1])
        if not self.turbulence:
            raise ValueError("air.turbulence must name at least one level")
        for level in self.turbulence:
            TurbulenceLevel.parse(level)
        if len(set(self.turbulence)) != len(self.turbulence):
            raise ValueError(f"air.turbulence names a level twice: {list(self.turbulence)}")
        if not (np.isfinite(self.steady_wind_max_m_s) and self.steady_wind_max_m_s >= 0.0):
            raise ValueError(f"air.steady_wind_max_m_s must be a finite speed >= 0, got {self.steady_wind_max_m_s!r}")
        if self.pool_size < 1:
            raise ValueError(f"air.pool_size must be >= 1, got {self.pool_size}")

    @classmethod
    def at_level(cls, level: str, turbulence: tuple[str, ...] = ("light",), steady_wind_max_m_s: float = 3.0,
                 pool_size: int = 16) -> AirDistribution:
        """The air of one of `AIR_LEVELS` (by option name, e.g. "hot-and-high").

        Raises:
            ValueError: an unknown level, naming the known ones.
        """
        if level not in AIR_LEVELS:
            raise ValueError(f"unknown air level {level!r}; choose from {', '.join(AIR_LEVELS)}")
        a = AIR_LEVELS[level]
        return cls(a.elevation_m, a.isa_offset_k, turbulence, steady_wind_max_m_s, pool_size)

    @property
    def levels(self) -> tuple[TurbulenceLevel, ...]:
        """The turbulence levels, parsed."""
        return tuple(TurbulenceLevel.parse(t) for t in self.turbulence)

    def fields(self) -> list[AtmosphereConditions]:
        """The pool's fields: one for single-valued ranges, else `pool_size`: the densest and the thinnest
        corner, then draws at fixed seeds (the same for every world of this distribution, so a training world
        and its validation world share them)."""
        (e0, e1), (t0, t1) = self.elevation_m, self.isa_offset_k
        if e0 == e1 and t0 == t1:
            return [AtmosphereConditions(e0, t0)]
        corners = [AtmosphereConditions(e0, t0), AtmosphereConditions(e1, t1)][:self.pool_size]
        rng = np.random.Generator(np.random.PCG64([self.pool_size, _POOL_STREAM]))
        drawn = [AtmosphereConditions(round(float(rng.uniform(e0, e1)), 1), round(float(rng.uniform(t0, t1)), 2))
                 for _ in range(self.pool_size - len(corners))]
        return corners + drawn
