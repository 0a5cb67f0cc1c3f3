"""GeoJSON building footprints, extruded; non-convex footprints decomposed exactly into convex parts.

A FeatureCollection of Polygon / MultiPolygon features, each with a height property [m].
Coordinates are ENU metres, or WGS84 lon/lat degrees when an origin is given (projected on a local
tangent plane about it: an equirectangular approximation, adequate at city scale).

Decomposition: the outer ring is cleaned (duplicate and collinear vertices removed) and checked to
be simple (GEOS, through shapely).  A rectilinear ring (all edges parallel or perpendicular to the
first) is cut into rectangles by a sweep over its vertices (strips at every vertex, merged where
equal).  Any other ring is triangulated (GEOS's constrained Delaunay triangulation), and the
triangles are merged into convex pieces across every diagonal whose removal keeps both ends convex
(Hertel-Mehlhorn: at most 4x the minimum number of pieces).  Each step is O(K log K) or close to it
for K vertices (a 10,000-vertex star takes well under a second); a ring may have at most
`MAX_FOOTPRINT_VERTICES` vertices.  The pieces tile the footprint exactly, so the distance from any
point outside the footprint is the minimum over the pieces: exact, not a bounding box.  (Inside a
footprint the sign is exact and the depth is the depth within the piece, a lower bound of the
footprint's.)  Rectangular pieces become Building boxes; the others convex Prism parts.  All parts
of one feature share the feature's index as id.
"""
from __future__ import annotations

import bisect
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import shapely

from uam_fdm.city.buildings import Building, Obstacle, Prism
from uam_fdm.errors import ConfigError
from uam_fdm.files.strict import strict_json_loads

# WGS84 ellipsoid, for the local tangent-plane projection.
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
# Vertices of one footprint ring (a detailed real building outline has tens to hundreds); the
# decomposition is near-linear, but every part it yields is checked at every physics step.
MAX_FOOTPRINT_VERTICES = 10_000
# no building is under 10 cm across; lon/lat footprints read as metres are (a city block is ~0.001 degrees)
MIN_FOOTPRINT_M = 0.1


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
    if Path(path).is_dir():
        raise ConfigError(src, "<file>", "is a folder, not a GeoJSON file")
    try:
        doc = strict_json_loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(src, "<file>", f"cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(src, "<file>", f"not a text file (byte {exc.start} is not UTF-8): expected GeoJSON") from None
    except ValueError as exc:  # JSONDecodeError is one, as is an integer too long to be a number
        raise ConfigError(src, "<json>", f"not valid JSON: {exc}") from None
    except RecursionError:
        raise ConfigError(src, "<json>", "nested too deeply") from None
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
        if (isinstance(height, bool) or not isinstance(height, (int, float))
                or not (math.isfinite(height) and height > 0)):
            raise ConfigError(src, f"{key}.properties.{height_key}",
                              f"must be a positive number of metres, got {height!r}")
        assert isinstance(geom, dict)  # gtype would be None otherwise
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
                if (np.abs(ring[:, 0]) > 180.0).any() or (np.abs(ring[:, 1]) > 90.0).any():
                    raise ConfigError(src, f"{pkey}[0]", "positions must be [lon, lat] degrees (map.origin_lonlat is "
                                                         f"given), got {ring[np.argmax(np.abs(ring).max(axis=1))]}")
                ring = lonlat_to_enu(ring, origin_lonlat)
            else:
                _check_metres(ring, src, f"{pkey}[0]")
            if (ring < np.asarray(bounds_min_xy)).any() or (ring > np.asarray(bounds_max_xy)).any():
                raise ConfigError(src, key, "footprint leaves the bounds in x/y")
            try:
                parts.extend(footprint_parts(ring, float(height), i))
            except ValueError as exc:
                raise ConfigError(src, pkey, str(exc)) from None
    return parts


def _check_metres(ring: np.ndarray, src: str, key: str) -> None:
    """Refuse a footprint read as metres that can only be degrees: lon/lat in range and smaller than any building."""
    extent = ring.max(axis=0) - ring.min(axis=0)
    degrees = (np.abs(ring[:, 0]) <= 180.0).all() and (np.abs(ring[:, 1]) <= 90.0).all()
    if degrees and extent.max() < MIN_FOOTPRINT_M:
        raise ConfigError(src, key, f"a footprint {extent[0]:.3g} x {extent[1]:.3g} m: these look like lon/lat "
                                    "degrees; give map.origin_lonlat [lon, lat] to project them onto local metres")


def _ring(ring: Any, src: str, key: str) -> np.ndarray:
    if not isinstance(ring, list) or len(ring) < 3:
        raise ConfigError(src, key, "a linear ring needs at least 3 positions")
    if len(ring) > MAX_FOOTPRINT_VERTICES + 1:  # + 1: GeoJSON repeats the first position at the end
        raise ConfigError(src, key, f"{len(ring):,} positions; a footprint may have at most "
                                    f"{MAX_FOOTPRINT_VERTICES:,} vertices")
    out = []
    for pos in ring:
        if (not isinstance(pos, list) or len(pos) < 2
                or not all(not isinstance(c, bool) and isinstance(c, (int, float)) and math.isfinite(c)
                           for c in pos[:2])):
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
        ring_xy: (K, 2) ring vertices, ENU metres, either orientation, closed or not;
            K <= MAX_FOOTPRINT_VERTICES (+ 1 closing vertex).
        height_m: height above the ground [m].
        building_id: id shared by the parts.

    Returns:
        Building boxes for rectangular pieces, Prism parts for the other convex pieces.

    Raises:
        ValueError: when the ring is too long, degenerate or self-intersecting.
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
    """Drop the closing, duplicate and collinear vertices; orient counter-clockwise; check simplicity.

    Raises:
        ValueError: more than MAX_FOOTPRINT_VERTICES vertices, fewer than 3 useful ones, or a ring
            that crosses or touches itself (naming where).
    """
    v = np.asarray(ring_xy, dtype=float).reshape(-1, 2)
    if len(v) > MAX_FOOTPRINT_VERTICES + 1:
        raise ValueError(f"footprint has {len(v):,} vertices; at most {MAX_FOOTPRINT_VERTICES:,}")
    scale = float(np.max(np.abs(v - v.mean(axis=0)))) if len(v) else 0.0
    if not scale > 0.0:
        raise ValueError("footprint is degenerate (all vertices coincide)")
    eps = 1e-9 * scale
    pts: list[tuple[float, float]] = []
    for x, y in v.tolist():
        if not pts or max(abs(x - pts[-1][0]), abs(y - pts[-1][1])) > eps:
            pts.append((x, y))
    if len(pts) > 1 and max(abs(pts[0][0] - pts[-1][0]), abs(pts[0][1] - pts[-1][1])) <= eps:
        pts.pop()
    pts = _drop_straight_vertices(pts, 1e-12 * scale * scale)
    if len(pts) < 3:
        raise ValueError("footprint has fewer than 3 distinct, non-collinear vertices")
    poly = np.array(pts)
    if _signed_area(poly) < 0.0:
        poly = poly[::-1].copy()
    _check_simple(poly)
    return poly


def _drop_straight_vertices(pts: list[tuple[float, float]], tol: float) -> list[tuple[float, float]]:
    """The ring without vertices where it goes straight on (or turns back): |cross| <= tol. One pass."""
    out: list[tuple[float, float]] = []
    for p in pts:
        out.append(p)
        while len(out) >= 3 and abs(_cross(out[-3], out[-2], out[-1])) <= tol:
            del out[-2]
    while len(out) >= 3:  # the pass never looked across the seam between the last and the first vertex
        if abs(_cross(out[-2], out[-1], out[0])) <= tol:
            out.pop()
        elif abs(_cross(out[-1], out[0], out[1])) <= tol:
            out.pop(0)
        else:
            break
    return out


def rectilinear_boxes(poly: np.ndarray) -> list[tuple[tuple[float, float], tuple[float, float], float]] | None:
    """Split a rectilinear polygon into rectangles, or None if it is not rectilinear.

    Rectilinear means every edge is parallel or perpendicular to the first one.  In that edge's
    frame the polygon is cut into horizontal strips at every vertex y; each strip is a set of
    x-intervals (between the vertical edges crossing it); equal intervals of consecutive strips
    are merged into one rectangle.  A sweep keeps the crossing edges sorted and updates only the
    intervals next to the edges that start or end at each y: O(K log K) for K vertices.

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
    # Edges on one line (rounded apart by the rotation) onto one coordinate, so that the sweep meets
    # them at the same y instead of leaving a strip one rounding error thick.
    local[:, 0] = _snap(local[:, 0], tol)
    local[:, 1] = _snap(local[:, 1], tol)
    starts: dict[float, list[float]] = {}  # y -> x of the vertical edges starting (bottom end) there
    ends: dict[float, list[float]] = {}
    for i in np.flatnonzero(vertical).tolist():
        x, ya, yb = float(local[i, 0]), float(local[i, 1]), float(local[nxt[i], 1])
        starts.setdefault(min(ya, yb), []).append(x)
        ends.setdefault(max(ya, yb), []).append(x)
    xs: list[float] = []  # x of the vertical edges crossing the current strip, sorted
    open_rects: dict[tuple[float, float], float] = {}  # (x0, x1) -> y0 of a rectangle still growing
    rects_local: list[tuple[float, float, float, float]] = []
    for y in sorted(set(starts) | set(ends)):
        changed = ends.get(y, []) + starts.get(y, [])
        before = {iv for x in changed if (iv := _interval_at(xs, x)) is not None}
        for x in ends.get(y, []):
            k = bisect.bisect_left(xs, x)
            if k == len(xs) or xs[k] != x:
                raise ValueError("footprint ring is not simple (a rectilinear sweep lost an edge)")
            del xs[k]
        for x in starts.get(y, []):
            bisect.insort(xs, x)
        after = {iv for x in changed if (iv := _interval_at(xs, x)) is not None}
        for iv in before - after:
            rects_local.append((iv[0], iv[1], open_rects.pop(iv), y))
        for iv in after - before:
            open_rects.setdefault(iv, y)
    if xs or open_rects:
        raise ValueError("footprint ring is not simple (a rectilinear sweep did not close)")
    out = []
    for x0, x1, y0, y1 in sorted(rects_local):
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        center = poly[0] + np.array([c * cx - s * cy, s * cx + c * cy])
        out.append(((float(center[0]), float(center[1])), (float(x1 - x0), float(y1 - y0)), yaw))
    return out


def _snap(values: np.ndarray, tol: float) -> np.ndarray:
    """`values` with each run of sorted values spaced <= tol apart replaced by the run's smallest."""
    order = np.argsort(values, kind="stable")
    v = values[order]
    run_start = np.diff(v, prepend=-np.inf) > tol
    out = np.empty_like(values)
    out[order] = v[run_start][np.cumsum(run_start) - 1]
    return out


def _interval_at(xs: list[float], x: float) -> tuple[float, float] | None:
    """The interval (xs[2k], xs[2k + 1]) holding x (endpoints included), or None when x is between intervals."""
    k = bisect.bisect_left(xs, x)
    if k < len(xs) and xs[k] == x:
        k -= k % 2
        return (xs[k], xs[k + 1]) if k + 1 < len(xs) else None
    if k % 2 == 1:  # xs[k - 1] < x < xs[k] with xs[k - 1] a left end
        return xs[k - 1], xs[k]
    return None


def convex_decomposition(poly: np.ndarray) -> list[np.ndarray]:
    """Split a simple counter-clockwise polygon (K, 2) into convex counter-clockwise pieces.

    A constrained Delaunay triangulation (GEOS), then Hertel-Mehlhorn: each diagonal is removed
    when both its ends stay convex in the merged piece.  Pieces are kept as linked boundaries and
    the smaller is merged into the larger, so the merging is O(K log K).  Deterministic: the
    triangulation depends only on the vertices, and diagonals are visited in a fixed order.
    """
    eps = 1e-12 * _scale(poly) ** 2
    turns = _turns(poly)
    if np.all(turns >= -eps):
        return [poly]
    pts = poly.tolist()
    # a sliver of zero area covers nothing; leaving it out keeps the neighbours' edges unambiguous
    tris = [t for t in _triangulate(poly) if _cross(pts[t[0]], pts[t[1]], pts[t[2]]) > eps]
    # piece id -> {vertex: [previous, next]} around the piece's counter-clockwise boundary
    pieces: dict[int, dict[int, list[int]]] = {}
    owner = list(range(len(tris)))  # union-find over triangles: the piece each belongs to
    edge_tri: dict[tuple[int, int], int] = {}
    for t, (i, j, k) in enumerate(tris):
        pieces[t] = {i: [k, j], j: [i, k], k: [j, i]}
        for edge in ((i, j), (j, k), (k, i)):
            edge_tri.setdefault(edge, t)

    def find(t: int) -> int:
        while owner[t] != t:
            owner[t] = owner[owner[t]]
            t = owner[t]
        return t

    for t, tri in enumerate(tris):
        for u, v in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            other = edge_tri.get((v, u))
            if other is None or other < t:  # a polygon edge, or a diagonal already visited
                continue
            pa, pb = find(t), find(other)  # pa has the edge u -> v, pb has v -> u
            a, b = pieces[pa], pieces[pb]
            # merged boundary: ... a.prev(u) -> u -> b.next(u) ... b.prev(v) -> v -> a.next(v) ...
            if a.get(u, (0, -1))[1] != v or b.get(v, (0, -1))[1] != u:
                continue  # not a shared boundary edge (degenerate input): keep the pieces apart
            if _cross(pts[a[u][0]], pts[u], pts[b[u][1]]) < 0.0 or _cross(pts[b[v][0]], pts[v], pts[a[v][1]]) < 0.0:
                continue
            small, large = (pb, pa) if len(b) <= len(a) else (pa, pb)
            if any(w in pieces[large] for w in pieces[small] if w not in (u, v)):
                continue  # the pieces touch elsewhere too (only for degenerate input): keep them apart
            u_links = (a[u][0], b[u][1])
            v_links = (b[v][0], a[v][1])
            merged = pieces[large]
            for w, w_links in pieces.pop(small).items():
                if w not in (u, v):
                    merged[w] = w_links
            merged[u] = list(u_links)
            merged[v] = list(v_links)
            owner[small] = large
    out = []
    for pid in sorted(pieces):
        links = pieces[pid]
        start = min(links)
        ring, w = [start], links[start][1]
        while w != start:
            ring.append(w)
            w = links[w][1]
        piece = poly[ring]
        keep = np.abs(_turns(piece)) > 1e-12 * _scale(piece) ** 2
        if keep.sum() >= 3:  # a sliver of zero area covers nothing
            out.append(piece[keep])
    return out


def _triangulate(poly: np.ndarray) -> list[tuple[int, int, int]]:
    """Counter-clockwise triangles (vertex indices) tiling the simple polygon `poly` (GEOS)."""
    index = {p: i for i, p in enumerate(map(tuple, poly.tolist()))}
    try:
        coll = shapely.constrained_delaunay_triangles(shapely.Polygon(poly))
    except shapely.errors.GEOSException as exc:
        raise ValueError(f"footprint could not be triangulated: {exc}") from None
    tris = []
    for tri in shapely.get_parts(coll):
        corners = [index.get(p) for p in map(tuple, shapely.get_coordinates(tri)[:3].tolist())]
        if None in corners:
            raise ValueError("footprint could not be triangulated on its own vertices")
        a, b, c = cast("list[int]", corners)  # no None left (checked above)
        tris.append((a, b, c) if _cross(poly[a], poly[b], poly[c]) > 0.0 else (a, c, b))
    area = sum(abs(_cross(poly[a], poly[b], poly[c])) for a, b, c in tris) / 2.0
    if abs(area - _signed_area(poly)) > 1e-9 * abs(_signed_area(poly)):
        raise ValueError("footprint could not be triangulated exactly (is the ring simple?)")
    return tris


# ---- geometry helpers ----------------------------------------------------------------------------------
def _cross(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray, c: Sequence[float] | np.ndarray) -> float:
    """z of (b - a) x (c - b): > 0 for a left turn at b."""
    return float((b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]))


def _turns(v: np.ndarray) -> np.ndarray:
    """`_cross` at every vertex of the ring v (K, 2), vectorised: (K,)."""
    a, c = np.roll(v, 1, axis=0), np.roll(v, -1, axis=0)
    return (v[:, 0] - a[:, 0]) * (c[:, 1] - v[:, 1]) - (v[:, 1] - a[:, 1]) * (c[:, 0] - v[:, 0])


def _signed_area(v: np.ndarray) -> float:
    w = np.roll(v, -1, axis=0)
    return 0.5 * float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]))


def _scale(v: np.ndarray) -> float:
    return float(np.max(np.abs(v - v.mean(axis=0))))


def _check_simple(poly: np.ndarray) -> None:
    """Raise ValueError, naming where, unless the ring neither crosses nor touches itself (GEOS, O(K log K))."""
    reason = shapely.is_valid_reason(shapely.Polygon(poly))
    if reason == "Valid Geometry":
        return
    where = re.search(r"\[(\S+) (\S+)\]", reason)
    at = f" at ({float(where[1]):g}, {float(where[2]):g})" if where else ""
    if "elf-intersection" in reason:
        raise ValueError(f"footprint ring self-intersects{at}")
    raise ValueError(f"footprint ring is not a simple polygon: {reason}")


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
