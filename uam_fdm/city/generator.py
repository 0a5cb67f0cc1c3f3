"""Seeded procedural cities: a street grid of blocks, lots and box buildings; the shipped maps.

A city is a rectangle [0, W] x [0, D] (ENU metres) cut by a street grid (optionally rotated about
the city centre).  Each block is split into lots (or, with `merge_prob`, kept whole); each lot
holds a building with probability `density`.  Heights are log-normal about `height_median_m`,
raised towards a downtown core by a Gaussian factor, and clipped to `height_range_m`.

Determinism: one `numpy.random.Generator(PCG64(seed))` per city, drawn in a fixed order (seven
numbers per lot whether or not it is built, so a change of density does not reshuffle the rest).
Outputs are rounded (positions and sizes to 1 cm, heights to 10 cm, yaw to 0.01 deg), so the same
seed gives the same city bit for bit on any machine.

Regenerate the shipped maps with `python -m uam_fdm.city.generator --write-shipped`.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.errors import ConfigError
from uam_fdm.files.atomic import write_text_atomic
from uam_fdm.files.strict import is_finite_number, mapping, number_list

MAPS_DIR = Path(__file__).parent / "maps"
REGENERATE_COMMAND = "python -m uam_fdm.city.generator --write-shipped"
# Generation costs ~40 us per lot, and every later step (clearance, planning, plots) grows with the
# buildings: these keep a generated city to ~1 s. The shipped maps are <= 1 km with < 800 lots.
MAX_CITY_EXTENT_M = 5000.0   # per axis
MAX_LOTS_PER_BLOCK = 10      # per axis
MAX_CITY_LOTS = 20_000       # lots the street grid holds over the whole city (built or not)
MIN_BUILDING_SIZE_M = 1.0    # smallest footprint side: lot size x fill_range low (positions round to 1 cm)


def _check_params(p: Any, source: str, prefix: str) -> None:
    """Value checks shared by the dataclass and the loader (ConfigError names the field)."""
    get: Callable[[str], Any] = p.get if isinstance(p, Mapping) else (lambda k: getattr(p, k))

    def fail(k: str, reason: str) -> None:
        raise ConfigError(source, f"{prefix}{k}", f"{reason}, got {get(k)!r}")

    for k in ("extent_m", "block_size_m"):
        if len(get(k)) != 2 or min(get(k)) <= 0:
            fail(k, "must be two positive numbers")
    if max(get("extent_m")) > MAX_CITY_EXTENT_M:
        fail("extent_m", f"must be at most {MAX_CITY_EXTENT_M:g} m per axis")
    if not get("street_width_m") > 0:
        fail("street_width_m", "must be positive")
    if not 0 <= get("margin_m") < 0.5 * min(get("extent_m")):
        fail("margin_m", "must be >= 0 and leave room for buildings")
    if not get("ceiling_m") > 0:
        fail("ceiling_m", "must be positive")
    lots = get("lots_per_block")
    if len(lots) != 2 or any(isinstance(v, bool) or int(v) != v or v < 1 for v in lots):
        fail("lots_per_block", "must be two integers >= 1")
    if max(lots) > MAX_LOTS_PER_BLOCK:
        fail("lots_per_block", f"must be at most {MAX_LOTS_PER_BLOCK} per axis")
    for k in ("density", "merge_prob"):
        if not 0.0 <= get(k) <= 1.0:
            fail(k, "must be in [0, 1]")
    f0, f1 = get("fill_range")
    if not 0.0 < f0 <= f1 <= 0.95:
        fail("fill_range", "must satisfy 0 < low <= high <= 0.95 (a gap between neighbours)")
    if not get("height_median_m") > 0 or not get("height_sigma") >= 0:
        fail("height_median_m" if not get("height_median_m") > 0 else "height_sigma",
             "median must be positive and sigma >= 0")
    h0, h1 = get("height_range_m")
    if not 0.0 < h0 <= h1:
        fail("height_range_m", "must satisfy 0 < low <= high")
    if not get("core_radius_m") >= 0 or not get("core_height_factor") > 0:
        fail("core_radius_m" if not get("core_radius_m") >= 0 else "core_height_factor",
             "core radius must be >= 0 and height factor positive")
    if not get("yaw_jitter_deg") >= 0:
        fail("yaw_jitter_deg", "must be >= 0")
    smallest = min(b / n for b, n in zip(get("block_size_m"), lots)) * f0
    if smallest < MIN_BUILDING_SIZE_M:
        fail("block_size_m", f"with lots_per_block {list(lots)} and fill_range low {f0:g} gives buildings "
                             f"{smallest:.3g} m wide; at least {MIN_BUILDING_SIZE_M:g} m")
    n_blocks = _grid_blocks(get("extent_m"), get("block_size_m"), get("street_width_m"))
    n_lots = n_blocks[0] * n_blocks[1] * int(lots[0]) * int(lots[1])
    if n_lots > MAX_CITY_LOTS:
        fail("extent_m", f"with block_size_m {list(get('block_size_m'))}, street_width_m {get('street_width_m'):g} "
                         f"and lots_per_block {list(lots)} makes a street grid of {n_lots:,} lots; at most "
                         f"{MAX_CITY_LOTS:,} (a smaller extent_m, larger blocks or fewer lots)")


def _grid_blocks(extent_m: Sequence[float], block_size_m: Sequence[float], street_width_m: float) -> list[int]:
    """Blocks of the street grid along its x and y: enough to cover the city at any grid rotation."""
    half_diag = 0.5 * math.hypot(extent_m[0], extent_m[1])
    return [math.ceil(2.0 * half_diag / (block_size_m[i] + street_width_m)) + 1 for i in range(2)]


@dataclass(frozen=True)
class CityGenConfig:
    """Parameters of a generated city (lengths in metres, angles in degrees).

    Attributes:
        extent_m: city size (x east, y north); the bounds are [0, W] x [0, D] x [0, ceiling].
            At most MAX_CITY_EXTENT_M per axis, and the street grid at most MAX_CITY_LOTS lots.
        margin_m: building-free border inside the bounds.
        ceiling_m: top of the flight volume.
        block_size_m: block footprint between streets (along the grid's x and y).
        street_width_m: street width between blocks.
        lots_per_block: lots per block along the grid's x and y, each 1..MAX_LOTS_PER_BLOCK.
        density: probability that a lot holds a building, in [0, 1].
        fill_range: building footprint as a fraction of its lot, per axis, drawn uniformly in range.
        height_median_m: median building height outside the core.
        height_sigma: log-normal spread (standard deviation of ln height).
        height_range_m: heights are clipped to this range.
        core_center_frac: downtown core centre as a fraction of the extent.
        core_radius_m: e-folding radius of the core's height boost (0 = no core).
        core_height_factor: median height multiplier at the core centre.
        merge_prob: probability that a block is one building instead of lots (podiums, towers).
        grid_yaw_deg: street-grid rotation about the city centre, counter-clockwise.
        yaw_jitter_deg: per-building yaw noise, uniform in +-this.
    """

    extent_m: tuple[float, float] = (1000.0, 1000.0)
    margin_m: float = 50.0
    ceiling_m: float = 300.0
    block_size_m: tuple[float, float] = (100.0, 80.0)
    street_width_m: float = 20.0
    lots_per_block: tuple[int, int] = (2, 2)
    density: float = 0.8
    fill_range: tuple[float, float] = (0.55, 0.85)
    height_median_m: float = 25.0
    height_sigma: float = 0.4
    height_range_m: tuple[float, float] = (10.0, 250.0)
    core_center_frac: tuple[float, float] = (0.5, 0.5)
    core_radius_m: float = 0.0
    core_height_factor: float = 1.0
    merge_prob: float = 0.0
    grid_yaw_deg: float = 0.0
    yaw_jitter_deg: float = 0.0

    def __post_init__(self) -> None:
        _check_params(self, "<CityGenConfig>", "")


# The shipped maps: generator parameters and seed.  Each stays <= 1.2 km square and <= 300 buildings.
SHIPPED_MAPS: dict[str, tuple[CityGenConfig, int]] = {
    "suburb": (CityGenConfig(
        extent_m=(800.0, 800.0), margin_m=40.0, ceiling_m=150.0, block_size_m=(120.0, 80.0),
        street_width_m=18.0, lots_per_block=(3, 2), density=0.7, fill_range=(0.4, 0.6),
        height_median_m=12.0, height_sigma=0.25, height_range_m=(10.0, 30.0), grid_yaw_deg=12.0,
        yaw_jitter_deg=4.0), 101),
    "downtown": (CityGenConfig(
        extent_m=(1000.0, 1000.0), margin_m=50.0, ceiling_m=300.0, block_size_m=(90.0, 90.0),
        street_width_m=24.0, lots_per_block=(2, 2), density=0.85, fill_range=(0.6, 0.85),
        height_median_m=30.0, height_sigma=0.35, height_range_m=(10.0, 250.0), core_radius_m=250.0,
        core_height_factor=4.0, merge_prob=0.15), 202),
    "canyon": (CityGenConfig(
        extent_m=(700.0, 700.0), margin_m=35.0, ceiling_m=300.0, block_size_m=(40.0, 150.0),
        street_width_m=16.0, lots_per_block=(1, 4), density=0.95, fill_range=(0.85, 0.95),
        height_median_m=110.0, height_sigma=0.3, height_range_m=(50.0, 250.0), core_radius_m=300.0,
        core_height_factor=1.5), 303),
}


def generate_city(params: CityGenConfig, seed: int, name: str = "") -> BuildingMap:
    """Generate a city of box buildings.

    Args:
        params: generator parameters.
        seed: seed of the city's own random generator (the only source of randomness).
        name: label of the resulting map.

    Returns:
        A BuildingMap with bounds [0, W] x [0, D] x [0, ceiling] and buildings numbered 0.. in
        generation order (blocks row by row from the south-west, lots likewise).
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    p = params
    width, depth = p.extent_m
    centre = np.array([0.5 * width, 0.5 * depth])
    yaw = math.radians(p.grid_yaw_deg)
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    pitch = np.array(p.block_size_m) + p.street_width_m
    # A grid large enough to cover the city at any rotation; blocks outside are dropped below.
    n_blocks = _grid_blocks(p.extent_m, p.block_size_m, p.street_width_m)
    core = np.array(p.core_center_frac) * np.array(p.extent_m)
    lo, hi = p.margin_m, np.array([width, depth]) - p.margin_m
    buildings: list[Building] = []
    for by in range(n_blocks[1]):
        for bx in range(n_blocks[0]):
            block_uv = (np.array([bx, by]) - 0.5 * (np.array(n_blocks) - 1)) * pitch
            lots = (1, 1) if rng.random() < p.merge_prob else p.lots_per_block
            lot_size = np.array(p.block_size_m) / np.array(lots)
            for ly in range(lots[1]):
                for lx in range(lots[0]):
                    u = rng.random(6)
                    z = rng.standard_normal()
                    lot_uv = block_uv - 0.5 * np.array(p.block_size_m) + (np.array([lx, ly]) + 0.5) * lot_size
                    size = lot_size * (p.fill_range[0] + u[1:3] * (p.fill_range[1] - p.fill_range[0]))
                    offset = (2.0 * u[3:5] - 1.0) * 0.4 * (lot_size - size)  # keep a gap to the neighbours
                    xy = centre + rot @ (lot_uv + offset)
                    factor = 1.0
                    if p.core_radius_m > 0.0:
                        r2 = float(np.sum((centre + rot @ lot_uv - core) ** 2))
                        factor += (p.core_height_factor - 1.0) * math.exp(-r2 / p.core_radius_m ** 2)
                    height = p.height_median_m * factor * math.exp(p.height_sigma * z)
                    height = min(max(height, p.height_range_m[0]), p.height_range_m[1])
                    yaw_deg = p.grid_yaw_deg + (2.0 * u[5] - 1.0) * p.yaw_jitter_deg
                    if u[0] >= p.density:
                        continue
                    b = Building(len(buildings), (round(float(xy[0]), 2), round(float(xy[1]), 2)),
                                 (round(float(size[0]), 2), round(float(size[1]), 2)), round(height, 1),
                                 math.radians(round(yaw_deg, 2)))
                    fp = b.footprint_xy_m()
                    if np.all(fp >= lo) and np.all(fp <= hi):
                        buildings.append(b)
    return BuildingMap(buildings, (0.0, 0.0, 0.0), (width, depth, p.ceiling_m), name=name)


def params_from_config(cfg: Any, source: str, key: str) -> tuple[CityGenConfig, int]:
    """Strictly parse a `generator` mapping: `{seed: N, preset: name?, name: label?, <CityGenConfig fields>...}`.

    Fields not given come from the preset (a shipped map's parameters) or the defaults. `name` labels
    the generated map (default: "gen-<preset>-<seed>", else "gen-<seed>"); `generated_map_name` reads it.

    Args:
        cfg: the mapping from YAML.
        source: file name for error messages.
        key: key path of the mapping for error messages (e.g. "map.generator").

    Returns:
        (params, seed).

    Raises:
        ConfigError: on unknown keys, wrong types or impossible values.
    """
    fields = {f.name: f for f in dataclasses.fields(CityGenConfig)}
    mapping(cfg, source, key, set(fields) | {"seed", "preset", "name"})
    if "name" in cfg and (not isinstance(cfg["name"], str) or not cfg["name"]):
        raise ConfigError(source, f"{key}.name", f"must be a non-empty string, got {cfg['name']!r}")
    if "seed" not in cfg:
        raise ConfigError(source, f"{key}.seed", "missing: a generated city needs an explicit seed")
    seed = cfg["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(source, f"{key}.seed", f"must be a non-negative integer, got {seed!r}")
    base = CityGenConfig()
    if "preset" in cfg:
        if cfg["preset"] not in SHIPPED_MAPS:
            raise ConfigError(source, f"{key}.preset",
                              f"unknown preset {cfg['preset']!r} (known: {', '.join(sorted(SHIPPED_MAPS))})")
        base = SHIPPED_MAPS[cfg["preset"]][0]
    values: dict[str, Any] = {}
    for name, value in cfg.items():
        if name in ("seed", "preset", "name"):
            continue
        default = getattr(base, name)
        k = f"{key}.{name}"
        if isinstance(default, tuple):
            items = number_list(value, len(default), source, k)
            values[name] = tuple(_scalar(v, type(d), source, k, value) for v, d in zip(items, default))
        else:
            values[name] = _scalar(value, type(default), source, k, value)
    merged = {f: getattr(base, f) for f in fields}
    merged.update(values)
    _check_params(merged, source, f"{key}.")
    return CityGenConfig(**merged), seed


def generated_map_name(cfg: Mapping[str, Any]) -> str:
    """The label of the map a checked `generator` mapping makes: its `name`, else the generator and seed it comes
    from, "gen-<preset>-<seed>" ("gen-suburb-42") or "gen-<seed>" without a preset. Never a shipped map's name
    alone: a city generated with the suburb's parameters at another seed is another city than the shipped
    "suburb" (run folders, reports and the viewer label episodes by this name)."""
    if "name" in cfg:
        return str(cfg["name"])
    return f"gen-{cfg['preset']}-{cfg['seed']}" if "preset" in cfg else f"gen-{cfg['seed']}"


def _scalar(v: Any, kind: type, source: str, key: str, shown: Any) -> Any:
    """v as `kind` (a field's type: int or float); the error shows `shown`, the whole value of the key."""
    if kind is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(source, key, f"must be integers, got {shown!r}")
        return v
    if not is_finite_number(v):
        raise ConfigError(source, key, f"must be finite numbers, got {shown!r}")
    return float(v)


# ---- shipped maps ----------------------------------------------------------------------------------
def _fmt(x: float) -> str:
    return f"{x:.2f}"  # every generated value is a multiple of 0.01, so this round-trips exactly


def map_yaml_text(bmap: BuildingMap, header: Sequence[str] = ()) -> str:
    """A map as YAML in the scenario `map`/`bounds` format (explicit box buildings, values to 1 cm).

    Args:
        bmap: a map of Building boxes (convex Prism parts have no `buildings` form).
        header: comment lines written at the top.

    Returns:
        The YAML text: `name`, `bounds: {min, max}` and `map: {buildings: [...]}`.
    """
    lines = [f"# {h}".rstrip() for h in header]
    lo, hi = bmap.bounds_min_m, bmap.bounds_max_m
    lines.append(f"name: {bmap.name}")
    lines.append(f"bounds: {{min: [{', '.join(_fmt(v) for v in lo)}], max: [{', '.join(_fmt(v) for v in hi)}]}}")
    lines.append("map:")
    lines.append("  buildings:")
    for i, b in enumerate(bmap.buildings):
        if not isinstance(b, Building):
            raise TypeError("only box buildings can be written as an explicit building list")
        # the id where it is not the index (it identifies a building across a city and its prior map), the base
        # where the box is raised (a crane's jib): a map without either is written as it always was
        extra = (f", base: {_fmt(b.base_m)}" if b.base_m > 0.0 else "") + (f", id: {b.id}" if b.id != i else "")
        lines.append(f"  - {{center: [{_fmt(b.center_xy_m[0])}, {_fmt(b.center_xy_m[1])}], "
                     f"size: [{_fmt(b.size_xy_m[0])}, {_fmt(b.size_xy_m[1])}], height: {_fmt(b.height_m)}, "
                     f"yaw_deg: {_fmt(math.degrees(b.yaw_rad))}{extra}}}")
    return "\n".join(lines) + "\n"


def shipped_map_text(name: str) -> str:
    """The exact text of a shipped map file, regenerated from its parameters and seed."""
    params, seed = SHIPPED_MAPS[name]
    fields = {f.name: getattr(params, f.name) for f in dataclasses.fields(CityGenConfig)}
    bmap = generate_city(params, seed, name=name)
    header = [
        f'Shipped map "{name}": {len(bmap.buildings)} buildings, generated by the project\'s own city generator.',
        "Do not edit by hand. Regenerate with:",
        f"  {REGENERATE_COMMAND}",
        f"i.e. uam_fdm.city.generator.generate_city(CityGenConfig(**params), seed={seed}) with params:",
        *(f"  {k}: {v}" for k, v in fields.items()),
    ]
    return map_yaml_text(bmap, header)


def write_shipped_maps(out_dir: Path = MAPS_DIR) -> list[Path]:
    """Rewrite the shipped map files deterministically (atomic: temp file then os.replace).

    Args:
        out_dir: folder for `<name>.yaml` (the package's maps folder by default).

    Returns:
        The written paths, in name order.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name in sorted(SHIPPED_MAPS):
        path = out_dir / f"{name}.yaml"
        write_text_atomic(path, shipped_map_text(name))
        written.append(path)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: `python -m uam_fdm.city.generator --write-shipped [--out DIR]` or `--check`."""
    ap = argparse.ArgumentParser(prog="python -m uam_fdm.city.generator", description=__doc__.splitlines()[0])
    ap.add_argument("--write-shipped", action="store_true", help="rewrite the shipped maps")
    ap.add_argument("--check", action="store_true", help="exit 1 if a shipped map differs from its regeneration")
    ap.add_argument("--out", type=Path, default=MAPS_DIR, help="folder for --write-shipped (default: the package's)")
    args = ap.parse_args(argv)
    if args.write_shipped:
        for path in write_shipped_maps(args.out):
            print(f"wrote {path}")
        return 0
    if args.check:
        stale = [n for n in sorted(SHIPPED_MAPS)
                 if not (MAPS_DIR / f"{n}.yaml").exists()
                 or (MAPS_DIR / f"{n}.yaml").read_text(encoding="utf-8") != shipped_map_text(n)]
        for n in stale:
            print(f"stale: {MAPS_DIR / (n + '.yaml')} (run {REGENERATE_COMMAND})")
        return 1 if stale else 0
    ap.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
