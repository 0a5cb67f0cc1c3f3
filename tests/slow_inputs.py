"""Inputs that once hung or were slow to refuse, built the same for the bad-input tests and for
perf/responsiveness.py, which times them."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from scenario_box import BASE


def alias_bomb(levels: int) -> str:
    """A list of nine aliases to a list of nine aliases ... : 9**levels strings from a few hundred bytes."""
    lines = ["  l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"  l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def star(n: int, center: tuple[float, float] = (150.0, 150.0)) -> np.ndarray:
    """A star-shaped footprint of `n` vertices (radii 60 and 20 m alternating) [m, ENU]."""
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rad = np.where(np.arange(n) % 2 == 0, 60.0, 20.0)
    return np.column_stack([center[0] + rad * np.cos(ang), center[1] + rad * np.sin(ang)])


def geojson_scenario(folder: Path, ring: np.ndarray, name: str = "scen.yaml") -> Path:
    """A scenario in `folder` whose map is one 20 m footprint, `ring`, in `folder/fp.geojson`."""
    coords = ring.tolist() + [ring[0].tolist()]
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 20.0}, "geometry": {"type": "Polygon", "coordinates": [coords]}}]}
    (folder / "fp.geojson").write_text(json.dumps(doc))
    path = folder / name
    path.write_text(yaml.safe_dump({**BASE, "map": {"geojson": "fp.geojson"},
                                    "bounds": {"min": [0, 0, 0], "max": [300, 300, 100]},
                                    "episodes": [{"start": [10.0, 10.0, 10.0], "goal": [290.0, 20.0, 10.0]}]},
                                   sort_keys=False))
    return path
