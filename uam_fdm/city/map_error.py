"""Map error: the map the pilots are given (the prior) differs from the world they fly in (the truth).

A scenario's `map:` (plus its `unmapped:` buildings and the obstacles generated here) is the TRUE world: it is
what the vehicle collides with and what scores. The prior is the same map as a survey would have it: some
buildings missing, heights off, footprints shifted, and no cranes or masts (thin obstacles that maps leave out).

Levels (`MAP_ERROR_PRESETS`): `exact` (prior = truth), `outdated` (10 % of the buildings missing from the prior,
every height off by up to ±5 m), `wrong` (25 % missing, heights ±8 m, footprints shifted by up to 3 m, 3 tower
cranes and 4 masts that are in no map). Everything is drawn from `np.random.SeedSequence([seed, _TAG])`, one
child stream per kind of error, so the same seed gives the same maps and a change of one parameter (say the
crane count) leaves the other draws as they were.

Frames: world ENU metres, ground z = 0. Building ids: the world's; unmapped buildings and generated obstacles get
new ids above the world's largest (a crane's mast and jib share one id).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from uam_fdm.city import distance as clearance_np
from uam_fdm.city.buildings import Building, BuildingMap, Obstacle, Prism, pack_parts
from uam_fdm.city.mapfile import building_from_config
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import mapping, number_in_range

logger = logging.getLogger(__name__)

MAP_ERROR_LEVELS = ("exact", "outdated", "wrong")  # the presets of the scenario key `map_error:`
MAX_HEIGHT_ERROR_M = 100.0
MAX_SHIFT_M = 50.0
MAX_CRANES = 20
MAX_MASTS = 100
MAX_SEED = 2**32 - 1
KEEP_CLEAR_MARGIN_M = 5.0
"""Generated errors keep this far [m] beyond the vehicle's collision radius from every start and goal."""

# Tower crane (a city-centre flat-top crane): a square lattice mast standing on the ground, a horizontal jib at its
# top reaching ahead and a counter-jib behind, together one box. Ranges are drawn uniformly.
CRANE_HEIGHT_M = (40.0, 70.0)  # top of the jib above the ground
CRANE_JIB_M = (30.0, 60.0)  # jib length ahead of the mast
CRANE_COUNTER_JIB_FRACTION = 0.25  # counter-jib length behind the mast, as a fraction of the jib's
CRANE_JIB_THICKNESS_M = (1.5, 2.0)  # the jib's square cross-section
CRANE_MAST_WIDTH_M = (1.8, 2.2)
# A mast (lighting, radio): thin and tall, on the ground.
MAST_HEIGHT_M = (25.0, 60.0)
MAST_WIDTH_M = (0.6, 1.2)

_TAG = 0x6D61705F  # mixed into the seed: these draws differ from any other stream of the same seed
_TRIES = 100  # draws per prior footprint or generated obstacle before it is left unperturbed or dropped
_GAP_M = 1.0  # a generated obstacle keeps this far from every other obstacle (it stands beside, not inside)
_SAMPLE_M = 1.0  # spacing of the axis samples that test a generated box against the other obstacles


@dataclass(frozen=True)
class MapErrorConfig:
    """How the prior map differs from the true world.

    Attributes:
        level: the preset it starts from ("exact", "outdated", "wrong").
        missing_fraction: fraction of the world's buildings absent from the prior, in [0, 1].
        height_error_m: each prior building's height is off by a uniform draw in ±this [m].
        shift_m: each prior footprint is moved horizontally by a vector drawn uniformly in a disc of this radius [m]
            (so `shift_m` is the largest shift).
        cranes: tower cranes in the true world and in no map, per city.
        masts: masts in the true world and in no map, per city.
        seed: the seed of the draws; None: the scenario's first seed.
        keep_clear: more points (x, y, z) [m, ENU] the drawn errors keep clear of, beside every start and goal (e.g.
            the legs a generated set's quick subset leaves out, so that its maps are its full set's).
        overridden: the keys a scenario changed from the preset (empty: the preset as it is).
    """

    level: str = "exact"
    missing_fraction: float = 0.0
    height_error_m: float = 0.0
    shift_m: float = 0.0
    cranes: int = 0
    masts: int = 0
    seed: int | None = None
    keep_clear: tuple[tuple[float, float, float], ...] = ()
    overridden: tuple[str, ...] = ()

    @property
    def exact(self) -> bool:
        """True: the prior is the world (nothing missing, moved, changed or added)."""
        return not (self.missing_fraction or self.height_error_m or self.shift_m or self.cranes or self.masts)

    @property
    def label(self) -> str:
        """The level as a report names it ("wrong", or "wrong+" when overridden)."""
        return self.level + ("+" if self.overridden else "")


MAP_ERROR_PRESETS = {
    "exact": MapErrorConfig(),
    "outdated": MapErrorConfig("outdated", missing_fraction=0.10, height_error_m=5.0),
    "wrong": MapErrorConfig("wrong", missing_fraction=0.25, height_error_m=8.0, shift_m=3.0, cranes=3, masts=4),
}


@dataclass(frozen=True)
class MapErrorResult:
    """The true world and the pilots' prior map.

    Attributes:
        truth: the world's parts, the unmapped buildings and the generated cranes and masts (the world itself
            when nothing is added).
        prior: the world's parts without the missing ones, heights and footprints perturbed (the world itself
            when nothing is changed).
        unmapped_ids: ids of the truth absent from the prior: unmapped, missing and generated, sorted.
        missing_ids: the world's buildings left out of the prior.
        generated_ids: the cranes and masts placed.
        shifted_ids: prior buildings whose footprint was moved.
        height_changed_ids: prior buildings whose height was changed.
        dropped: cranes and masts that found no place (keep-clear, bounds, other obstacles) and were left out.
    """

    truth: BuildingMap
    prior: BuildingMap
    unmapped_ids: tuple[int, ...]
    missing_ids: tuple[int, ...] = ()
    generated_ids: tuple[int, ...] = ()
    shifted_ids: tuple[int, ...] = ()
    height_changed_ids: tuple[int, ...] = ()
    dropped: int = 0


def map_error_preset(level: str) -> MapErrorConfig:
    """The preset `level` ("exact", "outdated" or "wrong").

    Raises:
        ValueError: an unknown level.
    """
    if level not in MAP_ERROR_PRESETS:
        raise ValueError(f"unknown map-error level {level!r}; expected one of {', '.join(MAP_ERROR_LEVELS)}")
    return MAP_ERROR_PRESETS[level]


def apply_map_error(world: BuildingMap, unmapped: Sequence[Obstacle], config: MapErrorConfig, seed: int,
                    keep_clear: Sequence[Sequence[float]] | np.ndarray, clearance_m: float) -> MapErrorResult:
    """The true world and the prior map of a scenario (a pure function of its arguments).

    Args:
        world: the scenario's map (buildings, bounds, no-fly zones).
        unmapped: buildings that stand in the world but are in no map; ids distinct from the world's.
        config: the map error.
        seed: the seed of every draw (a non-negative integer).
        keep_clear: (K, 3) points, ENU metres: every leg's start and goal.
        clearance_m: no generated obstacle comes within this distance [m] of a keep-clear point, and no perturbed
            prior building comes closer to one than this or than its true counterpart (whichever is less).

    Returns:
        The truth, the prior and the ids that tell them apart.

    Raises:
        ValueError: an unmapped id that is also the world's, a negative seed or clearance.
    """
    if seed < 0 or not clearance_m >= 0.0:
        raise ValueError(f"seed and clearance_m must be non-negative, got {seed}, {clearance_m}")
    world_ids = [int(i) for i in world.building_ids]
    clash = sorted({p.id for p in unmapped} & set(world_ids))
    if clash:
        raise ValueError(f"unmapped buildings reuse the world's ids {clash}")
    keep = np.asarray(keep_clear, dtype=float).reshape(-1, 3)
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence([seed, _TAG]).spawn(6)]
    missing = _missing_ids(world_ids, config.missing_fraction, streams[0])
    prior_parts, shifted, raised = _prior_parts(world, missing, config, streams[1:4], keep, clearance_m)
    next_id = max([*world_ids, *(p.id for p in unmapped)], default=-1) + 1
    known = tuple(world.buildings) + tuple(unmapped)
    generated, dropped = _generate(known, world, config, (streams[4], streams[5]), keep, clearance_m, next_id)
    generated_ids = tuple(sorted({p.id for p in generated}))
    if unmapped or generated:
        truth = BuildingMap(known + tuple(generated), world.bounds_min_m, world.bounds_max_m, world.no_fly,
                            name=world.name)
    else:
        truth = world
    prior = world if not (missing or shifted or raised) else BuildingMap(
        prior_parts, world.bounds_min_m, world.bounds_max_m, world.no_fly, name=world.name)
    absent = sorted({p.id for p in unmapped} | set(missing) | set(generated_ids))
    return MapErrorResult(truth=truth, prior=prior, unmapped_ids=tuple(absent), missing_ids=missing,
                          generated_ids=generated_ids, shifted_ids=shifted, height_changed_ids=raised,
                          dropped=dropped)


# ---- the prior ---------------------------------------------------------------------------------------
def _missing_ids(ids: list[int], fraction: float, rng: np.random.Generator) -> tuple[int, ...]:
    """round(fraction x buildings) of the world's building ids, drawn without replacement, sorted."""
    n = min(len(ids), math.floor(fraction * len(ids) + 0.5))
    if n == 0:
        return ()
    return tuple(sorted(int(i) for i in rng.choice(np.asarray(ids), size=n, replace=False)))


def _draw(n: int, config: MapErrorConfig, heights: np.random.Generator, shifts: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray]:
    """n height errors (n,) [m] and n horizontal shifts (n, 2) [m], uniform in ±height_error_m and in the disc."""
    dz = heights.uniform(-config.height_error_m, config.height_error_m, size=n)
    u = shifts.random((n, 2))
    r = config.shift_m * np.sqrt(u[:, 0])  # sqrt: uniform over the disc's area, not its radius
    theta = 2.0 * math.pi * u[:, 1]
    return dz, np.column_stack([r * np.cos(theta), r * np.sin(theta)])


def _prior_parts(world: BuildingMap, missing: tuple[int, ...], config: MapErrorConfig,
                 rngs: Sequence[np.random.Generator], keep: np.ndarray, clearance_m: float
                 ) -> tuple[tuple[Obstacle, ...], tuple[int, ...], tuple[int, ...]]:
    """The world's parts minus `missing`, each building's height and footprint perturbed (one draw per building
    id, shared by its parts). A building whose perturbed parts leave the bounds or come nearer a keep-clear point
    than min(clearance_m, its true distance) is drawn again from `rngs[2]`, and after `_TRIES` left as it is.

    Returns:
        The prior's parts, the ids shifted and the ids whose height changed (sorted).
    """
    gone = set(missing)
    parts = [p for p in world.buildings if p.id not in gone]
    ids = sorted({p.id for p in parts})
    if not parts or not (config.height_error_m or config.shift_m):
        return tuple(parts), (), ()
    row = {bid: i for i, bid in enumerate(ids)}
    part_row = np.array([row[p.id] for p in parts])
    dz, dxy = _draw(len(ids), config, rngs[0], rngs[1])
    true_d = clearance_np.part_distances(keep, pack_parts(parts)) if len(keep) else None
    for attempt in range(_TRIES + 1):
        moved = [_perturbed(p, float(dz[r]), dxy[r]) for p, r in zip(parts, part_row)]
        bad = np.zeros(len(ids), dtype=bool)
        bad[part_row[~_inside_bounds(moved, world)]] = True
        if true_d is not None:
            d = clearance_np.part_distances(keep, pack_parts(moved))
            near = (d < np.minimum(clearance_m, true_d)).any(axis=0)
            bad[part_row[near]] = True
        if not bad.any():
            break
        if attempt == _TRIES:  # no draw fits: this building stays as the world has it
            dz[bad], dxy[bad] = 0.0, 0.0
            moved = [_perturbed(p, float(dz[r]), dxy[r]) for p, r in zip(parts, part_row)]
            break
        dz[bad], dxy[bad] = _draw(int(bad.sum()), config, rngs[2], rngs[2])
    shifted = tuple(bid for bid, r in row.items() if np.any(dxy[r] != 0.0))
    raised = tuple(bid for bid, r in row.items() if dz[r] != 0.0)
    return tuple(moved), shifted, raised


def _perturbed(part: Obstacle, dz_m: float, dxy_m: np.ndarray) -> Obstacle:
    """`part` with its roof moved by dz_m (never below 1 m above its base, or its own height if lower) and its
    footprint by dxy_m (ENU metres)."""
    if dz_m == 0.0 and not dxy_m.any():
        return part
    base = part.base_m if isinstance(part, Building) else 0.0
    height = max(part.height_m + dz_m, min(part.height_m, base + 1.0))
    dx, dy = float(dxy_m[0]), float(dxy_m[1])
    if isinstance(part, Building):
        cx, cy = part.center_xy_m
        return dataclasses.replace(part, center_xy_m=(cx + dx, cy + dy), height_m=height)
    return Prism(part.id, tuple((x + dx, y + dy) for x, y in part.vertices_xy_m), height)


def _inside_bounds(parts: Sequence[Obstacle], world: BuildingMap) -> np.ndarray:
    """(P,) True where the part's footprint lies inside the world's bounds in x and y."""
    lo, hi = world.bounds_min_m[:2], world.bounds_max_m[:2]
    return np.array([bool(np.all(fp >= lo) and np.all(fp <= hi)) for fp in (p.footprint_xy_m() for p in parts)],
                    dtype=bool)


# ---- cranes and masts --------------------------------------------------------------------------------
def _crane(rng: np.random.Generator, bid: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Building, ...]:
    """A tower crane at a uniform spot: a mast from the ground to the jib's top and a jib (with its counter-jib)
    at the top, a horizontal box lifted off the ground (`base_m`), both with id `bid`."""
    top = rng.uniform(*CRANE_HEIGHT_M)
    jib = rng.uniform(*CRANE_JIB_M)
    thick = rng.uniform(*CRANE_JIB_THICKNESS_M)
    width = rng.uniform(*CRANE_MAST_WIDTH_M)
    yaw = rng.uniform(0.0, 2.0 * math.pi)
    x, y = rng.uniform(lo, hi)
    counter = CRANE_COUNTER_JIB_FRACTION * jib
    ahead = 0.5 * (jib - counter)  # the jib box's centre, ahead of the mast along its yaw
    mast = Building(bid, (x, y), (width, width), top, yaw)
    boom = Building(bid, (x + ahead * math.cos(yaw), y + ahead * math.sin(yaw)), (jib + counter, thick), top, yaw,
                    base_m=top - thick)
    return mast, boom


def _mast(rng: np.random.Generator, bid: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Building, ...]:
    """A thin mast at a uniform spot, standing on the ground."""
    height = rng.uniform(*MAST_HEIGHT_M)
    width = rng.uniform(*MAST_WIDTH_M)
    x, y = rng.uniform(lo, hi)
    return (Building(bid, (x, y), (width, width), height, rng.uniform(0.0, 0.5 * math.pi)),)


def _generate(known: tuple[Obstacle, ...], world: BuildingMap, config: MapErrorConfig,
              rngs: tuple[np.random.Generator, np.random.Generator], keep: np.ndarray, clearance_m: float,
              next_id: int) -> tuple[list[Building], int]:
    """Place `config.cranes` cranes then `config.masts` masts (ids from next_id): each inside the bounds, at
    least `clearance_m` from every keep-clear point and `_GAP_M` from every other obstacle; a candidate that does
    not fit is drawn again, and after `_TRIES` draws dropped (counted, logged)."""
    lo, hi = world.bounds_min_m[:2], world.bounds_max_m[:2]
    known_packed = pack_parts(known) if known else None
    placed: list[Building] = []
    dropped = 0
    for make, count, rng in ((_crane, config.cranes, rngs[0]), (_mast, config.masts, rngs[1])):
        for _ in range(count):
            for _attempt in range(_TRIES):
                candidate = make(rng, next_id, lo, hi)
                if _fits(candidate, known_packed, placed, world, keep, clearance_m):
                    placed.extend(candidate)
                    next_id += 1
                    break
            else:
                dropped += 1
                logger.info("map error: a %s found no free place in %d draws and is left out",
                            make.__name__.lstrip("_"), _TRIES)
    return placed, dropped


def _fits(candidate: tuple[Building, ...], known: clearance_np.PackedPrisms | None, placed: list[Building],
          world: BuildingMap, keep: np.ndarray, clearance_m: float) -> bool:
    """True: every box of `candidate` is inside the bounds, clear of the keep-clear points by clearance_m and
    clear of the other obstacles by `_GAP_M`."""
    if not _inside_bounds(candidate, world).all():
        return False
    if len(keep) and clearance_np.part_distances(keep, pack_parts(candidate)).min() < clearance_m:
        return False
    others = [known] if known is not None else []
    if placed:
        others.append(pack_parts(placed))
    for box in candidate:
        samples, reach = _axis_samples(box)
        for packed in others:
            if clearance_np.part_distances(samples, packed).min() < reach + _GAP_M:
                return False
    return True


def _axis_samples(box: Building) -> tuple[np.ndarray, float]:
    """Points along a box's longest axis, no more than `_SAMPLE_M` apart, and the reach [m] within which they
    cover the box: an obstacle farther than `reach` from every sample does not touch it."""
    sx, sy = box.size_xy_m
    sz = box.height_m - box.base_m
    dims = np.array([sx, sy, sz])
    axis = int(np.argmax(dims))
    n = max(2, math.ceil(dims[axis] / _SAMPLE_M) + 1)
    t = np.linspace(-0.5, 0.5, n) * dims[axis]
    local = np.zeros((n, 3))
    local[:, axis] = t
    c, s = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
    world_xy = local[:, :2] @ np.array([[c, s], [-s, c]]) + np.asarray(box.center_xy_m)
    z = local[:, 2] + 0.5 * (box.base_m + box.height_m)
    cross = np.delete(dims, axis)
    step = dims[axis] / (n - 1)
    return np.column_stack([world_xy, z]), 0.5 * math.sqrt(cross[0] ** 2 + cross[1] ** 2 + step ** 2)


# ---- scenario keys -----------------------------------------------------------------------------------
_CONFIG_KEYS = ("preset", "missing_fraction", "height_error_m", "shift_m", "cranes", "masts", "seed", "keep_clear")
MAX_KEEP_CLEAR = 10_000  # points a scenario's map error keeps clear of, beside its legs


def map_error_from_config(value: Any, source: str, key: str = "map_error") -> MapErrorConfig:
    """The scenario key `map_error:`: a preset name, or `{preset: <level>, <field>: value, ...}` overriding the
    preset's fields (preset default `exact`; `seed` default: the scenario's first seed).

    Raises:
        ConfigError: naming the file, the dotted key and the value.
    """
    levels = ", ".join(MAP_ERROR_LEVELS)
    if isinstance(value, str):
        return _preset(value, source, key)
    cfg = mapping(value, source, key, _CONFIG_KEYS,
                  expected=f"a preset ({levels}) or a mapping with keys from {', '.join(_CONFIG_KEYS)}")
    base = _preset(cfg.get("preset", "exact"), source, f"{key}.preset")
    changes: dict[str, Any] = {}
    for name in _CONFIG_KEYS[1:]:
        if name in cfg:
            changes[name] = _field(name, cfg[name], source, f"{key}.{name}")
    changed = tuple(k for k, v in changes.items() if k not in ("seed", "keep_clear") and v != getattr(base, k))
    return dataclasses.replace(base, **changes, overridden=changed)


def _preset(value: Any, source: str, key: str) -> MapErrorConfig:
    if not isinstance(value, str) or value not in MAP_ERROR_PRESETS:
        raise ConfigError(source, key, f"unknown map-error preset {value!r} (presets: {', '.join(MAP_ERROR_LEVELS)})")
    return MAP_ERROR_PRESETS[value]


def _field(name: str, value: Any, source: str, key: str) -> Any:
    if name == "keep_clear":
        return _points(value, source, key)
    if name == "missing_fraction":
        return number_in_range(value, (0.0, 1.0), "fraction of the buildings", source, key)
    if name == "height_error_m":
        return number_in_range(value, (0.0, MAX_HEIGHT_ERROR_M), "m", source, key)
    if name == "shift_m":
        return number_in_range(value, (0.0, MAX_SHIFT_M), "m", source, key)
    limit = {"cranes": MAX_CRANES, "masts": MAX_MASTS, "seed": MAX_SEED}[name]
    return integer_in_range(value, 0, limit, source, key)


def _points(value: Any, source: str, key: str) -> tuple[tuple[float, float, float], ...]:
    """A list of at most `MAX_KEEP_CLEAR` finite points [x, y, z] (m, ENU), else a ConfigError naming the first bad
    one."""
    if not isinstance(value, list) or len(value) > MAX_KEEP_CLEAR:
        raise ConfigError(source, key, f"must be a list of at most {MAX_KEEP_CLEAR} points [x, y, z] (m, ENU), got "
                                       f"{str(value)[:80]}")
    out = []
    for i, p in enumerate(value):
        if not (isinstance(p, list) and len(p) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                          and math.isfinite(v) for v in p)):
            raise ConfigError(source, f"{key}[{i}]", f"must be a point [x, y, z] of finite numbers (m, ENU), got "
                                                     f"{str(p)[:80]}")
        out.append((float(p[0]), float(p[1]), float(p[2])))
    return tuple(out)


def integer_in_range(value: Any, low: int, high: int, source: str, key: str) -> int:
    """An integer (not a boolean, not a float) in [low, high], else a ConfigError quoting it."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(source, key, f"must be an integer in [{low}, {high}], got {value!r}")
    return value


def unmapped_from_config(value: Any, source: str, world: BuildingMap, key: str = "unmapped") -> tuple[Building, ...]:
    """The scenario key `unmapped:`: a list of buildings in the `map.buildings` format, inside the world's bounds,
    with ids following the world's largest (errors name `unmapped[3].size` and so on).

    Raises:
        ConfigError: naming the file, the dotted key and the value.
    """
    if not isinstance(value, list):
        raise ConfigError(source, key, f"must be a list of buildings ({{center: [x, y], size: [w, d], height: h}}), "
                                       f"got {value!r}")
    first = int(world.building_ids.max()) + 1 if len(world.building_ids) else 0
    bounds = (list(world.bounds_min_m), list(world.bounds_max_m))
    return tuple(building_from_config(item, f"{key}[{i}]", first + i, source, bounds) for i, item in enumerate(value))

