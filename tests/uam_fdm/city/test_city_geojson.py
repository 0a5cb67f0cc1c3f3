"""GeoJSON footprints: exact clearance of non-convex footprints, projection, and bad input."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from uam_fdm.city import distance as clearance_np
from uam_fdm.city.buildings import Building, BuildingMap, Prism
from uam_fdm.city.geojson import clean_ring, convex_decomposition, footprint_parts, lonlat_to_enu
from uam_fdm.city.mapfile import map_from_config
from uam_fdm.errors import ConfigError

DATA = Path(__file__).resolve().parents[2] / "data"
BOUNDS = {"min": [0, 0, 0], "max": [300, 300, 150]}


def _load(name: str, **extra: object) -> BuildingMap:
    return map_from_config({"geojson": name, **extra}, BOUNDS, "scenario.yaml", DATA)


def test_l_shaped_footprint_notch_is_exact() -> None:
    bmap = _load("l_shape.geojson")  # L: (100,100)-(130,100)-(130,110)-(110,110)-(110,130)-(100,130), h 40
    assert set(bmap.building_ids.tolist()) == {0, 1}
    notch = np.array([[125.0, 118.0, 20.0]])  # in the L's notch, 20 m up
    expected = 8.0  # to the lower arm's inner edge y = 110 (the left arm's x = 110 is 15 m off; ground 20 m)
    for backend in ("numpy", "fcl"):
        res = bmap.clearance(notch, backend=backend)
        assert abs(res.distance_m[0] - expected) < 0.01
        assert abs(res.distance_m[0] - expected) < 1e-9  # in fact exact
        assert res.building_id[0] == 0
    assert abs(bmap.clearance_one(125.0, 118.0, 20.0) - expected) < 1e-9
    np.testing.assert_allclose(bmap.clearance(notch).nearest_point_m[0], [125.0, 110.0, 20.0], atol=1e-9)
    # The footprint's bounding box would contain the notch point: a box model is wrong there.
    bbox = BuildingMap([Building(0, (115.0, 115.0), (30.0, 30.0), 40.0)], (0, 0, 0), (300, 300, 150))
    assert bbox.clearance(notch).distance_m[0] < 0.0
    # Rectilinear footprints become exact boxes.
    assert all(isinstance(p, Building) for p in bmap.buildings if p.id == 0)


def _area(v: np.ndarray) -> float:
    w = np.roll(v, -1, axis=0)
    return 0.5 * abs(float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1])))


def _point_in_polygon(p: np.ndarray, poly: np.ndarray) -> bool:
    inside = False
    for i in range(len(poly)):
        (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % len(poly)]
        if (y1 > p[1]) != (y2 > p[1]) and p[0] < x1 + (p[1] - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def _edge_distance(p: np.ndarray, poly: np.ndarray) -> float:
    best = math.inf
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        e = b - a
        t = min(max(float(np.dot(p - a, e) / np.dot(e, e)), 0.0), 1.0)
        best = min(best, float(np.linalg.norm(p - a - t * e)))
    return best


@pytest.mark.parametrize("shape", ["star", "comb", "spiral"])
def test_general_nonconvex_footprints_are_exact(shape: str) -> None:
    if shape == "star":
        ang = np.linspace(0.0, 2.0 * np.pi, 14, endpoint=False)
        rad = np.where(np.arange(14) % 2 == 0, 40.0, 12.0)
        poly = np.column_stack([150 + rad * np.cos(ang), 150 + rad * np.sin(ang)])
    elif shape == "comb":  # rectilinear, rotated 20 degrees: boxes
        base = np.array([[0, 0], [60, 0], [60, 40], [50, 40], [50, 10], [40, 10], [40, 40], [30, 40],
                         [30, 10], [20, 10], [20, 40], [10, 40], [10, 10], [0, 10]], float)
        a = math.radians(20.0)
        poly = base @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]]) + 120.0
    else:  # a non-rectilinear hook with a slanted edge
        poly = np.array([[100, 100], [200, 110], [190, 200], [120, 190], [130, 150], [170, 160],
                         [175, 130], [110, 125]], float)
    parts = footprint_parts(poly, 30.0, 4)
    assert all(p.id == 4 for p in parts)
    bmap = BuildingMap(parts, (0, 0, 0), (300, 300, 150))
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(90, 210, 3000), rng.uniform(90, 210, 3000), rng.uniform(0, 30, 3000)])
    d = bmap.clearance(pts).distance_m
    one = np.array([bmap.clearance_one(*p) for p in pts])
    fcl_d = bmap.clearance(pts[:800], backend="fcl").distance_m
    np.testing.assert_allclose(one, d, atol=1e-9)
    np.testing.assert_allclose(fcl_d, d[:800], atol=1e-9)
    inside = np.array([_point_in_polygon(p[:2], poly) for p in pts])
    assert inside.sum() > 100 and (~inside).sum() > 100
    assert np.all(d[inside] <= 0.0)
    ref = np.array([min(_edge_distance(p[:2], poly), p[2]) for p in pts[~inside]])
    np.testing.assert_allclose(d[~inside], ref, atol=1e-9)
    # The pieces tile the footprint: their areas add up to the polygon's.
    area = sum(_area(p.footprint_xy_m()) for p in parts)
    assert abs(area - _area(clean_ring(poly))) < 1e-6


def test_convex_pieces_are_convex() -> None:
    ring = clean_ring(np.array([[0, 0], [10, 0], [10, 10], [5, 3], [0, 10]], float))
    pieces = convex_decomposition(ring)
    assert 2 <= len(pieces) <= 4  # Hertel-Mehlhorn: at most 4x the optimum (2 here)
    for piece in pieces:
        Prism(0, tuple(map(tuple, piece.tolist())), 1.0)  # validates convex, counter-clockwise


def test_multipolygon_parts_share_the_feature_id() -> None:
    bmap = _load("multi.geojson", height_key="h")
    ids = sorted({p.id for p in bmap.buildings})
    assert ids == [0, 1]
    assert sum(p.id == 0 for p in bmap.buildings) == 2  # two squares in feature 0
    assert [p.height_m for p in bmap.buildings if p.id == 1] == [25.0]
    assert any(isinstance(p, Prism) for p in bmap.buildings)  # the triangle


def test_lonlat_projection() -> None:
    xy = lonlat_to_enu(np.array([[0.001, 0.0], [0.0, 0.001], [0.0, 0.0]]), (0.0, 0.0))
    np.testing.assert_allclose(xy[0], [6378137.0 * math.radians(0.001), 0.0], rtol=1e-12)
    # Meridional radius at the equator: a (1 - e^2).
    e2 = (1 / 298.257223563) * (2 - 1 / 298.257223563)
    np.testing.assert_allclose(xy[1], [0.0, 6378137.0 * (1 - e2) * math.radians(0.001)], rtol=1e-12)
    np.testing.assert_allclose(xy[2], [0.0, 0.0], atol=1e-12)
    bmap = _load("lonlat.geojson", origin_lonlat=[8.538, 47.369])  # south-west of the footprint
    (b,) = bmap.buildings
    assert isinstance(b, (Building, Prism))
    fp = b.footprint_xy_m()
    assert 140.0 < fp[:, 0].max() - fp[:, 0].min() < 160.0  # 0.002 deg of longitude at 47.37 N ~ 151 m


@pytest.mark.parametrize("doc, key, reason", [
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 10}, "geometry": {"type": "Point", "coordinates": [1, 2]}}]},
     "features[0].geometry.type", "must be Polygon or MultiPolygon, got 'Point'"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "x"},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [20, 10], [20, 20], [10, 10]]]}}]},
     "features[0].properties.height", "missing"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": -3},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [20, 10], [20, 20], [10, 10]]]}}]},
     "features[0].properties.height", "positive"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 5},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [20, 20], [20, 10], [10, 20], [10, 10]]]}}]},
     "features[0].geometry.coordinates", "self-intersects"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 5},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [50, 10], [50, 50], [10, 10]],
                                                         [[20, 15], [30, 15], [30, 20], [20, 15]]]}}]},
     "features[0].geometry.coordinates", "holes"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 5},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [500, 10], [500, 50], [10, 10]]]}}]},
     "features[0]", "leaves the bounds"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"height": 5},
         "geometry": {"type": "Polygon", "coordinates": [[[10, 10], [20, 10], [30, 10], [10, 10]]]}}]},
     "features[0].geometry.coordinates", "collinear"),
    ({"type": "Feature", "features": []}, "<root>", "FeatureCollection"),
])
def test_bad_geojson(tmp_path: Path, doc: dict, key: str, reason: str) -> None:
    path = tmp_path / "bad.geojson"
    path.write_text(json.dumps(doc))
    with pytest.raises(ConfigError) as exc:
        map_from_config({"geojson": "bad.geojson"}, BOUNDS, "scenario.yaml", tmp_path)
    assert exc.value.source == str(path)
    assert exc.value.key == key and reason in exc.value.reason, str(exc.value)


def test_missing_geojson_file_names_the_scenario(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as exc:
        map_from_config({"geojson": "nope.geojson"}, BOUNDS, "scenario.yaml", tmp_path)
    assert exc.value.source == "scenario.yaml" and exc.value.key == "map.geojson"
    assert "not found" in exc.value.reason


def test_nearest_obstacles_counts_a_decomposed_footprint_once() -> None:
    hook = np.array([[100, 100], [200, 110], [190, 200], [120, 190], [130, 150], [170, 160], [175, 130],
                     [110, 125]], float)
    parts = footprint_parts(hook, 30.0, 5) + footprint_parts(
        np.array([[20, 220], [80, 220], [80, 260], [70, 260], [70, 230], [20, 230]], float), 20.0, 2)
    bmap = BuildingMap(parts, (0, 0, 0), (300, 300, 100))
    assert len(parts) > 4
    rng = np.random.default_rng(1)
    pts = rng.uniform([0, 0, 0], [300, 300, 50], size=(300, 3))
    near, dist, ids = bmap.nearest_obstacles_batch(pts, 3, 0.5, pad_distance_m=999.0)
    assert np.all(np.sort(ids[:, :2], axis=1) == [2, 5]) and np.all(ids[:, 2] == -1)
    np.testing.assert_array_equal(dist[:, 2], 999.0)
    for gid in (2, 5):
        alone = BuildingMap([p for p in parts if p.id == gid], (0, 0, 0), (300, 300, 100))
        ref = clearance_np.part_distances(pts, alone._packed).min(axis=1) - 0.5  # min over its parts
        np.testing.assert_allclose(np.where(ids[:, 0] == gid, dist[:, 0], dist[:, 1]), ref, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(near[:, :2] - pts[:, None], axis=2), np.abs(dist[:, :2] + 0.5),
                               atol=1e-9)


def test_lonlat_without_an_origin_is_refused() -> None:
    """Degrees read as metres would make a building millimetres wide: the file and the position are named."""
    with pytest.raises(ConfigError) as exc:
        _load("lonlat.geojson")
    assert exc.value.source.endswith("lonlat.geojson") and exc.value.key == "features[0].geometry.coordinates[0]"
    assert "origin_lonlat" in exc.value.reason


def test_metres_with_an_origin_are_refused() -> None:
    with pytest.raises(ConfigError) as exc:
        _load("l_shape.geojson", origin_lonlat=[8.5, 47.4])
    assert "lon, lat" in exc.value.reason and exc.value.key.startswith("features[0]")
