"""Atmosphere from JSBSim: density, temperature, pressure and speed of sound above the field.

JSBSim (``FGStandardAtmosphere``: the 1976 U.S. Standard Atmosphere, identical to the ICAO Standard
Atmosphere (ISA) below 11 km geopotential altitude) gives the atmosphere over a field at a given elevation
above mean sea level with an ISA temperature offset. The offset follows the convention of performance and
density-altitude charts: at a given height it changes the temperature but not the pressure, so the density
is the standard day's scaled by T_std / T (the textbook ISA+dT density).

JSBSim is called only while building the table: :meth:`Atmosphere.from_jsbsim` evaluates the atmosphere
once per grid row (default spacing 5 m, from 50 m below to 1000 m above the field); every query afterwards
is linear interpolation in that table (NumPy or plain floats), never JSBSim, and an :class:`Atmosphere` is
plain arrays, so it pickles (for process-level parallelism).

Frames and units: ``z_m`` is the ENU up coordinate, metres above the field (ground at z = 0);
SI units throughout (kg/m^3, K, Pa, m/s). Accuracy against the ICAO table and cost:
docs/design_notes.md, "uam_fdm.air.atmosphere".
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uam_fdm.files.strict import checked_number

__all__ = [
    "SEA_LEVEL_DENSITY_KG_M3",
    "density_altitude_m",
    "AtmosphereConditions",
    "AtmosphereSample",
    "Atmosphere",
    "jsbsim_exec",
    "load_probe_model",
    "PROBE_MODEL_NAME",
]

_log = logging.getLogger(__name__)

#: ISA sea-level density rho_0 (kg/m^3); the flight model's thrust scales with rho / rho_0.
SEA_LEVEL_DENSITY_KG_M3 = 1.225
# ISA troposphere: sea-level temperature [K], lapse rate [K/m], and the exponent g M / (R L) - 1 of rho(h)
_ISA_T0_K = 288.15
_ISA_LAPSE_K_M = 0.0065
_ISA_DENSITY_EXPONENT = 9.80665 / (287.05287 * _ISA_LAPSE_K_M) - 1.0

# Unit conversions at the JSBSim boundary (exact definitions or NIST values).
FT_TO_M = 0.3048
SLUG_FT3_TO_KG_M3 = 515.378818
PSF_TO_PA = 47.880259
RANKINE_PER_KELVIN = 1.8

# Limits for scenario inputs. JSBSim's model covers far more; these bounds catch typos
# (an elevation in feet, an offset in Fahrenheit) while allowing any real city.
ELEVATION_RANGE_M = (-500.0, 9000.0)
ISA_OFFSET_RANGE_K = (-50.0, 50.0)

# Our JSBSim aircraft (see uam_fdm/air/jsbsim/aircraft/windprobe/windprobe.xml): a point mass that
# cancels its own weight. It gives JSBSim's atmosphere a position and JSBSim's turbulence model
# a steady airspeed.
PROBE_MODEL_NAME = "windprobe"
_PROBE_AIRCRAFT_DIR = Path(__file__).resolve().parent / "jsbsim" / "aircraft"

# Columns of the internal table.
_RHO, _T, _P, _A = range(4)


@dataclass(frozen=True)
class AtmosphereConditions:
    """Where and on what kind of day the flight happens.

    Attributes:
        elevation_m: Field (ground, z = 0) elevation above mean sea level, metres.
        isa_offset_k: Temperature offset from the ISA standard day, kelvin (e.g. +20 for a hot day).

    Raises:
        ValueError: If a value is not finite or outside the accepted range.
    """

    elevation_m: float = 0.0
    isa_offset_k: float = 0.0

    def __post_init__(self) -> None:
        # Normalise to float so equal conditions compare and hash equal (1000 vs 1000.0).
        object.__setattr__(
            self, "elevation_m",
            checked_number("elevation_m", self.elevation_m, ELEVATION_RANGE_M, "m above mean sea level"),
        )
        object.__setattr__(
            self, "isa_offset_k",
            checked_number("isa_offset_k", self.isa_offset_k, ISA_OFFSET_RANGE_K, "K from the ISA day"),
        )


@dataclass(frozen=True)
class AtmosphereSample:
    """Atmospheric state at one or many heights (floats, or arrays shaped like the query).

    Attributes:
        density_kg_m3: Air density, kg/m^3.
        temperature_k: Static temperature, K.
        pressure_pa: Static pressure, Pa.
        speed_of_sound_m_s: Speed of sound, m/s.
    """

    density_kg_m3: Any
    temperature_k: Any
    pressure_pa: Any
    speed_of_sound_m_s: Any


class Atmosphere:
    """Tabulated JSBSim atmosphere above one field; queries are pure NumPy.

    Build with :meth:`from_jsbsim`. The table spans ``[z_min_m, z_max_m]`` metres above the
    field on a uniform grid; a query outside that span raises ``ValueError`` (the caller sizes
    the table from its map bounds, so an out-of-table height is a bug worth seeing).
    """

    def __init__(
        self,
        conditions: AtmosphereConditions,
        z_min_m: float,
        spacing_m: float,
        table: NDArray[np.float64],
    ) -> None:
        """Wrap an existing table (normally called by :meth:`from_jsbsim`).

        Args:
            conditions: Field elevation and ISA offset the table was built for.
            z_min_m: Height of the first row, metres above the field.
            spacing_m: Uniform row spacing, metres (> 0).
            table: (N, 4) array, N >= 2, columns density kg/m^3, temperature K, pressure Pa,
                speed of sound m/s, all finite and positive.

        Raises:
            ValueError: If the table is malformed.
        """
        table = np.array(table, dtype=np.float64)  # own copy: the object must stay immutable
        if table.ndim != 2 or table.shape[0] < 2 or table.shape[1] != 4:
            raise ValueError(f"atmosphere table must have shape (N>=2, 4), got {table.shape}")
        if not (np.all(np.isfinite(table)) and np.all(table > 0.0)):
            raise ValueError("atmosphere table must be finite and positive")
        if not (math.isfinite(spacing_m) and spacing_m > 0.0 and math.isfinite(z_min_m)):
            raise ValueError(f"bad table grid: z_min_m={z_min_m}, spacing_m={spacing_m}")
        table.setflags(write=False)
        self._conditions = conditions
        self._z_min = float(z_min_m)
        self._dz = float(spacing_m)
        self._n = int(table.shape[0])
        self._z_max = self._z_min + (self._n - 1) * self._dz
        self._table = table
        # Plain-float copies of the columns: the scalar path (one call per physics step) is
        # several times faster on Python floats than on NumPy rows and scalars.
        self._cols = tuple([float(v) for v in table[:, j]] for j in range(4))
        self._rho_list = self._cols[_RHO]

    # ----------------------------------------------------------------------------- building
    @classmethod
    def from_jsbsim(
        cls,
        conditions: AtmosphereConditions,
        z_max_m: float = 1000.0,
        z_min_m: float = -50.0,
        spacing_m: float = 5.0,
    ) -> Atmosphere:
        """Tabulate JSBSim's standard atmosphere (with ISA offset) above the field, once.

        Args:
            conditions: Field elevation above MSL (m) and ISA temperature offset (K).
            z_max_m: Highest height to tabulate, metres above the field.
            z_min_m: Lowest height to tabulate, metres above the field (may be negative).
            spacing_m: Largest allowed row spacing, metres; the grid is made uniform so that it
                ends exactly at ``z_max_m`` (the actual spacing may be slightly smaller).

        Returns:
            The tabulated atmosphere.

        Raises:
            ValueError: If the span or spacing is not sensible.
            RuntimeError: If JSBSim cannot load the probe model.
        """
        for name, value in (("z_max_m", z_max_m), ("z_min_m", z_min_m), ("spacing_m", spacing_m)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
        if not z_max_m > z_min_m:
            raise ValueError(f"z_max_m ({z_max_m}) must be above z_min_m ({z_min_m})")
        if not spacing_m > 0.0:
            raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
        n = int(math.ceil((z_max_m - z_min_m) / spacing_m - 1e-9)) + 1
        n = max(n, 2)
        dz = (z_max_m - z_min_m) / (n - 1)
        z_msl = conditions.elevation_m + z_min_m + dz * np.arange(n)

        t0 = time.perf_counter()
        table = np.empty((n, 4))
        with jsbsim_exec() as fdm:
            # Any model gives the atmosphere a position; our probe loads without the warning the
            # shipped `ball` model logs (ball.xml has a force with no direction element).
            load_probe_model(fdm)
            fdm["ic/h-sl-ft"] = float(z_msl[0]) / FT_TO_M
            fdm.run_ic()
            # Hold the state: run() then only re-evaluates the models at the position we set.
            fdm.suspend_integration()
            # Standard day: pressure and density at every height.
            fdm["atmosphere/delta-T"] = 0.0
            t_std = np.empty(n)
            for i, h_m in enumerate(z_msl):
                fdm["position/h-sl-ft"] = float(h_m) / FT_TO_M
                fdm.run()
                table[i, _P] = fdm["atmosphere/P-psf"] * PSF_TO_PA
                table[i, _RHO] = fdm["atmosphere/rho-slugs_ft3"] * SLUG_FT3_TO_KG_M3
                t_std[i] = fdm["atmosphere/T-R"] / RANKINE_PER_KELVIN
            # The scenario's day: JSBSim's uniform temperature bias gives T and a.
            fdm["atmosphere/delta-T"] = conditions.isa_offset_k * RANKINE_PER_KELVIN
            for i, h_m in enumerate(z_msl):
                fdm["position/h-sl-ft"] = float(h_m) / FT_TO_M
                fdm.run()
                table[i, _T] = fdm["atmosphere/T-R"] / RANKINE_PER_KELVIN
                table[i, _A] = fdm["atmosphere/a-fps"] * FT_TO_M
        # ISA-deviation convention: the offset changes temperature, not pressure, at a given
        # height, so by the ideal gas law at equal pressure rho = rho_std * T_std / T. (JSBSim's
        # own delta-T also re-integrates the hydrostatic equation through the warmer column,
        # raising pressure aloft: +0.8 % at 1 km for +20 K. We keep the standard-day pressure so
        # that a hot field has the textbook ISA+dT density, as density-altitude charts assume.)
        table[:, _RHO] *= t_std / table[:, _T]
        _log.debug(
            "atmosphere table: %d rows, %.3f m spacing, %.1f..%.1f m MSL, delta-T %+.1f K, built in %.1f ms",
            n, dz, z_msl[0], z_msl[-1], conditions.isa_offset_k, 1e3 * (time.perf_counter() - t0),
        )
        return cls(conditions, z_min_m, dz, table)

    # ----------------------------------------------------------------------------- properties
    @property
    def conditions(self) -> AtmosphereConditions:
        """Field elevation and ISA offset this table was built for."""
        return self._conditions

    @property
    def z_min_m(self) -> float:
        """Lowest tabulated height, metres above the field."""
        return self._z_min

    @property
    def z_max_m(self) -> float:
        """Highest tabulated height, metres above the field."""
        return self._z_max

    @property
    def spacing_m(self) -> float:
        """Row spacing of the table, metres."""
        return self._dz

    @property
    def heights_m(self) -> NDArray[np.float64]:
        """(N,) tabulated heights, metres above the field."""
        return self._z_min + self._dz * np.arange(self._n, dtype=np.float64)

    @property
    def table(self) -> NDArray[np.float64]:
        """(N, 4) read-only table: density kg/m^3, temperature K, pressure Pa, speed of sound m/s."""
        return self._table

    # ----------------------------------------------------------------------------- queries
    @overload
    def sample(self, z_m: float) -> AtmosphereSample: ...
    @overload
    def sample(self, z_m: ArrayLike) -> AtmosphereSample: ...
    def sample(self, z_m: ArrayLike) -> AtmosphereSample:
        """Atmospheric state at heights above the field.

        Args:
            z_m: Height(s) above the field, metres (ENU z); scalar or array of any shape.

        Returns:
            Floats for a scalar query, otherwise arrays shaped like ``z_m``.

        Raises:
            ValueError: If any height is not finite or lies outside the table.
        """
        if np.ndim(z_m) == 0:
            i, f = self._locate_scalar(float(z_m))  # type: ignore[arg-type]
            rho, t, p, a = (c[i] + f * (c[i + 1] - c[i]) for c in self._cols)
            return AtmosphereSample(rho, t, p, a)
        idx, frac = self._locate_array(np.asarray(z_m, dtype=np.float64))
        lo, hi = self._table[idx], self._table[idx + 1]
        rows = lo + frac[..., None] * (hi - lo)
        return AtmosphereSample(rows[..., _RHO], rows[..., _T], rows[..., _P], rows[..., _A])

    @overload
    def density_kg_m3(self, z_m: float) -> float: ...
    @overload
    def density_kg_m3(self, z_m: ArrayLike) -> NDArray[np.float64]: ...
    def density_kg_m3(self, z_m: ArrayLike) -> float | NDArray[np.float64]:
        """Air density at heights above the field.

        Args:
            z_m: Height(s) above the field, metres; scalar or array.

        Returns:
            Density in kg/m^3: a float for a scalar, else an array shaped like ``z_m``.

        Raises:
            ValueError: If any height is not finite or lies outside the table.
        """
        if np.ndim(z_m) == 0:
            i, f = self._locate_scalar(float(z_m))  # type: ignore[arg-type]
            lo = self._rho_list[i]
            return lo + f * (self._rho_list[i + 1] - lo)
        idx, frac = self._locate_array(np.asarray(z_m, dtype=np.float64))
        rho = self._table[:, _RHO]
        return rho[idx] + frac * (rho[idx + 1] - rho[idx])

    @overload
    def density_ratio(self, z_m: float) -> float: ...
    @overload
    def density_ratio(self, z_m: ArrayLike) -> NDArray[np.float64]: ...
    def density_ratio(self, z_m: ArrayLike) -> float | NDArray[np.float64]:
        """Density ratio rho / rho_0 (rho_0 = :data:`SEA_LEVEL_DENSITY_KG_M3`), the thrust scale.

        Args:
            z_m: Height(s) above the field, metres; scalar or array.

        Returns:
            Dimensionless ratio: a float for a scalar, else an array shaped like ``z_m``.

        Raises:
            ValueError: If any height is not finite or lies outside the table.
        """
        return self.density_kg_m3(z_m) / SEA_LEVEL_DENSITY_KG_M3

    def density_ratio_clamped(self, z_m: ArrayLike) -> float | NDArray[np.float64]:
        """`density_ratio` with heights outside the table held at its edge (for the physics loop).

        A vehicle that leaves the flight volume ends its episode on the runner's bounds check; the one
        control period it may spend beyond the table sees the edge density rather than an exception.
        """
        if isinstance(z_m, float):  # the physics loop's scalar: plain Python (np.clip costs ~10 µs here)
            return self.density_ratio(min(max(z_m, self._z_min), self._z_max))
        z = np.clip(z_m, self._z_min, self._z_max)
        return self.density_ratio(float(z) if np.ndim(z) == 0 else z)

    def __reduce__(self) -> tuple[Any, ...]:
        # Pickle only the defining data; __init__ rebuilds the derived float lists.
        return (type(self), (self._conditions, self._z_min, self._dz, np.array(self._table)))

    def __repr__(self) -> str:
        c = self._conditions
        return (
            f"Atmosphere(elevation_m={c.elevation_m}, isa_offset_k={c.isa_offset_k}, "
            f"z_m=[{self._z_min}, {self._z_max}], spacing_m={self._dz:.3f})"
        )

    # ----------------------------------------------------------------------------- internals
    def _locate_scalar(self, z: float) -> tuple[int, float]:
        if not self._z_min <= z <= self._z_max:  # also rejects NaN
            raise ValueError(self._range_message(z))
        s = (z - self._z_min) / self._dz
        i = min(int(s), self._n - 2)
        return i, s - i

    def _locate_array(self, z: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        bad = ~((z >= self._z_min) & (z <= self._z_max))  # NaN compares False: counted as bad
        if np.any(bad):
            raise ValueError(self._range_message(float(z[bad].flat[0])))
        s = (z - self._z_min) / self._dz
        idx = np.minimum(s.astype(np.intp), self._n - 2)
        return idx, s - idx

    def _range_message(self, z: float) -> str:
        return (
            f"height z={z!r} m above the field is outside the atmosphere table "
            f"[{self._z_min}, {self._z_max}] m; build the Atmosphere with a wider z range"
        )


# --------------------------------------------------------------------------------- JSBSim glue
class AtmosphereBank:
    """The atmospheres of N vehicles, looked up in one call (the learned pilot's batched environment).

    Vehicle i flies one atmosphere of a shared pool (tables on one height grid: same lowest height,
    spacing and rows), so a batch flies fields at many elevations and temperatures at once. Vehicle i's
    density is exactly (bit for bit) that of `atmosphere(i)`, the `Atmosphere` the comparison runner
    flies: the same interpolation on the same doubles.

    Args:
        pool: the atmospheres (at least one), all on one grid.
        n: number of vehicles (each starts with pool entry 0).

    Raises:
        ValueError: an empty pool, or tables on different grids.
    """

    def __init__(self, pool: Sequence[Atmosphere], n: int) -> None:
        self.pool = list(pool)
        if not self.pool:
            raise ValueError("an AtmosphereBank needs at least one atmosphere")
        first = self.pool[0]
        grid = (first.z_min_m, first.spacing_m, first.table.shape[0])
        if any((a.z_min_m, a.spacing_m, a.table.shape[0]) != grid for a in self.pool):
            raise ValueError("the atmospheres of an AtmosphereBank must share one height grid")
        self._z_min, self._dz, self._n = grid
        self._z_max = first.z_max_m
        self._rho = np.stack([a.table[:, _RHO] for a in self.pool])  # (K, rows)
        self.which = np.zeros(int(n), dtype=np.int64)

    def assign(self, i: int, k: int) -> None:
        """Vehicle i flies pool entry k."""
        if not 0 <= k < len(self.pool):
            raise ValueError(f"atmosphere {k} is not in a pool of {len(self.pool)}")
        self.which[i] = int(k)

    def atmosphere(self, i: int) -> Atmosphere:
        """Vehicle i's atmosphere (the same numbers), for flying its episode elsewhere."""
        return self.pool[int(self.which[i])]

    def density_ratio_clamped(self, z_m: ArrayLike, idx: ArrayLike | None = None) -> NDArray[np.float64]:
        """`Atmosphere.density_ratio_clamped` (M,) of vehicles `idx` (default all) at heights z_m (M,)
        [m above their fields], each in its own atmosphere."""
        sel = slice(None) if idx is None else np.asarray(idx, dtype=np.int64)
        k = self.which[sel]
        z = np.clip(np.asarray(z_m, dtype=np.float64).reshape(-1), self._z_min, self._z_max)
        s = (z - self._z_min) / self._dz
        i = np.minimum(s.astype(np.intp), self._n - 2)
        f = s - i
        lo = self._rho[k, i]
        return (lo + f * (self._rho[k, i + 1] - lo)) / SEA_LEVEL_DENSITY_KG_M3


class _JSBSimToLogging:
    """A JSBSim log backend that forwards records to Python ``logging``.

    JSBSim's default backend prints its banner and model summaries to stdout; library code here
    never prints. Routine chatter goes to DEBUG, JSBSim warnings and errors keep their level.
    Created lazily so that importing this module does not import jsbsim's logger classes.
    """

    _instance_cls: type | None = None

    @classmethod
    def create(cls) -> Any:
        if cls._instance_cls is None:
            import jsbsim  # deferred: see the class docstring

            levels = {
                jsbsim.LogLevel.WARN: logging.WARNING,
                jsbsim.LogLevel.ERROR: logging.ERROR,
                jsbsim.LogLevel.FATAL: logging.CRITICAL,
            }
            target = logging.getLogger("uam_fdm.jsbsim")

            class Bridge(jsbsim.FGLogger):
                def __init__(self) -> None:
                    super().__init__()
                    self._parts: list[str] = []
                    self._level = logging.DEBUG
                    self._where = ""

                def set_level(self, level: Any) -> None:
                    self._parts, self._where = [], ""
                    self._level = levels.get(level, logging.DEBUG)

                def file_location(self, filename: str, line: int) -> None:
                    self._where = f"{filename}:{line}: "

                def message(self, message: str) -> None:
                    self._parts.append(message)

                def format(self, format: Any) -> None:  # colours: not meaningful in logging
                    pass

                def flush(self) -> None:
                    text = "".join(self._parts).strip()
                    self._parts = []
                    if text and target.isEnabledFor(self._level):
                        target.log(self._level, "%s%s", self._where, text)

            cls._instance_cls = Bridge
        return cls._instance_cls()


@contextlib.contextmanager
def jsbsim_exec(root_dir: str | os.PathLike[str] | None = None) -> Iterator[Any]:
    """A fresh, quiet ``jsbsim.FGFDMExec`` whose messages go to Python logging.

    JSBSim's log backend is per thread, and it must be installed *before* FGFDMExec is created
    (the banner goes through it). This installs a backend that forwards to the
    ``uam_fdm.jsbsim`` logger for the duration of the block, then restores the previous one, so
    no process state is left changed.

    Args:
        root_dir: JSBSim root directory (holding aircraft/, engine/, systems/); defaults to the
            one shipped with the jsbsim package.

    Yields:
        The executive, with debug level 0. It is only valid inside the block.
    """
    import jsbsim  # deferred (0.1 s to import): only building a table needs it, not an unpickled Atmosphere

    previous = jsbsim.get_logger()
    jsbsim.set_logger(_JSBSimToLogging.create())
    try:
        fdm = jsbsim.FGFDMExec(str(root_dir) if root_dir is not None else jsbsim.get_default_root_dir())
        fdm.set_debug_level(0)
        yield fdm
    finally:
        jsbsim.set_logger(previous)


def load_probe_model(fdm: Any) -> None:
    """Load the ``windprobe`` point-mass aircraft shipped in ``uam_fdm/air/jsbsim`` into ``fdm``.

    The probe has no engines or systems, so JSBSim's own engine/ and systems/ folders are passed
    (they must merely exist); only the aircraft folder is ours.

    Args:
        fdm: A fresh ``jsbsim.FGFDMExec`` (see :func:`jsbsim_exec`).

    Raises:
        RuntimeError: If JSBSim reports the model could not be loaded.
    """
    root = Path(fdm.get_root_dir())
    ok = fdm.load_model_with_paths(
        PROBE_MODEL_NAME, str(_PROBE_AIRCRAFT_DIR), str(root / "engine"), str(root / "systems")
    )
    if not ok:
        raise RuntimeError(
            f"JSBSim could not load {PROBE_MODEL_NAME!r} from {_PROBE_AIRCRAFT_DIR} "
            "(see the uam_fdm.jsbsim log for JSBSim's reason)"
        )



def density_altitude_m(density_kg_m3: float) -> float:
    """The ISA (troposphere) altitude where the standard atmosphere has this density [m] (negative below sea
    level): the air's thinness as one number, e.g. for hot-and-high fields."""
    ratio = density_kg_m3 / SEA_LEVEL_DENSITY_KG_M3
    return _ISA_T0_K / _ISA_LAPSE_K_M * (1.0 - ratio ** (1.0 / _ISA_DENSITY_EXPONENT))
