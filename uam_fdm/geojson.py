"""GeoJSON building footprints, extruded; non-convex footprints decomposed exactly into convex parts.

A FeatureCollection of Polygon / MultiPolygon features, each with a height property [m].
Coordinates are ENU metres, or WGS84 lon/lat degrees when an origin is given (projected on a local
tangent plane about it: an equirectangular approximation, adequate at city scale).

Decomposition: the outer ring is cleaned (duplicate and collinear vertices removed) and checked to
be simple.  A rectilinear ring (all edges parallel or perpendicular to the first) is cut into
rectangles (strips at every vertex, merged where equal).  Any other ring is ear-clipped into
triangles, which are merged greedily into convex pieces while the union stays convex
(Hertel-Mehlhorn: at most 4x the minimum number of pieces).  The pieces tile the
footprint exactly, so the distance from any point outside the footprint is the minimum over the
pieces: exact, not a bounding box.  (Inside a footprint the sign is exact and the depth is the
depth within the piece, a lower bound of the footprint's.)  Rectangular pieces become Building
boxes; the others convex Prism parts.  All parts of one feature share the feature's index as id.
"""
from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uam_fdm.city import Building, Obstacle, Prism
from uam_fdm.errors import ConfigError

# WGS84 ellipsoid, for the local tangent-plane projection.
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563


def load_footprints(path: Path, height_key: str, origin_lonlat: Sequence[float] | None,
                    bounds_min_xy: Sequence[float], bounds_max_xy: Sequence[float]) -> list[Obstacle]:
    """Read a GeoJSON FeatureCollection of footprints and decompose them into convex parts.

    Args:
        path: the .geojson file.
        height_key: name of the feature property holding the height above ground [m].
        origin_lonlat: (lon, lat) degrees of the ENU origin when coordinates are WGS84; None when
            they are already ENU metres.
        bounds_min_xy: (2,) lower corner of the flight volume, ENU metres.
        bounds_max_xy: (2,) upper corner.

    Returns:
        Obstacle parts; a feature's parts all carry the feature's index as id.

    Raises:
        ConfigError: naming the file, the feature (`features[i]...`) and the reason.
    """
    src = str(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(src, "<file>", f"cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(src, "<json>", f"not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        raise ConfigError(src, "<root>", "must be a GeoJSON FeatureCollection with a 'features' list")
    parts: list[Obstacle] = []
    for i, feat in enumerate(doc["features"]):
        key = f"features[{i}]"
        if not isinstance(feat, dict) or feat.get("type") != "Feature":
            raise ConfigError(src, key, "must be a GeoJSON Feature")
        geom = feat.get("geometry")
        gtype = geom.get("type") if isinstance(geom, dict) else None
        if gtype not in ("Polygon", "MultiPolygon"):
            raise ConfigError(src, f"{key}.geometry.type", f"must be Polygon or MultiPolygon, got {gtype!r}")
        props = feat.get("properties")
        height = props.get(height_key) if isinstance(props, dict) else None
        if height is None:
            raise ConfigError(src, f"{key}.properties.{height_key}", "missing: every footprint needs a height [m]")
        if isinstance(height, bool) or not isinstance(height, (int, float)) or not (math.isfinite(height) and height > 0):
            raise ConfigError(src, f"{key}.properties.{height_key}", f"must be a positive number of metres, got {height!r}")
        coords = geom.get("coordinates")
        polygons = [coords] if gtype == "Polygon" else coords
        if not isinstance(polygons, list) or not polygons:
            raise ConfigError(src, f"{key}.geometry.coordinates", "must hold at least one polygon")
        for j, rings in enumerate(polygons):
            pkey = f"{key}.geometry.coordinates" + ("" if gtype == "Polygon" else f"[{j}]")
            if not isinstance(rings, list) or not rings:
                raise ConfigError(src, pkey, "must be a list of linear rings")
            if len(rings) > 1:
                raise ConfigError(src, pkey, "polygons with holes (interior rings) are not supported")
            ring = _ring(rings[0], src, f"{pkey}[0]")
            if origin_lonlat is not None:
                ring = lonlat_to_enu(ring, origin_lonlat)
            if (ring < np.asarray(bounds_min_xy)).any() or (ring > np.asarray(bounds_max_xy)).any():
                raise ConfigError(src, key, "footprint leaves the bounds in x/y")
            try:
                parts.extend(footprint_parts(ring, float(height), i))
            except ValueError as exc:
                raise ConfigError(src, pkey, str(exc)) from None
    return parts


def _ring(ring: Any, src: str, key: str) -> np.ndarray:
    if not isinstance(ring, list) or len(ring) < 3:
        raise ConfigError(src, key, "a linear ring needs at least 3 positions")
    out = []
    for pos in ring:
        if (not isinstance(pos, list) or len(pos) < 2
                or not all(not isinstance(c, bool) and isinstance(c, (int, float)) and math.isfinite(c) for c in pos[:2])):
            raise ConfigError(src, key, f"positions must be [x, y] finite numbers, got {pos!r}")
        out.append((float(pos[0]), float(pos[1])))
    return np.array(out)


def lonlat_to_enu(lonlat: np.ndarray, origin_lonlat: Sequence[float]) -> np.ndarray:
    """Project WGS84 lon/lat degrees (N, 2) onto the local tangent plane at the origin: (N, 2) metres."""
    lon0, lat0 = (math.radians(v) for v in origin_lonlat)
    e2 = _WGS84_F * (2.0 - _WGS84_F)
    w = 1.0 - e2 * math.sin(lat0) ** 2
    r_n = _WGS84_A_M / math.sqrt(w)  # prime-vertical radius of curvature
    r_m = _WGS84_A_M * (1.0 - e2) / w ** 1.5  # meridional radius of curvature
    ll = np.radians(np.asarray(lonlat, dtype=float))
    return np.column_stack([(ll[:, 0] - lon0) * r_n * math.cos(lat0), (ll[:, 1] - lat0) * r_m])


def footprint_parts(ring_xy: np.ndarray, height_m: float, building_id: int) -> list[Obstacle]:
    """Decompose one simple footprint ring into convex parts extruded to a height.

    Args:
        ring_xy: (K, 2) ring vertices, ENU metres, either orientation, closed or not.
        height_m: height above the ground [m].
        building_id: id shared by the parts.

    Returns:
        Building boxes for rectangular pieces, Prism parts for the other convex pieces.

    Raises:
        ValueError: when the ring is degenerate or self-intersecting.
    """
    poly = clean_ring(ring_xy)
    rects = rectilinear_boxes(poly)
    if rects is not None:  # rectilinear: exact boxes, the cheapest primitive for FCL and NumPy
        return [Building(building_id, c, s, height_m, yaw) for c, s, yaw in rects]
    parts: list[Obstacle] = []
    for piece in convex_decomposition(poly):
        rect = _as_rectangle(piece)
        if rect is not None:
            center, size, yaw = rect
            parts.append(Building(building_id, center, size, height_m, yaw))
        else:
            parts.append(Prism(building_id, tuple(map(tuple, piece.tolist())), height_m))
    return parts


def clean_ring(ring_xy: np.ndarray) -> np.ndarray:
    """Drop the closing, duplicate and collinear vertices; orient counter-clockwise; check simplicity."""
    v = np.asarray(ring_xy, dtype=float).reshape(-1, 2)
    scale = float(np.max(np.abs(v - v.mean(axis=0)))) if len(v) else 0.0
    if not scale > 0.0:
        raise ValueError("footprint is degenerate (all vertices coincide)")
    eps = 1e-9 * scale
    pts: list[np.ndarray] = []
    for p in v:
        if not pts or np.max(np.abs(p - pts[-1])) > eps:
            pts.append(p)
    if len(pts) > 1 and np.max(np.abs(pts[0] - pts[-1])) <= eps:
        pts.pop()
    changed = True
    while changed and len(pts) >= 3:
        changed = False
        for i in range(len(pts)):
            a, b, c = pts[i - 1], pts[i], pts[(i + 1) % len(pts)]
            if abs(_cross(a, b, c)) <= 1e-12 * scale * scale:
                pts.pop(i)
                changed = True
                break
    if len(pts) < 3:
        raise ValueError("footprint has fewer than 3 distinct, non-collinear vertices")
    poly = np.array(pts)
    area = _signed_area(poly)
    if area < 0.0:
        poly = poly[::-1].copy()
    _check_simple(poly)
    return poly


def rectilinear_boxes(poly: np.ndarray) -> list[tuple[tuple[float, float], tuple[float, float], float]] | None:
    """Split a rectilinear polygon into rectangles, or None if it is not rectilinear.

    Rectilinear means every edge is parallel or perpendicular to the first one.  In that edge's
    frame the polygon is cut into horizontal strips at every vertex y; each strip is a set of
    x-intervals (between the vertical edges crossing it); equal intervals of consecutive strips
    are merged into one rectangle.

    Args:
        poly: (K, 2) simple counter-clockwise polygon, ENU metres.

    Returns:
        (centre, size, yaw_rad) per rectangle, in ENU metres and radians; or None.
    """
    e0 = poly[1] - poly[0]
    yaw = math.atan2(float(e0[1]), float(e0[0]))
    c, s = math.cos(yaw), math.sin(yaw)
    local = (poly - poly[0]) @ np.array([[c, -s], [s, c]])  # rotate by -yaw about vertex 0
    edges = np.roll(local, -1, axis=0) - local
    tol = 1e-9 * _scale(local)
    vertical = np.abs(edges[:, 0]) <= tol
    if not np.all(vertical | (np.abs(edges[:, 1]) <= tol)):
        return None
    local = local.copy()
    nxt = np.roll(np.arange(len(local)), -1)
    local[nxt[vertical], 0] = local[vertical, 0]  # snap: vertical edges exactly vertical
    horiz = ~vertical
    local[nxt[horiz], 1] = local[horiz, 1]
    ys = np.unique(local[:, 1])
    vert_edges = [(local[i, 0], min(local[i, 1], local[j, 1]), max(local[i, 1], local[j, 1]))
                  for i, j in enumerate(nxt) if vertical[i]]
    open_rects: dict[tuple[float, float], float] = {}  # (x0, x1) -> y0 of a rectangle still growing
    rects_local: list[tuple[float, float, float, float]] = []
    for y0, y1 in itertools.pairwise(ys):
        mid = 0.5 * (y0 + y1)
        xs = sorted(x for x, lo, hi in vert_edges if lo < mid < hi)
        intervals = set(zip(xs[0::2], xs[1::2]))
        for iv in [iv for iv in open_rects if iv not in intervals]:
            rects_local.append((iv[0], iv[1], open_rects.pop(iv), y0))
        for iv in sorted(intervals):
            open_rects.setdefault(iv, y0)
    for iv, y0 in sorted(open_rects.items()):
        rects_local.append((iv[0], iv[1], y0, float(ys[-1])))
    out = []
    for x0, x1, y0, y1 in sorted(rects_local):
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        center = poly[0] + np.array([c * cx - s * cy, s * cx + c * cy])
        out.append(((float(center[0]), float(center[1])), (float(x1 - x0), float(y1 - y0)), yaw))
    return out


def convex_decomposition(poly: np.ndarray) -> list[np.ndarray]:
    """Split a simple counter-clockwise polygon (K, 2) into convex counter-clockwise pieces.

    Ear clipping, then Hertel-Mehlhorn merging.  Deterministic: ears and merges are taken in
    vertex order.
    """
    if _is_convex(poly, list(range(len(poly)))):
        return [poly]
    pieces = [list(t) for t in _ear_clip(poly)]
    merged = True
    while merged:
        merged = False
        for a in range(len(pieces)):
            for b in range(a + 1, len(pieces)):
                m = _merge(pieces[a], pieces[b])
                if m is not None and _is_convex(poly, m):
                    pieces[a] = m
                    del pieces[b]
                    merged = True
                    break
            if merged:
                break
    out = []
    for idx in pieces:
        piece = poly[idx]
        keep = [i for i in range(len(piece))
                if abs(_cross(piece[i - 1], piece[i], piece[(i + 1) % len(piece)])) > 1e-12 * _scale(piece) ** 2]
        out.append(piece[keep])
    return out


# ---- geometry helpers ----------------------------------------------------------------------------------
def _cross(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """z of (b - a) x (c - b): > 0 for a left turn at b."""
    return float((b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]))


def _signed_area(v: np.ndarray) -> float:
    w = np.roll(v, -1, axis=0)
    return 0.5 * float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]))


def _scale(v: np.ndarray) -> float:
    return float(np.max(np.abs(v - v.mean(axis=0))))


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _segments_touch(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> bool:
    d1, d2 = _orient(q1, q2, p1), _orient(q1, q2, p2)
    d3, d4 = _orient(p1, p2, q1), _orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and d1 != 0 and d2 != 0 and d3 != 0 and d4 != 0:
        return True

    def on(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float) -> bool:
        return d == 0 and min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    return on(q1, q2, p1, d1) or on(q1, q2, p2, d2) or on(p1, p2, q1, d3) or on(p1, p2, q2, d4)


def _check_simple(poly: np.ndarray) -> None:
    n = len(poly)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # adjacent edges share a vertex by construction
            if _segments_touch(poly[i], poly[(i + 1) % n], poly[j], poly[(j + 1) % n]):
                raise ValueError(f"footprint ring self-intersects (edges {i} and {j})")


def _in_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> bool:
    """Inside or on the boundary of the counter-clockwise triangle abc."""
    return _orient(a, b, p) >= 0.0 and _orient(b, c, p) >= 0.0 and _orient(c, a, p) >= 0.0


def _ear_clip(poly: np.ndarray) -> list[tuple[int, int, int]]:
    idx = list(range(len(poly)))
    tris: list[tuple[int, int, int]] = []
    eps = 1e-12 * _scale(poly) ** 2
    while len(idx) > 3:
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            turn = _cross(poly[i0], poly[i1], poly[i2])
            if abs(turn) <= eps:  # a straight vertex left by an earlier cut: drop it, no area lost
                del idx[k]
                break
            if turn < 0.0:
                continue  # reflex
            if any(_in_triangle(poly[j], poly[i0], poly[i1], poly[i2]) for j in idx if j not in (i0, i1, i2)):
                continue
            tris.append((i0, i1, i2))
            del idx[k]
            break
        else:
            raise ValueError("footprint could not be triangulated (is the ring simple?)")
    tris.append((idx[0], idx[1], idx[2]))
    return tris


def _merge(a: list[int], b: list[int]) -> list[int] | None:
    """Union of two counter-clockwise pieces sharing an edge (u->v in a, v->u in b), else None."""
    na, nb = len(a), len(b)
    for i in range(na):
        u, v = a[i], a[(i + 1) % na]
        for j in range(nb):
            if b[j] == v and b[(j + 1) % nb] == u:
                a_rot = a[i + 1:] + a[:i + 1]  # starts at v, ends at u
                b_rot = b[j + 1:] + b[:j + 1]  # starts at u, ends at v
                return a_rot + b_rot[1:-1]
    return None


def _is_convex(poly: np.ndarray, idx: list[int]) -> bool:
    pts = poly[idx]
    eps = 1e-12 * _scale(poly) ** 2
    return all(_cross(pts[i - 1], pts[i], pts[(i + 1) % len(pts)]) >= -eps for i in range(len(pts)))


def _as_rectangle(piece: np.ndarray) -> tuple[tuple[float, float], tuple[float, float], float] | None:
    """(centre, size, yaw) if the convex piece is a rectangle, else None."""
    if len(piece) != 4:
        return None
    e = np.roll(piece, -1, axis=0) - piece
    lengths = np.linalg.norm(e, axis=1)
    for i in range(4):
        if abs(float(np.dot(e[i], e[(i + 1) % 4]))) > 1e-12 * lengths[i] * lengths[(i + 1) % 4]:
            return None
    center = piece.mean(axis=0)
    yaw = math.atan2(float(e[0, 1]), float(e[0, 0]))
    return (float(center[0]), float(center[1])), (float(lengths[0]), float(lengths[1])), yaw
