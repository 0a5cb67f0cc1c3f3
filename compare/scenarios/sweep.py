"""The robustness sweep: success and collision rate against density altitude, steady wind, the share of the
buildings the prior map lacks, the GNSS sky and the lidar's range, on the same held-out tasks at every step, per
vehicle; generated, seeded and versioned like the benchmark sets.

`build_sweep("sweep")` (or "sweep-quick") generates the scenarios. Per vehicle a few cities of the learned
pilot's own distribution at seeds no pool or set uses (3,800,000.. small quad, 3,900,000.. UAM: disjoint from every
training, test and validation pool and from both benchmark families' sets and validation twins, checked), each
with its legs drawn once as the benchmark draws them (`compare.scenarios.benchmark.draw_leg`: a straight line
blocked by buildings where possible), then flown at every step of five axes, one varied at a time. The air's two,
at `perfect` sensing on an exact map:

* density altitude 0, 0.75, ..., 4.5 km (`DENSITY_ALTITUDES_M`) at the vehicle's low wind (`SweepVehicle.
  da_axis_wind_m_s`, the second wind step) in light turbulence. The rule: a standard day (ISA +0 K) at a field
  elevation equal to the density altitude; JSBSim's atmosphere then gives the step's density altitude within
  4 m at 4.5 km (`DA_TOLERANCE_M`, tested);
* steady wind (`SweepVehicle.wind_steps_m_s`: small quad 0-12 m/s, UAM 0-16 m/s, seven equal steps) at sea
  level on a standard day in light turbulence, blowing from one heading per city (drawn from the city's seed,
  the same at every step).

The two axes meet at sea level in the low wind: that point is one scenario, counted on both axes. The sensed
axes fly that air (sea level, standard day, the low wind, light turbulence) at `nominal` sensing on an exact map,
each moving one thing away from it (`SENSED_POINTS`):

* the prior map's missing share: 0, 10, 25, 50 % of the buildings left out of the pilots' map (`MISSING_FRACTIONS`;
  each step drawn from the city's seed);
* the GNSS sky: open sky (nominal), an urban canyon (the true buildings block satellites; half the blocked ones
  tracked through reflections), and that canyon with outages up to 10, 30 and 60 s (`GNSS_STEPS`). Outages come
  at 2 a minute, four times the `degraded` preset's rate, so that most legs of a minute meet one and the step
  measures the outage's length rather than the chance of one;
* the lidar's range: 20, 40, 60 and 100 % of the part's (`LIDAR_RANGE_FRACTIONS`; the small quad's VLP-16 100 m,
  the UAM's VLP-32C 200 m).

A scenario is one (city, step); its name says the step (`sweep-quad-00-da1500-w020`: city 0, density altitude
1,500 m, wind 2.0 m/s; `sweep-quad-00-sensed-m25-g0-l100`: 25 % missing, open sky, the lidar's full range), and its
episodes are the city's legs in the same order at every step, so every pilot flies the same tasks at every step
(paired across pilots and steps; the turbulence realisation is seeded per scenario, so it differs between steps as
the air does).

"sweep-quick" is the first `quick_cities` cities with their first `quick_legs` legs at every step: the same
names and tasks as in "sweep", so its cells are cells of the full set. Version: `GENERATOR_VERSION` + "+" +
a hash of everything generated (`compare.scenarios.benchmark.task_set_version`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compare.results.run_info import TaskSetInfo
from compare.scenarios.benchmark import (
    DENSITY_LEVELS,
    FAMILIES,
    LEARNED_PILOT_POOLS,
    PILOT_NAMES,
    TaskSet,
    VehicleBenchmark,
    city_params,
    city_seed_ranges,
    draw_leg,
    task_set_version,
    validation_design,
)
from compare.scenarios.scenario import scenario_from_dict
from rl.task.vehicles import task_for
from uam_fdm.city.generator import generate_city
from uam_fdm.sensing.specs import sensing_preset
from uam_fdm.vehicle.params import load_vehicle

GENERATOR_VERSION = "2"
"""Bumped by hand when the design changes on purpose; the hash in the version catches every change anyway."""
SWEEP_SETS = ("sweep", "sweep-quick")  # the generated sets' names (`compare.scenarios.sets` resolves them)
FULL, QUICK = SWEEP_SETS
DENSITY_ALTITUDES_M = (0.0, 750.0, 1500.0, 2250.0, 3000.0, 3750.0, 4500.0)
"""The density-altitude axis [m]: sea level to past the widest training envelope (about 4.1 km)."""
DA_TOLERANCE_M = 10.0
"""How close a step's field (standard day at that elevation) comes to its density altitude [m]."""
TURBULENCE = "light"  # every axis: the level the shipped policies trained in, so only the axis moves
MISSING_FRACTIONS = (0.0, 0.10, 0.25, 0.50)
"""The map axis: the share of the city's buildings absent from the pilots' prior map."""
GNSS_OUTAGE_RATE_PER_MIN = 2.0
"""Outages a minute on the GNSS axis's outage steps (the `degraded` preset: 0.5)."""
GNSS_STEPS: tuple[tuple[str, dict[str, float | bool]], ...] = (
    ("open sky", {}),
    ("urban canyon", {"urban_canyon": True, "nlos_probability": 0.5}),
    *((f"urban canyon, outages to {s:g} s", {"urban_canyon": True, "nlos_probability": 0.5,
                                             "outage_rate_per_min": GNSS_OUTAGE_RATE_PER_MIN, "max_outage_s": s})
      for s in (10.0, 30.0, 60.0)),
)
"""The GNSS axis: each step's name and its changes to the `nominal` preset's receiver (scenario key `sensing.gnss`)."""
LIDAR_RANGE_FRACTIONS = (0.2, 0.4, 0.6, 1.0)
"""The lidar axis: the range as a share of the part's (`nominal`)."""
SENSED_AXES = ("map missing", "GNSS", "lidar range")
_STREAM_HEADING = 0x5E1  # PCG64 stream tag of a city's wind heading


@dataclass(frozen=True)
class SweepVehicle:
    """One vehicle's sweep.

    Attributes:
        tasks: its cities, legs and heights (the benchmark's distribution of the vehicle, at the sweep's seeds).
        wind_steps_m_s: the wind axis [m/s], first 0.
        da_axis_wind_m_s: the steady wind of the density-altitude axis [m/s] (one of the wind steps, so the
            axes share their sea-level point).
    """

    tasks: VehicleBenchmark
    wind_steps_m_s: tuple[float, ...]
    da_axis_wind_m_s: float


@dataclass(frozen=True)
class SweepDesign:
    """What the sweep sets hold.

    Attributes:
        vehicles: one sweep per vehicle (never pooled).
        cities, legs_per_city: the full set's tasks per vehicle and step (cities x legs).
        quick_cities, quick_legs: the quick set's (the first cities, their first legs).
        seeds: the seeds every episode is flown with.
        pilots: the pilots flown.
    """

    vehicles: tuple[SweepVehicle, ...] = (
        # the benchmark's task scale per vehicle (legs, heights); wind to 12 m/s (the quad's top speed: a head
        # wind it cannot beat) and to 16 m/s for the UAM, in seven equal steps
        SweepVehicle(VehicleBenchmark("small_quad", "quad", 3_800_000,
                                      ((60.0, 120.0), (120.0, 180.0), (180.0, 240.0)), (8.0, 25.0), 0.0),
                     (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0), 2.0),
        SweepVehicle(VehicleBenchmark("uam_multicopter", "uam", 3_900_000,
                                      ((300.0, 600.0), (600.0, 900.0), (900.0, 1200.0)), (30.0, 90.0), 0.0),
                     (0.0, 2.7, 5.3, 8.0, 10.7, 13.3, 16.0), 2.7),
    )
    # 72 tasks per step and pilot: a Wilson 95 % interval at most +-11 points wide; 12 cities so that one
    # city's streets do not make a step's rate
    cities: int = 12
    legs_per_city: int = 6
    # sized so that `uam-compare run sweep-quick --jobs 2` takes minutes (2 tasks per step: it checks that
    # everything runs and shows the shape, it does not measure)
    quick_cities: int = 1
    quick_legs: int = 2
    seeds: tuple[int, ...] = (0,)
    pilots: tuple[str, ...] = PILOT_NAMES


DESIGN = SweepDesign()


@dataclass(frozen=True)
class SweepPoint:
    """One step of the sweep: density altitude [m] (a standard day at this field elevation) and steady wind
    speed [m/s]; `axes` the axes it lies on ("density altitude", "wind")."""

    density_altitude_m: float
    wind_m_s: float
    axes: tuple[str, ...]


def sweep_points(sv: SweepVehicle) -> tuple[SweepPoint, ...]:
    """The vehicle's steps: the density-altitude axis at its low wind, then the wind axis at sea level (the
    shared sea-level point once, on both axes)."""
    points = [SweepPoint(da, sv.da_axis_wind_m_s, ("density altitude",) + (("wind",) if da == 0.0 else ()))
              for da in DENSITY_ALTITUDES_M]
    points += [SweepPoint(0.0, w, ("wind",)) for w in sv.wind_steps_m_s if w != sv.da_axis_wind_m_s]
    return tuple(points)


def point_name(tag: str, city: int, p: SweepPoint) -> str:
    """The scenario name of city `city` at step `p`, e.g. "sweep-quad-00-da1500-w020"."""
    return f"sweep-{tag}-{city:02d}-da{round(p.density_altitude_m):04d}-w{round(10 * p.wind_m_s):03d}"


@dataclass(frozen=True)
class SensedPoint:
    """One step of the sensed axes (at sea level in the low wind, `nominal` sensing otherwise).

    Attributes:
        missing_fraction: the share of the buildings the prior map lacks.
        gnss: the index of its GNSS sky in `GNSS_STEPS`.
        lidar_fraction: the lidar's range as a share of the part's.
        axes: the axes it lies on (of `SENSED_AXES`).
    """

    missing_fraction: float
    gnss: int
    lidar_fraction: float
    axes: tuple[str, ...]


def sensed_points() -> tuple[SensedPoint, ...]:
    """The sensed axes' steps: their shared point (nothing missing, open sky, the full range) once, on all three,
    then each axis's other steps."""
    out = [SensedPoint(0.0, 0, 1.0, SENSED_AXES)]
    out += [SensedPoint(m, 0, 1.0, ("map missing",)) for m in MISSING_FRACTIONS if m]
    out += [SensedPoint(0.0, g, 1.0, ("GNSS",)) for g in range(1, len(GNSS_STEPS))]
    out += [SensedPoint(0.0, 0, f, ("lidar range",)) for f in LIDAR_RANGE_FRACTIONS if f != 1.0]
    return tuple(out)


def sensed_name(tag: str, city: int, p: SensedPoint) -> str:
    """The scenario name of city `city` at sensed step `p`, e.g. "sweep-quad-00-sensed-m25-g0-l100"."""
    return (f"sweep-{tag}-{city:02d}-sensed-m{round(100 * p.missing_fraction):02d}-g{p.gnss}"
            f"-l{round(100 * p.lidar_fraction):03d}")


# ---- the sets ---------------------------------------------------------------------------------------
def build_sweep(name: str, design: SweepDesign = DESIGN, vehicles: tuple[str, ...] | None = None) -> TaskSet:
    """Generate and check the sweep set `name` (one of `SWEEP_SETS`), vehicle by vehicle, city by city, step
    by step.

    Args:
        name: "sweep" or "sweep-quick".
        design: what the sets hold.
        vehicles: only these vehicles' sweeps (None: every vehicle's); the version covers what is generated.

    Raises:
        ValueError: an unknown set name or vehicle, a quick set that is not a subset, city seeds not held out,
            or a density-altitude axis wind that is not a wind step.
    """
    if name not in SWEEP_SETS:
        raise ValueError(f"unknown sweep set {name!r} (known: {', '.join(SWEEP_SETS)})")
    _check_design(design)
    known = [sv.tasks.vehicle for sv in design.vehicles]
    for v in vehicles or ():
        if v not in known:
            raise ValueError(f"--vehicle {v}: no sweep for this vehicle (known: {', '.join(known)})")
    if vehicles is not None:
        design = dataclasses.replace(design, vehicles=tuple(sv for sv in design.vehicles
                                                            if sv.tasks.vehicle in vehicles))
    n_cities, n_legs = (design.cities, design.legs_per_city) if name == FULL else (design.quick_cities,
                                                                                     design.quick_legs)
    checked = []
    for sv in design.vehicles:
        for i in range(n_cities):
            for data in city_mappings(sv, i, n_legs, design):
                checked.append(scenario_from_dict(data, f"{name}:{data['name']}", Path(".")))
    info = TaskSetInfo(name, task_set_version(checked, GENERATOR_VERSION), _describe(name, n_cities, n_legs, design))
    return TaskSet(info, tuple(dataclasses.replace(sc, task_set=info) for sc in checked))


def sweep_seed_ranges(design: SweepDesign = DESIGN) -> dict[str, range]:
    """The city seeds of the full sweep, per vehicle."""
    return {sv.tasks.vehicle: range(sv.tasks.first_seed, sv.tasks.first_seed + design.cities)
            for sv in design.vehicles}


def _check_design(design: SweepDesign) -> None:
    """Raise ValueError for a quick set that is not a subset, a city seed in a learned pilot's pool, the
    benchmark's or twice, or a density-altitude axis wind that is not one of the wind steps."""
    if not (1 <= design.quick_cities <= design.cities and 1 <= design.quick_legs <= design.legs_per_city):
        raise ValueError(f"the quick sweep ({design.quick_cities} x {design.quick_legs}) must be a non-empty subset "
                         f"of the full one ({design.cities} x {design.legs_per_city})")
    taken: dict[str, range] = dict(LEARNED_PILOT_POOLS)
    for family in FAMILIES:  # both benchmarks' sets and their validation twins
        for twin, name in ((family, family.sets[0]), (validation_design(family), family.sets[2])):
            taken.update({f"{v} {name}": r for v, r in city_seed_ranges(twin).items()})
    for vehicle, seeds in sweep_seed_ranges(design).items():
        for pool, other in taken.items():
            if seeds.start < other.stop and other.start < seeds.stop:
                raise ValueError(f"{vehicle}: sweep city seeds {seeds.start}-{seeds.stop - 1} overlap the {pool} "
                                 f"cities ({other.start}-{other.stop - 1})")
        taken[f"{vehicle} sweep"] = seeds
    for sv in design.vehicles:
        if sv.da_axis_wind_m_s not in sv.wind_steps_m_s:
            raise ValueError(f"{sv.tasks.vehicle}: the density-altitude axis wind {sv.da_axis_wind_m_s:g} m/s is "
                             f"not one of the wind steps {list(sv.wind_steps_m_s)}")


def _describe(name: str, n_cities: int, n_legs: int, design: SweepDesign) -> str:
    cities = f"{n_cities} {'city' if n_cities == 1 else 'cities'}"
    sizes = ", ".join(f"{sv.tasks.vehicle} {cities} x {n_legs} legs = {n_cities * n_legs} tasks at each of "
                      f"{len(sweep_points(sv)) + len(sensed_points())} steps (wind 0-{max(sv.wind_steps_m_s):g} m/s)"
                      for sv in design.vehicles)
    subset = f" (the first of {FULL}'s)" if name == QUICK else ""
    km = "/".join(f"{da / 1000:g}" for da in DENSITY_ALTITUDES_M)
    missing = "/".join(f"{100 * m:g}" for m in MISSING_FRACTIONS)
    lidar = "/".join(f"{100 * f:g}" for f in LIDAR_RANGE_FRACTIONS)
    return (f"Robustness sweep on held-out generated tasks{subset}: {sizes}; at perfect sensing, density altitude "
            f"{km} km (standard day at that field) in a low wind, and steady wind at sea level; at nominal sensing "
            f"at sea level in the low wind, {missing} % of the buildings missing from the map, GNSS from open sky "
            f"to an urban canyon with outages to {GNSS_STEPS[-1][1]['max_outage_s']:g} s, lidar range {lidar} % of "
            f"the part's; light turbulence; the same tasks at every step")


# ---- one city at every step ---------------------------------------------------------------------------
def city_mappings(sv: SweepVehicle, index: int, n_legs: int, design: SweepDesign = DESIGN) -> list[dict]:
    """The scenario mappings (the scenario-file schema, `compare.scenarios.scenario`) of city `index` of a vehicle, one
    per step (`sweep_points`, then `sensed_points`), all with the same legs.

    Args:
        sv: the vehicle's sweep.
        index: the city's index (its seed is the first seed + index; its building density level index mod 3,
            starting at the middle one).
        n_legs: how many legs (the first n of the city's sequence).
        design: the sets' design (seeds, pilots).

    Raises:
        RuntimeError: a leg with no free start and goal (`compare.scenarios.benchmark.draw_leg`).
    """
    vb, nav, vehicle = sv.tasks, task_for(sv.tasks.vehicle), load_vehicle(sv.tasks.vehicle)
    seed = vb.first_seed + index
    density = (1 + index) % len(DENSITY_LEVELS)
    params = city_params(nav.cities, seed, density)
    city = generate_city(params, seed, name=f"gen-{seed}")
    heading = float(np.random.Generator(np.random.PCG64([seed, _STREAM_HEADING])).uniform(-math.pi, math.pi))
    legs = [draw_leg(city, nav.tasks, vb, vehicle.collision_radius_m, seed, j) for j in range(n_legs)]
    episodes = [{"start": a, "goal": b,
                 "timeout_s": round(nav.tasks.timeout_s(math.dist(a, b), b[2] - a[2], vehicle.controller.max_speed_m_s,
                                                        vehicle.controller.max_vertical_speed_m_s), 1)}
                for a, b in legs]
    fields = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(params).items()}
    where = f"{vb.vehicle} in held-out city {seed} ({DENSITY_LEVELS[density]} buildings)"

    def scenario(name: str, description: str, elevation_m: float, wind_m_s: float, **sensed: object) -> dict:
        wind = [round(wind_m_s * math.cos(heading), 2), round(wind_m_s * math.sin(heading), 2), 0.0]
        return {"name": name, "description": description,
                "map": {"generator": {"seed": seed, "name": city.name, **fields}},
                "vehicle": vb.vehicle,
                "atmosphere": {"elevation_m": elevation_m, "isa_offset_k": 0.0, "wind_mps": wind,
                               "turbulence": TURBULENCE},
                "goal_radius_m": nav.tasks.goal_radius_m,
                "episodes": episodes,
                "seeds": list(design.seeds),
                "pilots": list(design.pilots),
                **sensed}

    out = [scenario(point_name(vb.tag, index, p),
                    f"{where}: density altitude {p.density_altitude_m:g} m (standard day at a {p.density_altitude_m:g} "
                    f"m field), steady wind {p.wind_m_s:g} m/s towards {math.degrees(heading):.0f} deg from east, "
                    f"{TURBULENCE} turbulence, perfect sensing; sweep axes: {', '.join(p.axes)}",
                    p.density_altitude_m, p.wind_m_s)
           for p in sweep_points(sv)]
    part_range = sensing_preset("nominal", vehicle.mass_kg).lidar.max_range_m
    for p in sensed_points():
        gnss_name, gnss = GNSS_STEPS[p.gnss]
        lidar_m = round(p.lidar_fraction * part_range, 1)
        changes = {**({"gnss": gnss} if gnss else {}),
                   **({"lidar": {"max_range_m": lidar_m}} if p.lidar_fraction != 1.0 else {})}
        out.append(scenario(
            sensed_name(vb.tag, index, p),
            f"{where}: sea level (standard day), steady wind {sv.da_axis_wind_m_s:g} m/s towards "
            f"{math.degrees(heading):.0f} deg from east, {TURBULENCE} turbulence, nominal sensing with GNSS "
            f"{gnss_name} and lidar range {lidar_m:g} m, {100 * p.missing_fraction:g} % of the buildings missing from "
            f"the map; sweep axes: {', '.join(p.axes)}",
            0.0, sv.da_axis_wind_m_s,
            sensing={"preset": "nominal", **changes} if changes else "nominal",
            map_error={"preset": "exact", "missing_fraction": p.missing_fraction, "seed": seed}
            if p.missing_fraction else "exact"))
    return out
