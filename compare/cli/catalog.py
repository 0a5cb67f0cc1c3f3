"""`list`: what a scenario or a command can name — the scenario sets, the shipped maps, the vehicles, the pilots
(plug-ins too) and the shipped policies — one line each, or `--json` for scripts.

It reads the registries themselves (`compare.scenarios.sets`, `uam_fdm.city.mapfile`, `uam_fdm.vehicle.params`,
`compare.flying.pilots`, `rl.policies.folder`), so nothing here can drift from what the loader accepts, and nothing
more: no set is generated (the generated sets are described from their designs), no plug-in is imported (an entry
point is listed by what it names), and neither PyTorch, matplotlib nor OMPL is loaded.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from compare.flying.pilots import PILOTS, PLUGIN_GROUP
from compare.scenarios import benchmark, sweep
from compare.scenarios.sets import SCENARIO_DIR, builtin_sets
from rl.policies.folder import PROVENANCE, SHIPPED_POLICIES, shipped_policy_dir
from uam_fdm.city.generator import SHIPPED_MAPS
from uam_fdm.city.mapfile import load_named_map, named_maps
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import json_object_file
from uam_fdm.files.yamlfile import load_yaml_file
from uam_fdm.vehicle.params import load_vehicle, preset_names

ROOT = Path(__file__).resolve().parents[2]
"""The folder holding the packages: paths are shown relative to it (no path of this machine is printed)."""


@dataclass(frozen=True)
class Item:
    """One thing a scenario or an option can name.

    Attributes:
        name: what to write (a set name, `map: {named: NAME}`, `vehicle: NAME`, a pilot, a vehicle's policy).
        description: one line.
        details: machine-readable facts for `--json` (kind, path, default, ...).
    """

    name: str
    description: str
    details: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Section:
    """A heading (what names its items, and where) and its items."""

    key: str
    heading: str
    items: tuple[Item, ...]


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `list` to the command line."""
    ls = sub.add_parser("list", help="list the scenario sets, shipped maps, vehicles, pilots (plug-ins too) and "
                                     "shipped policies, one line each (--json for scripts)")
    ls.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    ls.set_defaults(func=list_command)


def list_command(args: argparse.Namespace) -> int:
    """`list`: every section as an aligned table, or (`--json`) one JSON object {section: [{name, description,
    ...}]}."""
    sections = catalog()
    if args.json:
        print(json.dumps({s.key: [{"name": i.name, "description": i.description, **i.details} for i in s.items]
                          for s in sections}, indent=1))
        return 0
    for k, s in enumerate(sections):
        print(("\n" if k else "") + s.heading)
        width = max(len(i.name) for i in s.items)
        for i in s.items:
            print(f"  {i.name:<{width}}  {i.description}")
    return 0


def catalog() -> tuple[Section, ...]:
    """The sections `list` prints, in order: sets, maps, vehicles, pilots, policies."""
    return (
        Section("sets", "Scenario sets (uam-compare run SET, validate SET):", scenario_sets()),
        Section("maps", "Shipped maps (map: {named: NAME}; uam-compare maps draws them):", shipped_maps()),
        Section("vehicles", "Vehicles (vehicle: NAME, or a path to a vehicle file):", vehicles()),
        Section("pilots", "Pilots (pilots: [NAME, ...] in a scenario, --pilots, --pilot):", pilot_items()),
        Section("policies", "Shipped policies (the learned pilot's, per vehicle; --policy DIR flies another):",
                policies()),
    )


def scenario_sets() -> tuple[Item, ...]:
    """The built-in sets: the shipped folders (with the maps and vehicles their files name) and the generated
    sets (from their designs; nothing is generated here)."""
    items = []
    for name in builtin_sets():
        folder = SCENARIO_DIR / name
        if folder.is_dir():
            items.append(Item(name, _folder_set(folder), {"kind": "folder", "path": _shown(folder)}))
        else:
            items.append(Item(name, _generated_set(name), {"kind": "generated"}))
    return tuple(items)


def _folder_set(folder: Path) -> str:
    files = sorted(p for p in folder.iterdir() if p.suffix in (".yaml", ".yml") and p.is_file())
    maps, vehicles = set(), set()
    for path in files:
        try:
            doc = load_yaml_file(path)
        except ConfigError:
            continue  # `validate` names what is wrong with it; a listing only counts it
        if isinstance(doc, dict):
            named = doc.get("map", {}).get("named") if isinstance(doc.get("map"), dict) else None
            maps.add(str(named) if named else "own map")
            vehicles.add(str(doc.get("vehicle")) if isinstance(doc.get("vehicle"), str) else "own vehicle")
    return (f"{len(files)} scenario files in {_shown(folder)}/: maps {', '.join(sorted(maps))}; vehicles "
            f"{', '.join(sorted(vehicles))}")


def _generated_set(name: str) -> str:
    """A generated set's line from its design (`compare.scenarios.benchmark`, `compare.scenarios.sweep`)."""
    if name in benchmark.BENCHMARK_SETS:
        d = benchmark.design_of(name)
        quick = name.endswith("quick")
        cities, legs = (d.quick_scenarios, d.quick_legs) if quick else (d.scenarios_per_vehicle, d.legs_per_scenario)
        role = ("for tuning: the test set's twin on other cities" if "validation" in name
                else "the held-out test pool, versioned")
        subset = f" (the first of {name.removesuffix('-quick')}'s)" if quick else ""
        tiers = ("sensing and map-error tiers" if d.tiers
                 else "perfect sensing over exact maps (the headline set before the tiers)")
        return (f"generated, {role}: per vehicle ({', '.join(vb.vehicle for vb in d.vehicles)}) "
                f"{_count(cities, 'city')} x {_count(legs, 'leg')}{subset}, {tiers}; pilots {', '.join(d.pilots)}")
    if name in sweep.SWEEP_SETS:
        s = sweep.DESIGN
        cities, legs = (s.cities, s.legs_per_city) if name == sweep.FULL else (s.quick_cities, s.quick_legs)
        steps = ", ".join(f"{sv.tasks.vehicle} {len(sweep.sweep_points(sv))}" for sv in s.vehicles)
        return (f"generated robustness sweep: success against density altitude (to "
                f"{max(sweep.DENSITY_ALTITUDES_M) / 1000:g} km) and steady wind, {_count(cities, 'city')} x "
                f"{_count(legs, 'leg')} at each step (steps: {steps})")
    return "generated"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun[:-1] + 'ies' if noun.endswith('y') else noun + 's'}"


def shipped_maps() -> tuple[Item, ...]:
    """The shipped maps: buildings, their heights, the flight volume, and the generator seed they come from."""
    items = []
    for name in named_maps():
        city = load_named_map(name)
        lo, hi = city.bounds_min_m, city.bounds_max_m
        heights = [p.height_m for p in city.buildings] or [0.0]
        seed = SHIPPED_MAPS[name][1] if name in SHIPPED_MAPS else None
        text = (f"{len(city.building_ids)} buildings {min(heights):g}-{max(heights):g} m tall on "
                f"{hi[0] - lo[0]:g} x {hi[1] - lo[1]:g} m, ceiling {hi[2]:g} m"
                + (f" (city generator, seed {seed})" if seed is not None else ""))
        items.append(Item(name, text, {"buildings": len(city.building_ids),
                                       "bounds_m": [list(map(float, lo)), list(map(float, hi))]}))
    return tuple(items)


def vehicles() -> tuple[Item, ...]:
    """The vehicle presets, with the collision radius (start and goal clearances) and top speed."""
    items = []
    for name in preset_names():
        v = load_vehicle(name)
        items.append(Item(name, f"{v.description}; collision radius {v.collision_radius_m:g} m, top speed "
                                f"{v.controller.max_speed_m_s:g} m/s",
                          {"collision_radius_m": v.collision_radius_m, "max_speed_m_s": v.controller.max_speed_m_s}))
    return tuple(items)


def pilot_items() -> tuple[Item, ...]:
    """The registered pilots, the installed plug-in entry points (named, not imported) and the module:Class form."""
    items = []
    for name, entry in PILOTS.items():
        kind = entry.description.split(":", 1)[0].lower()
        notes = [n for n, on in (("flown by default", entry.default), ("flies a policy per vehicle",
                                                                       entry.needs_policy)) if on]
        items.append(Item(name, f"{entry.label}: {kind}" + (f" ({'; '.join(notes)})" if notes else ""),
                          {"kind": "built-in", "default": entry.default}))
    for ep in sorted(metadata.entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        items.append(Item(ep.name, f"plug-in: entry point {ep.value} of {PLUGIN_GROUP} (checked when named)",
                          {"kind": "plug-in", "entry_point": ep.value, "default": False}))
    items.append(Item("module:Class", "any class with the Pilot protocol on PYTHONPATH (docs/plugins.md)",
                      {"kind": "form", "default": False}))
    return tuple(items)


def policies() -> tuple[Item, ...]:
    """The shipped policy folders, per vehicle, with how each was trained and validated (its provenance)."""
    items = []
    for vehicle, folder in SHIPPED_POLICIES.items():
        if shipped_policy_dir(vehicle) is None:
            items.append(Item(vehicle, f"{_shown(folder)}: not installed", {"path": _shown(folder)}))
            continue
        items.append(Item(vehicle, f"{_shown(folder)}: {_provenance_line(folder / PROVENANCE)}",
                          {"path": _shown(folder)}))
    return tuple(items)


def _provenance_line(path: Path) -> str:
    try:
        p = json_object_file(path)
    except (OSError, ValueError):
        return "no readable provenance.json"
    text = f"{p.get('method', 'trained')}"
    if isinstance(p.get("timesteps"), (int, float)):
        text += f", {p['timesteps'] / 1e6:.1f} M timesteps"
    if p.get("preset"):
        text += f" ({p['preset']} preset)"
    val = p.get("validation_of_kept_model")
    if isinstance(val, dict) and isinstance(val.get("success_rate"), (int, float)):
        text += f"; validation success {100.0 * val['success_rate']:.1f} % over {val.get('episodes', '?')} episodes"
    return text


def _shown(path: Path) -> str:
    """`path` relative to the packages' folder (as the repository names it), else its name."""
    try:
        return Path(path).resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return Path(path).name

