"""The city: buildings and no-fly volumes as vertical prisms (`BuildingMap`, clearance through FCL
and the NumPy distance kernel), its sources (explicit lists, the seeded generator, GeoJSON, the
shipped maps) and its figures. World frame ENU, metres.

The public names below are resolved on first use, so `python -m uam_fdm.city.generator` (which
rewrites the shipped maps) runs a module this package has not imported already."""
from __future__ import annotations

import importlib
from typing import Any

_PUBLIC = {
    "Building": "buildings", "BuildingMap": "buildings", "Clearance": "buildings", "NoFlyZone": "buildings",
    "Prism": "buildings", "CityGenConfig": "generator", "generate_city": "generator", "load_map_file": "mapfile",
    "load_named_map": "mapfile", "map_from_config": "mapfile", "named_maps": "mapfile",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'uam_fdm.city' has no attribute {name!r}")
    return getattr(importlib.import_module(f"uam_fdm.city.{_PUBLIC[name]}"), name)
