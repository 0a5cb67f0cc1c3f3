"""City generator: determinism, sanity of the districts, and the shipped maps."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.city.generator import (
    MAPS_DIR,
    SHIPPED_MAPS,
    CityGenConfig,
    generate_city,
    params_from_config,
    shipped_map_text,
)
from uam_fdm.city.mapfile import load_named_map, named_maps
from uam_fdm.errors import ConfigError


def _arrays(bmap: BuildingMap) -> np.ndarray:
    """(M, 7) id, centre x, y, size x, y, height, yaw of every building."""
    return np.array([[b.id, *b.center_xy_m, *b.size_xy_m, b.height_m, b.yaw_rad] for b in bmap.buildings])


def _overlap(p: np.ndarray, q: np.ndarray) -> bool:
    """Separating-axis test for two convex polygons (touching counts as overlap)."""
    for poly in (p, q):
        for i in range(len(poly)):
            e = poly[(i + 1) % len(poly)] - poly[i]
            n = np.array([-e[1], e[0]])
            if (p @ n).max() < (q @ n).min() or (q @ n).max() < (p @ n).min():
                return False
    return True


def test_same_seed_same_city_different_seed_different() -> None:
    params = SHIPPED_MAPS["suburb"][0]
    a, b = _arrays(generate_city(params, 7)), _arrays(generate_city(params, 7))
    assert a.shape == b.shape and np.array_equal(a, b)
    c = _arrays(generate_city(params, 8))
    assert a.shape != c.shape or not np.array_equal(a, c)


def test_generator_does_not_touch_global_numpy_random() -> None:
    np.random.seed(123)
    before = np.random.random(3)
    np.random.seed(123)
    generate_city(CityGenConfig(), 1)
    assert np.array_equal(np.random.random(3), before)


@pytest.mark.parametrize("name", sorted(SHIPPED_MAPS))
def test_districts_are_sane(name: str) -> None:
    params, seed = SHIPPED_MAPS[name]
    bmap = generate_city(params, seed)
    fps = [b.footprint_xy_m() for b in bmap.buildings]
    lo, hi = params.margin_m, np.array(params.extent_m) - params.margin_m
    assert all(np.all(fp >= lo - 1e-9) and np.all(fp <= hi + 1e-9) for fp in fps)
    heights = np.array([b.height_m for b in bmap.buildings])
    assert heights.min() >= params.height_range_m[0] and heights.max() <= params.height_range_m[1]
    assert [b.id for b in bmap.buildings] == list(range(len(bmap.buildings)))
    centres = np.array([b.center_xy_m for b in bmap.buildings])
    radius = np.array([0.5 * np.hypot(*b.size_xy_m) for b in bmap.buildings])
    for i in range(len(fps)):  # no two footprints overlap or touch
        near = np.nonzero(np.hypot(*(centres - centres[i]).T) < radius + radius[i])[0]
        assert not any(_overlap(fps[i], fps[j]) for j in near if j != i)


def test_downtown_core_is_taller() -> None:
    params, seed = SHIPPED_MAPS["downtown"]
    bmap = generate_city(params, seed)
    c = np.array(params.core_center_frac) * params.extent_m
    r = np.array([np.hypot(*(np.array(b.center_xy_m) - c)) for b in bmap.buildings])
    h = np.array([b.height_m for b in bmap.buildings])
    assert np.median(h[r < 200]) > 2.0 * np.median(h[r > 350])
    assert h.max() > 150.0 and h.min() >= 10.0


def test_named_maps_are_shipped_and_regenerate_exactly() -> None:
    assert named_maps() == ["canyon", "downtown", "suburb"]
    for name in named_maps():
        text = (MAPS_DIR / f"{name}.yaml").read_text(encoding="utf-8")
        assert text == shipped_map_text(name), \
            f"{name}.yaml is stale: run python -m uam_fdm.city.generator --write-shipped"
        params, seed = SHIPPED_MAPS[name]
        loaded, generated = load_named_map(name), generate_city(params, seed, name=name)
        assert loaded.buildings == generated.buildings  # exact, float for float
        np.testing.assert_array_equal(loaded.bounds_max_m, generated.bounds_max_m)
        assert loaded.name == name
        extent = loaded.bounds_max_m[:2] - loaded.bounds_min_m[:2]
        assert 600.0 <= extent.min() and extent.max() <= 1200.0
        assert 50 <= len(loaded.buildings) <= 300
        assert all(isinstance(b, Building) for b in loaded.buildings)


def test_suburb_is_low_and_canyon_high() -> None:
    mean = {n: np.mean([b.height_m for b in load_named_map(n).buildings]) for n in named_maps()}
    assert mean["suburb"] < 20.0 < mean["downtown"] < mean["canyon"]


def test_params_from_config_strict() -> None:
    params, seed = params_from_config({"preset": "downtown", "seed": 9, "density": 0.5}, "s.yaml", "map.generator")
    assert seed == 9 and params == dataclasses.replace(SHIPPED_MAPS["downtown"][0], density=0.5)
    params, _ = params_from_config({"seed": 1, "extent_m": [600, 700], "lots_per_block": [3, 1]}, "s.yaml", "g")
    assert params.extent_m == (600.0, 700.0) and params.lots_per_block == (3, 1)
    bad = [
        ({"density": 0.5}, "g.seed", "missing"),
        ({"seed": 1, "densty": 0.5}, "g.densty", "unknown key"),
        ({"seed": -1}, "g.seed", "non-negative integer"),
        ({"seed": 1.5}, "g.seed", "non-negative integer"),
        ({"seed": 1, "density": 1.5}, "g.density", "[0, 1]"),
        ({"seed": 1, "extent_m": [100]}, "g.extent_m", "list of 2"),
        ({"seed": 1, "block_size_m": [0, 50]}, "g.block_size_m", "positive"),
        ({"seed": 1, "lots_per_block": [1.5, 2]}, "g.lots_per_block", "integers"),
        ({"seed": 1, "height_median_m": float("nan")}, "g.height_median_m", "finite"),
        ({"seed": 1, "preset": "mars"}, "g.preset", "unknown preset"),
        ({"seed": 1, "fill_range": [0.5, 1.0]}, "g.fill_range", "0.95"),
    ]
    for cfg, key, reason in bad:
        with pytest.raises(ConfigError) as exc:
            params_from_config(cfg, "s.yaml", "g")
        assert exc.value.source == "s.yaml" and exc.value.key == key and reason in exc.value.reason, exc.value
