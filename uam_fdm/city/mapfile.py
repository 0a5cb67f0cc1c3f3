"""Strict parsing of map configurations (scenario `map` + `bounds` entries, shipped map files).

Formats (lengths in metres, ENU; yaw in degrees, counter-clockwise about +z):

    bounds: {min: [x, y, z], max: [x, y, z]}      # the flight volume; min z >= 0 (ground at z = 0)
    map: {buildings: [{center: [x, y], size: [w, d], height: h, yaw_deg: a}, ...]}
    map: {generator: {seed: N, preset: downtown, name: label, <CityGenConfig fields>...}}   # bounds optional
    map: {geojson: footprints.geojson, height_key: height, origin_lonlat: [lon, lat]}
    map: {named: downtown}                                                    # bounds optional
    # any of them may add  no_fly: [{center: [x, y], size: [w, d], z_range: [z0, z1], yaw_deg: a}]

Every problem raises `ConfigError(file, key, reason)`, e.g.
`maps/x.yaml: map.buildings[3].size: must be two positive numbers, got [0, 5]`.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from uam_fdm.city import generator as citygen
from uam_fdm.city import geojson
from uam_fdm.city.buildings import Building, BuildingMap, NoFlyZone
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import (
    is_finite_number,
    mapping,
    numbers,
    reject_unknown,
    require_keys,
    root_mapping,
)
from uam_fdm.files.yamlfile import load_yaml_file

MAPS_DIR = citygen.MAPS_DIR  # one folder of shipped maps: the generator writes it
_SOURCES = ("buildings", "generator", "geojson", "named")
_GEOJSON_OPTIONS = ("height_key", "origin_lonlat")
_MAP_KEYS = set(_SOURCES) | set(_GEOJSON_OPTIONS) | {"no_fly"}
_BUILDING_KEYS = {"center", "size", "height", "yaw_deg", "base", "id"}
MAX_BUILDING_ID = 10**9
_NO_FLY_KEYS = {"center", "size", "z_range", "yaw_deg"}


def map_from_config(map_cfg: Any, bounds_cfg: Any, source: str, base_dir: Path) -> BuildingMap:
    """Build a BuildingMap from a scenario's `map` and `bounds` entries.

    Args:
        map_cfg: the `map` mapping (exactly one of buildings / generator / geojson / named, plus
            optional no_fly; geojson also takes height_key and origin_lonlat).
        bounds_cfg: the `bounds` mapping `{min: [x, y, z], max: [x, y, z]}` (ENU metres), or None.
            Required for buildings and geojson; for generator it defaults to the generated extent
            and ceiling, for named to the shipped map's bounds.
        source: the file name used in error messages.
        base_dir: folder against which a relative GeoJSON path is resolved.

    Returns:
        The map.  Building ids: list index (buildings), generation order (generator), feature
        index (geojson).

    Raises:
        ConfigError: naming the file, the key and the reason.
    """
    mapping(map_cfg, source, "map", _MAP_KEYS)
    kinds = [k for k in _SOURCES if k in map_cfg]
    if len(kinds) != 1:
        raise ConfigError(source, "map", f"needs exactly one of {', '.join(_SOURCES)}; got {kinds or 'none'}")
    kind = kinds[0]
    if kind != "geojson":
        for opt in _GEOJSON_OPTIONS:
            if opt in map_cfg:
                raise ConfigError(source, f"map.{opt}", "only applies to map.geojson")
    bounds = parse_bounds(bounds_cfg, source) if bounds_cfg is not None else None
    no_fly = _no_fly(map_cfg.get("no_fly", []), source)

    if kind == "generator":
        params, seed = citygen.params_from_config(map_cfg["generator"], source, "map.generator")
        generated = citygen.generate_city(params, seed, name=citygen.generated_map_name(map_cfg["generator"]))
        return _rebound(generated, bounds, no_fly, source)
    if kind == "named":
        return _rebound(load_named_map(map_cfg["named"], source=source), bounds, no_fly, source)
    # map.buildings and map.geojson: footprints in a volume the bounds give
    if bounds is None:
        raise ConfigError(source, "bounds", f"missing: required with map.{kind} ({{min: [x, y, z], max: [x, y, z]}})")
    if kind == "buildings":
        items = map_cfg["buildings"]
        if not isinstance(items, list):
            raise ConfigError(source, "map.buildings", f"must be a list of buildings, got {items!r}")
        parts = [_building(item, i, source, bounds) for i, item in enumerate(items)]
        return BuildingMap(parts, bounds[0], bounds[1], no_fly)
    if kind == "geojson":
        path_value = map_cfg["geojson"]
        if not isinstance(path_value, str) or not path_value:
            raise ConfigError(source, "map.geojson", f"must be a file path, got {path_value!r}")
        path = Path(path_value)
        path = path if path.is_absolute() else Path(base_dir) / path
        if not path.is_file():
            raise ConfigError(source, "map.geojson", f"file not found: {path}")
        height_key = map_cfg.get("height_key", "height")
        if not isinstance(height_key, str) or not height_key:
            raise ConfigError(source, "map.height_key", f"must be a property name, got {height_key!r}")
        origin = None
        if "origin_lonlat" in map_cfg:
            origin = numbers(map_cfg["origin_lonlat"], 2, source, "map.origin_lonlat")
            if not (-180.0 <= origin[0] <= 180.0 and -85.0 <= origin[1] <= 85.0):
                raise ConfigError(source, "map.origin_lonlat", f"must be [lon, lat] in degrees, got {origin}")
        footprints = geojson.load_footprints(path, height_key, origin, bounds[0][:2], bounds[1][:2])
        return BuildingMap(footprints, bounds[0], bounds[1], no_fly, name=path.stem)
    raise AssertionError(f"unhandled map kind {kind!r}")  # _SOURCES lists the kinds handled above


MAX_EXTENT_M = 20_000.0
"""Largest flight volume per horizontal axis [m]."""
MAX_COORDINATE_M = 1_000_000.0
"""Largest |x| or |y| of a flight volume [m] (local ENU metres from the map's origin)."""
MAX_CEILING_M = 5_000.0
"""Highest ceiling of a flight volume above the ground [m]: the atmosphere and turbulence are tabulated up to it."""


def parse_bounds(cfg: Any, source: str) -> tuple[list[float], list[float]]:
    """Parse `bounds: {min: [x, y, z], max: [x, y, z]}` (ENU metres): returns (min, max)."""
    mapping(cfg, source, "bounds", {"min", "max"}, ("min", "max"),
            expected="a mapping {min: [x, y, z], max: [x, y, z]}")
    lo = numbers(cfg["min"], 3, source, "bounds.min")
    hi = numbers(cfg["max"], 3, source, "bounds.max")
    if lo[2] < 0.0:
        raise ConfigError(source, "bounds.min", f"z must be >= 0 (the ground is z = 0), got {cfg['min']!r}")
    if not all(h > lo_ for lo_, h in zip(lo, hi)):
        raise ConfigError(source, "bounds.max", f"must exceed bounds.min in x, y and z, got {cfg['max']!r} "
                                                f"vs {cfg['min']!r}")
    # before anything is sized by the volume (the atmosphere and wind tables up to the ceiling, the route grids
    # over the ground): a typo of a few zeros must be an error here, not minutes of tabulating or a MemoryError
    for axis, name in enumerate("xy"):
        if max(abs(lo[axis]), abs(hi[axis])) > MAX_COORDINATE_M:
            raise ConfigError(source, "bounds", f"{name} beyond +-{MAX_COORDINATE_M:g} m, got {cfg['min']!r} to "
                                                f"{cfg['max']!r} (local metres, not longitude and latitude)")
        if hi[axis] - lo[axis] > MAX_EXTENT_M:
            raise ConfigError(source, "bounds", f"{hi[axis] - lo[axis]:g} m wide in {name}; at most "
                                                f"{MAX_EXTENT_M:g} m (a city, not a country)")
    if hi[2] > MAX_CEILING_M:
        raise ConfigError(source, "bounds.max", f"ceiling z {hi[2]:g} m above the ground; at most {MAX_CEILING_M:g} m "
                                                f"(urban air mobility flies low)")
    return lo, hi


def load_map_file(path: Path, source: str | None = None) -> BuildingMap:
    """Load a map file in the shipped format: `name`, `bounds` and `map` keys.

    Args:
        path: the YAML file.
        source: name used in error messages (default: the path).
    """
    src = source or str(path)
    doc = load_yaml_file(path, src)
    root_mapping(doc, src, "map-file keys (name, bounds, map)")
    reject_unknown(doc, {"name", "bounds", "map"}, src)
    require_keys(doc, ("name", "bounds", "map"), src)
    bmap = map_from_config(doc["map"], doc["bounds"], src, Path(path).parent)
    return BuildingMap(bmap.buildings, bmap.bounds_min_m, bmap.bounds_max_m, bmap.no_fly, name=str(doc["name"]))


def named_maps() -> list[str]:
    """Names of the shipped maps (uam_fdm/city/maps/*.yaml), sorted."""
    return sorted(p.stem for p in MAPS_DIR.glob("*.yaml"))


def load_named_map(name: str, source: str = "map.named") -> BuildingMap:
    """Load a shipped map by name.

    Args:
        name: one of `named_maps()`.
        source: the referring file, for the error message when the name is unknown.
    """
    if not isinstance(name, str) or name not in named_maps():
        raise ConfigError(source, "map.named", f"unknown map {name!r} (shipped: {', '.join(named_maps())})")
    return load_map_file(MAPS_DIR / f"{name}.yaml", source=f"uam_fdm/city/maps/{name}.yaml")


# ---- helpers -----------------------------------------------------------------------------------------
def _rebound(bmap: BuildingMap, bounds: tuple[list[float], list[float]] | None, no_fly: list[NoFlyZone],
             source: str) -> BuildingMap:
    """The same buildings with the scenario's bounds (when given) and no-fly zones."""
    lo, hi = (bmap.bounds_min_m, bmap.bounds_max_m) if bounds is None else bounds
    if bounds is not None:
        for b in bmap.buildings:
            fp = b.footprint_xy_m()
            if fp[:, 0].min() < lo[0] or fp[:, 1].min() < lo[1] or fp[:, 0].max() > hi[0] or fp[:, 1].max() > hi[1]:
                raise ConfigError(source, "bounds", f"building {b.id} of the map lies outside these bounds")
    return BuildingMap(bmap.buildings, lo, hi, tuple(bmap.no_fly) + tuple(no_fly), name=bmap.name)


def _size(v: Any, source: str, key: str) -> list[float]:
    return numbers(v, 2, source, key, what="two positive numbers", all_positive=True)


def _yaw_deg(item: Mapping, source: str, key: str) -> float:
    yaw = item.get("yaw_deg", 0.0)
    if not is_finite_number(yaw):
        raise ConfigError(source, f"{key}.yaw_deg", f"must be a finite number of degrees, got {yaw!r}")
    return float(yaw)


def _building(item: Any, i: int, source: str, bounds: tuple[list[float], list[float]]) -> Building:
    """`map.buildings[i]`: its id is `id` when given (a run folder's map keeps the city's ids, so a prior map's
    buildings can be matched to the truth's; a crane's mast and jib share one), else its index."""
    key = f"map.buildings[{i}]"
    building_id = i
    if isinstance(item, Mapping) and "id" in item:
        value = item["id"]
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_BUILDING_ID:
            raise ConfigError(source, f"{key}.id", f"must be an integer in [0, {MAX_BUILDING_ID}], got {value!r}")
        building_id = value
        item = {k: v for k, v in item.items() if k != "id"}
    return building_from_config(item, key, building_id, source, bounds)


def building_from_config(item: Any, key: str, building_id: int, source: str,
                         bounds: tuple[list[float], list[float]]) -> Building:
    """One box building in the `map.buildings` format (`{center, size, height, yaw_deg, base}`: `base` [m] raises
    the box off the ground, e.g. a crane's jib), its footprint inside the (min, max) bounds [m]; errors name `key`
    (e.g. `unmapped[3]`). Its id is `building_id` (an `id` key is the caller's to read: here it is refused)."""
    item = mapping(item, source, key, _BUILDING_KEYS - {"id"}, ("center", "size", "height"))
    center = numbers(item["center"], 2, source, f"{key}.center")
    size = _size(item["size"], source, f"{key}.size")
    height = item["height"]
    if not (is_finite_number(height) and height > 0):
        raise ConfigError(source, f"{key}.height", f"must be a positive number of metres, got {height!r}")
    base = item.get("base", 0.0)
    if not (is_finite_number(base) and 0.0 <= base < height):
        raise ConfigError(source, f"{key}.base", f"must be a number of metres in [0, height {height!r}), got {base!r}")
    b = Building(building_id, (center[0], center[1]), (size[0], size[1]), float(height),
                 math.radians(_yaw_deg(item, source, key)), float(base))
    fp = b.footprint_xy_m()
    lo, hi = bounds
    if fp[:, 0].min() < lo[0] or fp[:, 1].min() < lo[1] or fp[:, 0].max() > hi[0] or fp[:, 1].max() > hi[1]:
        raise ConfigError(source, key, f"footprint x [{fp[:, 0].min():.2f}, {fp[:, 0].max():.2f}], "
                                       f"y [{fp[:, 1].min():.2f}, {fp[:, 1].max():.2f}] leaves the bounds "
                                       f"x [{lo[0]}, {hi[0]}], y [{lo[1]}, {hi[1]}]")
    return b


def _no_fly(items: Any, source: str) -> list[NoFlyZone]:
    if not isinstance(items, list):
        raise ConfigError(source, "map.no_fly", f"must be a list of zones, got {items!r}")
    zones = []
    for i, item in enumerate(items):
        key = f"map.no_fly[{i}]"
        item = mapping(item, source, key, _NO_FLY_KEYS, ("center", "size", "z_range"))
        center = numbers(item["center"], 2, source, f"{key}.center")
        size = _size(item["size"], source, f"{key}.size")
        z = numbers(item["z_range"], 2, source, f"{key}.z_range")
        if not z[1] > z[0]:
            raise ConfigError(source, f"{key}.z_range",
                              f"must be [bottom, top] with top > bottom, got {item['z_range']!r}")
        zones.append(NoFlyZone((center[0], center[1]), (size[0], size[1]), (z[0], z[1]),
                               math.radians(_yaw_deg(item, source, key))))
    return zones
