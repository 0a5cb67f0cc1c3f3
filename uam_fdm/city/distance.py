"""Exact signed distances from points to vertical prisms, in NumPy and in plain Python.

Every obstacle is a vertical prism: a footprint (a yawed rectangle, or a general convex polygon)
extruded over a height range [z_c - h_z, z_c + h_z].  For such a product set the signed distance is
exact and closed-form: with d2 the signed 2D distance to the footprint and dz the signed 1D distance
to the height range, the distance is hypot(max(d2, 0), max(dz, 0)) outside and max(d2, dz) inside.

The formula is written here once, for every consumer in the project:
  * `vertical_prism_key`: the product-set combination above (signed squared distance), fed by a box
    (`box_signed_sq_distance`, the kernel every box distance calls: BuildingMap.clearance and
    `rl.sensing.sensor.BoxSensor`) or by a convex footprint; `signed_sqrt` turns keys into distances.
  * `box_frame_xy`: a point in a box's own horizontal frame (the rotation the formula starts with;
    also used for footprint distances, nearest points and inside tests here and in `rl`).
  * `box_signed_distance_one` / `_prism_distance_py`: the same arithmetic for one point in plain
    Python, where NumPy's per-call overhead would cost more than the formula (CellIndex, the
    sensor's single-vehicle path); they return the same doubles as the NumPy kernel (tested).
Consumers in this module, all exact (the analytic formula, not an approximation):
  * `nearest_parts` / `part_distances`: a batch of points against all obstacles, vectorised over
    (points x obstacles) and chunked so the temporaries stay in cache (BuildingMap.clearance).
  * `CellIndex`: one point at a time in plain Python (BuildingMap.clearance_one, called from OMPL
    validity callbacks), over a short candidate list per grid cell built lazily from exact bounds.
Both agree with FCL point queries to ~1e-12 m (tests/uam_fdm/city/test_city_clearance.py).

Frames: world ENU, metres.  Distances here are point distances (no radius).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

_Real = np.ndarray | float  # an array, or one value on the plain-Python paths

# Points per chunk of the (points x obstacles) broadcast: ~128 x 200 float64 temporaries stay in L2.
_CHUNK = 128
_PRUNE_FROM = 64  # boxes from which nearest_parts first leaves out those that cannot be any point's nearest
# bound once: the per-point paths call them for every point and candidate
_floor = math.floor
_sqrt = math.sqrt


@dataclass(frozen=True)
class PackedPrisms:
    """Obstacles packed as arrays; boxes and convex prisms apart (the box formula is ~5x cheaper).

    Rows of the box arrays are boxes, rows of the prism arrays are convex prisms; `box_part` and
    `prism_part` give each row's index in the caller's list of parts.  Prism edges are padded to a
    common count by repeating edge 0 (harmless for the max/min over edges).
    """

    box_part: np.ndarray  # (B,) int
    box_cx: np.ndarray  # (B,) footprint centre x [m]
    box_cy: np.ndarray
    box_cos: np.ndarray  # cos(yaw)
    box_sin: np.ndarray
    box_hx: np.ndarray  # half size along the box's own x axis [m]
    box_hy: np.ndarray
    box_zc: np.ndarray  # centre of the height range [m]
    box_hz: np.ndarray  # half of the height range [m]
    prism_part: np.ndarray  # (P,) int
    prism_v0: np.ndarray  # (P, K, 2) edge start vertices [m]
    prism_e: np.ndarray  # (P, K, 2) edge vectors [m]
    prism_n: np.ndarray  # (P, K, 2) unit outward normals
    prism_inv_len2: np.ndarray  # (P, K) 1 / |e|^2
    prism_zc: np.ndarray  # (P,)
    prism_hz: np.ndarray  # (P,)

    @property
    def n_parts(self) -> int:
        """Number of obstacles (boxes + prisms)."""
        return len(self.box_part) + len(self.prism_part)


def pack(
    boxes: list[tuple[float, float, float, float, float, float, float]],
    polygons: list[tuple[np.ndarray, float, float]],
    box_part: list[int],
    prism_part: list[int],
) -> PackedPrisms:
    """Pack obstacles into arrays.

    Args:
        boxes: per box (cx, cy, yaw_rad, size_x, size_y, z_min, z_max), metres, ENU.
        polygons: per convex prism (vertices (K, 2) counter-clockwise, z_min, z_max).
        box_part: index of each box in the caller's part list.
        prism_part: index of each prism in the caller's part list.
    """
    b = np.asarray(boxes, dtype=float).reshape(-1, 7)
    kmax = max((len(v) for v, _, _ in polygons), default=3)
    n_p = len(polygons)
    v0 = np.zeros((n_p, kmax, 2))
    e = np.zeros((n_p, kmax, 2))
    zc = np.zeros(n_p)
    hz = np.zeros(n_p)
    for i, (verts, z0, z1) in enumerate(polygons):
        v = np.asarray(verts, dtype=float)
        idx = np.arange(kmax)
        idx[len(v):] = 0  # pad with copies of edge 0: a repeated edge changes neither max nor min
        v0[i] = v[idx]
        e[i] = np.roll(v, -1, axis=0)[idx] - v[idx]
        zc[i], hz[i] = 0.5 * (z0 + z1), 0.5 * (z1 - z0)
    len2 = np.einsum("pki,pki->pk", e, e) if n_p else np.zeros((0, kmax))
    inv_len2 = 1.0 / np.where(len2 > 0.0, len2, 1.0)
    length = np.sqrt(len2)[..., None]
    # Outward normal of a counter-clockwise polygon: the edge direction turned clockwise.
    normal = np.stack([e[..., 1], -e[..., 0]], axis=-1) / np.where(length > 0.0, length, 1.0)
    return PackedPrisms(
        box_part=np.asarray(box_part, dtype=np.int64),
        box_cx=b[:, 0].copy(), box_cy=b[:, 1].copy(),
        box_cos=np.cos(b[:, 2]), box_sin=np.sin(b[:, 2]),
        box_hx=0.5 * b[:, 3], box_hy=0.5 * b[:, 4],
        box_zc=0.5 * (b[:, 5] + b[:, 6]), box_hz=0.5 * (b[:, 6] - b[:, 5]),
        prism_part=np.asarray(prism_part, dtype=np.int64),
        prism_v0=v0, prism_e=e, prism_n=normal, prism_inv_len2=inv_len2, prism_zc=zc, prism_hz=hz,
    )


# ----------------------------------------------------------------- the formula (one place)


def box_frame_xy(x: _Real, y: _Real, cx: _Real, cy: _Real, cos: _Real, sin: _Real) -> tuple[Any, Any]:
    """Horizontal positions in boxes' own frames (x along the box's x axis), broadcast.

    Args:
        x, y: point coordinates, ENU metres.
        cx, cy: footprint centres, ENU metres.
        cos, sin: cos and sin of the boxes' yaw (counter-clockwise about +z).

    Returns:
        (lx, ly) [m], new arrays of the broadcast shape (floats for floats: the per-point paths).
    """
    dx = x - cx
    dy = y - cy
    # In place where the shapes allow (the batched paths: one temporary at a time, so a chunk's arrays
    # stay in cache), else new arrays; the same doubles either way.
    lx = dx * cos
    t = dy * sin
    if isinstance(lx, np.ndarray) and isinstance(t, np.ndarray) and lx.shape == t.shape:
        lx += t
    else:
        lx = lx + t
    ly = dy * cos
    t = dx * sin
    if isinstance(ly, np.ndarray) and isinstance(t, np.ndarray) and ly.shape == t.shape:
        ly -= t
    else:
        ly = ly - t
    return lx, ly


def vertical_prism_key(out2_xy: np.ndarray, d_xy: np.ndarray, qz: np.ndarray) -> np.ndarray:
    """Signed squared distance sign(d)*d^2 to vertical prisms, from the footprint and height parts.

    The exact product-set formula: d = hypot(max(d_xy, 0), max(qz, 0)) outside, max(d_xy, qz) inside,
    as out2_xy + max(qz, 0)^2 - min(max(d_xy, qz), 0)^2.  The arguments are overwritten (no copies).

    Args:
        out2_xy: squared 2D distance to the footprint where the point is outside it (0 inside) [m^2].
        d_xy: signed 2D footprint distance where inside (<= 0), any positive value outside [m].
        qz: signed distance to the height range, |z - zc| - hz [m].

    Returns:
        The keys [m^2] (the array `out2_xy`), monotone in the signed distance.
    """
    inside = np.maximum(d_xy, qz, out=d_xy)
    np.minimum(inside, 0.0, out=inside)
    np.maximum(qz, 0.0, out=qz)
    qz *= qz
    out2_xy += qz
    inside *= inside
    out2_xy -= inside
    return out2_xy


def box_signed_sq_distance(x: np.ndarray, y: np.ndarray, z: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                           cos: np.ndarray, sin: np.ndarray, hx: np.ndarray, hy: np.ndarray, zc: np.ndarray,
                           hz: np.ndarray) -> np.ndarray:
    """Signed squared point distances sign(d)*d^2 to (yawed) boxes, broadcast: THE box kernel.

    The key is monotone in the signed distance, so an argmin needs no square root (`signed_sqrt`
    gives the distance).  In-place operations keep the temporaries to a few arrays of the result's
    shape; x - cx and z - zc must already have that shape (true when the box arrays have it).

    Args:
        x, y, z: point coordinates, ENU metres (e.g. (N, 1) against boxes (B,) or (N, C)).
        cx, cy: footprint centres [m]; cos, sin: of the yaw (counter-clockwise about +z).
        hx, hy: half sizes along the box's own x and y axes [m].
        zc, hz: centre and half of the height range [m].

    Returns:
        keys [m^2], negative inside.
    """
    qx, qy = box_frame_xy(x, y, cx, cy, cos, sin)
    np.abs(qx, out=qx)
    qx -= hx
    np.abs(qy, out=qy)
    qy -= hy
    qz = z - zc
    np.abs(qz, out=qz)
    qz -= hz
    d_xy = np.maximum(qx, qy)
    np.maximum(qx, 0.0, out=qx)
    np.maximum(qy, 0.0, out=qy)
    qx *= qx
    qy *= qy
    qx += qy
    return vertical_prism_key(qx, d_xy, qz)


def signed_sqrt(key: np.ndarray) -> np.ndarray:
    """Signed distances [m] from an array (at least 1-D) of signed squared distances sign(d)*d^2 [m^2].

    Exact for the keys above: outside it is the square root of the sum of squares; inside,
    sqrt(d*d) == |d| in binary floating point, so the result is max(d_xy, qz) itself.
    """
    d = np.abs(key)
    np.sqrt(d, out=d)
    return np.copysign(d, key, out=d)


def box_signed_distance(x: np.ndarray, y: np.ndarray, z: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                        cos: np.ndarray, sin: np.ndarray, hx: np.ndarray, hy: np.ndarray, zc: np.ndarray,
                        hz: np.ndarray) -> np.ndarray:
    """Signed point distances [m] to boxes (negative inside): `box_signed_sq_distance` (same arguments)
    through `signed_sqrt`."""
    return signed_sqrt(box_signed_sq_distance(x, y, z, cx, cy, cos, sin, hx, hy, zc, hz))


def box_signed_distance_one(x: float, y: float, z: float, box: tuple[float, ...]) -> float:
    """`box_signed_distance` for one point and one box in plain Python (same doubles).

    Args:
        x, y, z: the point, ENU metres.
        box: (cx, cy, cos, sin, hx, hy, zc, hz) as in `box_signed_sq_distance`.

    Returns:
        The signed distance [m], negative inside.
    """
    cx, cy, co, si, hx, hy, zc, hz = box
    dx = x - cx
    dy = y - cy
    # The same products and sums as box_frame_xy; if-expressions: a builtin call here costs more.
    qx = abs(dx * co + dy * si) - hx
    qy = abs(dy * co - dx * si) - hy
    qz = abs(z - zc) - hz
    if qx > 0.0 or qy > 0.0 or qz > 0.0:
        qx = qx if qx > 0.0 else 0.0
        qy = qy if qy > 0.0 else 0.0
        qz = qz if qz > 0.0 else 0.0
        return _sqrt(qx * qx + qy * qy + qz * qz)
    return max(qx, qy, qz)


def _box_keys(p: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Signed squared distances sign(d)*d^2 from points (n, 3) to every box: (n, B)."""
    return box_signed_sq_distance(p[:, 0:1], p[:, 1:2], p[:, 2:3], a.box_cx, a.box_cy, a.box_cos, a.box_sin,
                                  a.box_hx, a.box_hy, a.box_zc, a.box_hz)


def _prism_parts(p: np.ndarray, a: PackedPrisms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2D pieces for points (n, 3) against every convex prism.

    Returns:
        side (n, P, K): signed distance to each edge's line (positive = outside that edge);
        seg2 (n, P): squared distance to the footprint outline (meaningful when outside);
        qz (n, P): signed distance to the height range.
    """
    rel = p[:, None, None, 0:2] - a.prism_v0[None]  # (n, P, K, 2)
    side = np.einsum("npki,pki->npk", rel, a.prism_n)
    t = np.einsum("npki,pki->npk", rel, a.prism_e) * a.prism_inv_len2
    np.clip(t, 0.0, 1.0, out=t)
    off = rel - t[..., None] * a.prism_e
    seg2 = np.einsum("npki,npki->npk", off, off).min(axis=2)
    qz = np.abs(p[:, 2:3] - a.prism_zc) - a.prism_hz
    return side, seg2, qz


def _prism_keys(p: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Signed squared distances from points (n, 3) to every convex prism: (n, P)."""
    side, seg2, qz = _prism_parts(p, a)
    d2 = side.max(axis=2)  # <= 0 inside the footprint: minus the distance to the nearest edge line
    return vertical_prism_key(np.where(d2 > 0.0, seg2, 0.0), d2, qz)


def _keys(p: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Signed squared distances to every part, columns in part order: (n, n_parts)."""
    out = np.empty((len(p), a.n_parts))
    if len(a.box_part):
        out[:, a.box_part] = _box_keys(p, a)
    if len(a.prism_part):
        out[:, a.prism_part] = _prism_keys(p, a)
    return out


def surface_below(points: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Height of the surface directly below each point: the highest obstacle top at or below the point
    whose footprint holds the point's (x, y) (edges included), else the ground (0).

    Args:
        points: (N, 3) positions, ENU metres.
        a: packed obstacles (height ranges starting at the ground, as `BuildingMap` packs them).

    Returns:
        (N,) surface heights [m].
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.zeros(len(p))
    for s in range(0, len(p), _CHUNK):
        q = p[s:s + _CHUNK]
        if len(a.box_part):
            lx, ly = box_frame_xy(q[:, 0:1], q[:, 1:2], a.box_cx, a.box_cy, a.box_cos, a.box_sin)
            inside = (np.abs(lx) <= a.box_hx) & (np.abs(ly) <= a.box_hy)
            top = a.box_zc + a.box_hz
            under = inside & (top <= q[:, 2:3])
            out[s:s + len(q)] = np.max(np.where(under, top, 0.0), axis=1, initial=0.0)
        if len(a.prism_part):
            rel = q[:, None, None, 0:2] - a.prism_v0[None]
            inside = np.einsum("npki,pki->npk", rel, a.prism_n).max(axis=2) <= 0.0
            top = a.prism_zc + a.prism_hz
            under = inside & (top <= q[:, 2:3])
            out[s:s + len(q)] = np.maximum(out[s:s + len(q)], np.max(np.where(under, top, 0.0), axis=1, initial=0.0))
    return out


def part_distances(points: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Signed point distances from every point to every part.

    Args:
        points: (N, 3) positions, ENU metres.
        a: packed obstacles.

    Returns:
        (N, n_parts) signed distances [m], negative inside.
    """
    return signed_sqrt(_keys(np.asarray(points, dtype=float), a))


def nearest_parts(points: np.ndarray, a: PackedPrisms) -> tuple[np.ndarray, np.ndarray]:
    """The nearest part to each point and the signed distance to it.

    Args:
        points: (N, 3) positions, ENU metres.
        a: packed obstacles.

    Returns:
        distance (N,) [m] (+inf when there are no parts) and part index (N,) (-1 when none).
        Ties go to the lowest part index.
    """
    p_all = np.asarray(points, dtype=float)
    n = len(p_all)
    dist = np.full(n, np.inf)
    part = np.full(n, -1, dtype=np.int64)
    if a.n_parts == 0:
        return dist, part
    boxes_only = len(a.box_part) and not len(a.prism_part)
    reach = _box_reach(a) if boxes_only and len(a.box_part) > _PRUNE_FROM else None
    for i in range(0, n, _CHUNK):
        p = p_all[i:i + _CHUNK]
        rows = np.arange(len(p))
        if boxes_only:  # the common case: no column scatter needed
            near = None if reach is None else _boxes_within_reach(p, a, reach)
            if near is None:
                keys = _box_keys(p, a)
                j = np.argmin(keys, axis=1)
                part[i:i + _CHUNK] = a.box_part[j]
            else:
                keys = box_signed_sq_distance(p[:, 0:1], p[:, 1:2], p[:, 2:3], a.box_cx[near], a.box_cy[near],
                                              a.box_cos[near], a.box_sin[near], a.box_hx[near], a.box_hy[near],
                                              a.box_zc[near], a.box_hz[near])
                j = np.argmin(keys, axis=1)
                part[i:i + _CHUNK] = a.box_part[near[j]]
        else:
            keys = _keys(p, a)
            j = np.argmin(keys, axis=1)
            part[i:i + _CHUNK] = j
        dist[i:i + _CHUNK] = keys[rows, j]
    return signed_sqrt(dist), part


def _box_reach(a: PackedPrisms) -> np.ndarray:
    """Half extents (B, 3) [m] of each box's world-axis-aligned bounding box (about its centre cx, cy, zc)."""
    ac, asn = np.abs(a.box_cos), np.abs(a.box_sin)
    return np.column_stack([ac * a.box_hx + asn * a.box_hy, asn * a.box_hx + ac * a.box_hy, a.box_hz])


def _boxes_within_reach(p: np.ndarray, a: PackedPrisms, reach: np.ndarray) -> np.ndarray | None:
    """The boxes (ascending indices) that can be the nearest to some point of `p` (n, 3), or None when too many
    are to save work. A box whose bounding box is farther from the points' bounding box than some box's centre
    is from every point (an upper bound of each point's nearest distance: the centre lies in its box) is nobody's
    nearest, so leaving it out changes no result, ties included."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = np.column_stack([a.box_cx, a.box_cy, a.box_zc])
    gap = np.maximum(np.maximum(centre - reach - hi, lo - centre - reach), 0.0)
    lb2 = np.einsum("ij,ij->i", gap, gap)
    far = np.maximum(np.abs(centre - lo), np.abs(centre - hi))  # the points' bounding box's farthest corner
    ub2 = float(np.min(np.einsum("ij,ij->i", far, far)))
    near = np.flatnonzero(lb2 <= ub2)
    return near if len(near) < 0.5 * len(lb2) else None


def nearest_points_on_parts(points: np.ndarray, parts: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """The point of a given part's surface nearest to each point.

    Args:
        points: (N, 3) positions, ENU metres.
        parts: (N,) part index per point (every entry a valid part).
        a: packed obstacles.

    Returns:
        (N, 3) nearest surface points, ENU metres.  Inside a part, the point is projected onto the
        nearest face (ties go to x, then y, then z for boxes, and to the side over top/bottom).
    """
    p = np.asarray(points, dtype=float)
    parts = np.asarray(parts, dtype=np.int64)
    out = np.empty_like(p)
    box_row = np.full(a.n_parts, -1, dtype=np.int64)
    box_row[a.box_part] = np.arange(len(a.box_part))
    prism_row = np.full(a.n_parts, -1, dtype=np.int64)
    prism_row[a.prism_part] = np.arange(len(a.prism_part))
    rb = box_row[parts]
    sel = rb >= 0
    if np.any(sel):
        out[sel] = _nearest_on_boxes(p[sel], rb[sel], a)
    rp = prism_row[parts]
    sel = rp >= 0
    if np.any(sel):
        out[sel] = _nearest_on_prisms(p[sel], rp[sel], a)
    return out


def _nearest_on_boxes(p: np.ndarray, r: np.ndarray, a: PackedPrisms) -> np.ndarray:
    c, s = a.box_cos[r], a.box_sin[r]
    lx, ly = box_frame_xy(p[:, 0], p[:, 1], a.box_cx[r], a.box_cy[r], c, s)
    local = np.stack([lx, ly, p[:, 2] - a.box_zc[r]], axis=1)
    half = np.stack([a.box_hx[r], a.box_hy[r], a.box_hz[r]], axis=1)
    q = np.abs(local) - half
    inside = np.all(q <= 0.0, axis=1)
    near = np.clip(local, -half, half)
    face = np.argmax(q, axis=1)  # the nearest face of an inside point is the one with the largest q
    rows = np.nonzero(inside)[0]
    near[rows, face[rows]] = np.copysign(half[rows, face[rows]], local[rows, face[rows]])
    x = c * near[:, 0] - s * near[:, 1] + a.box_cx[r]
    y = s * near[:, 0] + c * near[:, 1] + a.box_cy[r]
    return np.stack([x, y, near[:, 2] + a.box_zc[r]], axis=1)


def _nearest_on_prisms(p: np.ndarray, r: np.ndarray, a: PackedPrisms) -> np.ndarray:
    v0, e, nrm, inv = a.prism_v0[r], a.prism_e[r], a.prism_n[r], a.prism_inv_len2[r]
    rel = p[:, None, 0:2] - v0  # (n, K, 2)
    side = np.einsum("nki,nki->nk", rel, nrm)
    t = np.clip(np.einsum("nki,nki->nk", rel, e) * inv, 0.0, 1.0)
    foot = v0 + t[..., None] * e
    k_seg = np.argmin(np.einsum("nki,nki->nk", p[:, None, 0:2] - foot, p[:, None, 0:2] - foot), axis=1)
    k_side = np.argmax(side, axis=1)
    rows = np.arange(len(p))
    d2 = side[rows, k_side]
    zc, hz = a.prism_zc[r], a.prism_hz[r]
    qz = np.abs(p[:, 2] - zc) - hz
    xy = np.where((d2 > 0.0)[:, None], foot[rows, k_seg], p[:, 0:2])
    z = np.clip(p[:, 2], zc - hz, zc + hz)
    inside = (d2 <= 0.0) & (qz <= 0.0)
    to_side = inside & (d2 >= qz)
    xy[to_side] = p[to_side, 0:2] - d2[to_side, None] * nrm[rows[to_side], k_side[to_side]]
    to_cap = inside & ~to_side
    z[to_cap] = zc[to_cap] + np.copysign(hz[to_cap], p[to_cap, 2] - zc[to_cap])
    return np.column_stack([xy, z])


def k_nearest_groups(points: np.ndarray, a: PackedPrisms, part_group: np.ndarray, groups: np.ndarray,
                     k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k nearest groups of parts (buildings) to each point.

    Args:
        points: (N, 3) positions, ENU metres.
        a: packed obstacles.
        part_group: (n_parts,) group (building id) of each part.
        groups: (G,) sorted distinct groups, G >= k.
        k: how many groups per point.

    Returns:
        nearest points (N, k, 3), signed point distances (N, k) [m], and indices into `groups`
        (N, k), sorted by distance; ties go to the lower group.
    """
    n = len(points)
    d_parts = part_distances(points, a)
    by_group = np.argsort(part_group, kind="stable")  # parts sorted by group, then index
    starts = np.searchsorted(part_group[by_group], groups)
    d_sorted = d_parts[:, by_group]
    d_g = np.minimum.reduceat(d_sorted, starts, axis=1)  # (n, G) best distance per group
    counts = np.diff(np.append(starts, len(by_group)))
    # The first part (in sorted order) that attains its group's best distance.
    rank = np.where(d_sorted == np.repeat(d_g, counts, axis=1), np.arange(len(by_group)), len(by_group))
    best_part = by_group[np.minimum.reduceat(rank, starts, axis=1)]
    order = np.argsort(d_g, axis=1, kind="stable")[:, :k]  # stable: ties go to the lower group
    rows = np.arange(n)[:, None]
    near = nearest_points_on_parts(np.repeat(points, k, axis=0), best_part[rows, order].reshape(-1), a)
    return near.reshape(n, k, 3), d_g[rows, order], order


def footprint_distance_2d(xy: np.ndarray, a: PackedPrisms) -> np.ndarray:
    """Unsigned 2D distance from points (V, 2) to every part's footprint (0 inside): (V, n_parts)."""
    p = np.column_stack([xy, np.zeros(len(xy))])
    out = np.empty((len(xy), a.n_parts))
    if len(a.box_part):
        lx, ly = box_frame_xy(p[:, 0:1], p[:, 1:2], a.box_cx, a.box_cy, a.box_cos, a.box_sin)
        out[:, a.box_part] = np.hypot(np.maximum(np.abs(lx) - a.box_hx, 0.0),
                                      np.maximum(np.abs(ly) - a.box_hy, 0.0))
    if len(a.prism_part):
        side, seg2, _ = _prism_parts(p, a)
        out[:, a.prism_part] = np.where(side.max(axis=2) > 0.0, np.sqrt(seg2), 0.0)
    return out


# A part for the per-point loop: its plain-Python distance function and the shape tuple it takes.
_Part = tuple[Callable[[float, float, float, tuple], float], tuple]
# One slab of a CellIndex column: its candidates' lower bounds [m] (ascending) and parts.
_Slab = tuple[list[float], list[_Part]]


class CellIndex:
    """Exact one-point signed distance through per-cell candidate lists (plain Python per query).

    The flight volume [x0, x1] x [y0, y1] x [0, z_top] is cut into square columns of side `cell_m`
    and horizontal slabs.  For a cell, every part gets a lower bound lb (no point of the cell is
    nearer) and an upper bound ub (no point of the cell is farther); the ground's upper bound is the
    slab top.  Only parts with lb <= min(all upper bounds) can be nearest, so each cell keeps those,
    sorted by lb, and a query stops at the first lb not below the best distance found so far.
    A column's lists (all its slabs) are built the first time it is queried, so cost follows use.

    Bounds used (all exact, no tolerance): 2D lb = max(gap between the cell and the footprint's
    axis-aligned box, min over the cell corners of the footprint distance minus the cell's half
    diagonal); 2D ub = max over the corners (distance to a convex set is convex, so its maximum over
    the cell is at a corner).  3D adds the vertical gap to the part's height range.
    """

    def __init__(self, a: PackedPrisms, footprints: list[np.ndarray], xy_min: np.ndarray,
                 xy_max: np.ndarray, z_top: float, cell_m: float) -> None:
        """Set up the grid; nothing is computed until the first query.

        Args:
            a: packed obstacles.
            footprints: per part, footprint vertices (K, 2), ENU metres (for the axis-aligned boxes).
            xy_min: (2,) grid corner [m].
            xy_max: (2,) opposite grid corner [m].
            z_top: top of the indexed slab stack [m]; points above it are not indexed.
            cell_m: horizontal cell size [m].
        """
        self._a = a
        self._x0, self._y0 = float(xy_min[0]), float(xy_min[1])
        self._cell = float(cell_m)
        self._inv = 1.0 / self._cell
        self._nx = max(1, math.ceil((float(xy_max[0]) - self._x0) * self._inv))
        self._ny = max(1, math.ceil((float(xy_max[1]) - self._y0) * self._inv))
        self._nz = max(1, math.ceil(z_top * self._inv))
        self._dz = z_top / self._nz
        self._inv_dz = 1.0 / self._dz
        self._z_top = z_top
        # Per column (ix, iy): the candidate lists of all its slabs, built together on first use.
        self._columns: list[list[_Slab] | None] = [None] * (self._nx * self._ny)
        self._z_bounds_sq: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        fp_lo = np.array([f.min(axis=0) for f in footprints]).reshape(-1, 2)
        fp_hi = np.array([f.max(axis=0) for f in footprints]).reshape(-1, 2)
        self._fp_lo, self._fp_hi = fp_lo, fp_hi
        z_lo = np.empty(a.n_parts)
        z_hi = np.empty(a.n_parts)
        z_lo[a.box_part], z_hi[a.box_part] = a.box_zc - a.box_hz, a.box_zc + a.box_hz
        z_lo[a.prism_part], z_hi[a.prism_part] = a.prism_zc - a.prism_hz, a.prism_zc + a.prism_hz
        self._part_z_lo, self._part_z_hi = z_lo, z_hi
        self._parts = _python_parts(a)

    def query(self, x: float, y: float, z: float) -> float | None:
        """Signed point distance to the nearest part or the ground (z = 0), or None if not indexed.

        Args:
            x, y, z: position, ENU metres.

        Returns:
            The distance [m] (negative inside a part or below ground), or None when the point is
            outside the grid or above its top (the caller then asks FCL).
        """
        ix = _floor((x - self._x0) * self._inv)
        iy = _floor((y - self._y0) * self._inv)
        iz = _floor(z * self._inv_dz)
        if iz < 0:
            iz = 0  # below ground: the ground wins anyway and slab 0's lower bounds still hold
        if not (0 <= ix < self._nx and 0 <= iy < self._ny and iz < self._nz):
            return None
        column = self._columns[iy * self._nx + ix]
        if column is None:
            column = self._columns[iy * self._nx + ix] = self._build_column(ix, iy)
        best = z
        for lb, (distance_fn, shape) in zip(*column[iz]):
            if lb >= best and lb > 0.0:  # (lb < best, the common case, is one comparison)
                break
            d = distance_fn(x, y, z, shape)
            if d < best:
                best = d
        return best

    def _vertical_bounds_sq(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared vertical gaps per (slab, part), lower and upper bound, and squared slab tops."""
        z_lo = (np.arange(self._nz) * self._dz)[:, None]
        z_hi = z_lo + self._dz
        lb_z = np.maximum(np.maximum(z_lo - self._part_z_hi, self._part_z_lo - z_hi), 0.0)
        ub_z = np.maximum(np.maximum(z_hi - self._part_z_hi, self._part_z_lo - z_lo), 0.0)
        return lb_z * lb_z, ub_z * ub_z, z_hi[:, 0] * z_hi[:, 0]

    def _build_column(self, ix: int, iy: int) -> list[_Slab]:
        """Candidate lists (lower bounds ascending, parts) for every slab of a column."""
        x0, y0 = self._x0 + ix * self._cell, self._y0 + iy * self._cell
        x1, y1 = x0 + self._cell, y0 + self._cell
        corners = footprint_distance_2d(np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]), self._a)
        gap_x = np.maximum(np.maximum(self._fp_lo[:, 0] - x1, x0 - self._fp_hi[:, 0]), 0.0)
        gap_y = np.maximum(np.maximum(self._fp_lo[:, 1] - y1, y0 - self._fp_hi[:, 1]), 0.0)
        lb2 = np.maximum(np.maximum(np.hypot(gap_x, gap_y), corners.min(axis=0) - self._cell * math.sqrt(0.5)), 0.0)
        ub2 = corners.max(axis=0)
        if self._z_bounds_sq is None:
            self._z_bounds_sq = self._vertical_bounds_sq()
        lb_z2, ub_z2, z_hi2 = self._z_bounds_sq
        lb_sq = lb2 * lb2 + lb_z2  # (nz, parts); squares avoid np.hypot, the slow part here
        ub_sq = ub2 * ub2 + ub_z2
        # The nearest obstacle is no farther than the ground (slab top) or any part's upper bound.
        limit_sq = np.minimum(z_hi2, ub_sq.min(axis=1)) if ub_sq.shape[1] else z_hi2
        slab, part = np.nonzero(lb_sq <= limit_sq[:, None])  # few per slab: filter before sorting
        lb_kept = np.sqrt(lb_sq[slab, part])
        order = np.lexsort((part, lb_kept, slab))  # by slab, then lower bound, then part index
        ends = np.searchsorted(slab[order], np.arange(1, self._nz + 1), side="left").tolist()
        lbs = lb_kept[order].tolist()
        parts = [self._parts[j] for j in part[order].tolist()]
        column = []
        start = 0
        for end in ends:
            column.append((lbs[start:end], parts[start:end]))
            start = end
        return column


def _python_parts(a: PackedPrisms) -> list[_Part]:
    """Per part, its plain-Python distance function and the plain tuple that function takes."""
    parts: list[_Part] = [(_prism_distance_py, ())] * a.n_parts
    for r, j in enumerate(a.box_part.tolist()):
        parts[j] = (box_signed_distance_one, (
            float(a.box_cx[r]), float(a.box_cy[r]), float(a.box_cos[r]), float(a.box_sin[r]),
            float(a.box_hx[r]), float(a.box_hy[r]), float(a.box_zc[r]), float(a.box_hz[r])))
    for r, j in enumerate(a.prism_part.tolist()):
        edges = tuple(
            (float(v[0]), float(v[1]), float(e[0]), float(e[1]), float(n[0]), float(n[1]), float(il))
            for v, e, n, il in zip(a.prism_v0[r], a.prism_e[r], a.prism_n[r], a.prism_inv_len2[r])
        )
        parts[j] = (_prism_distance_py, (edges, float(a.prism_zc[r]), float(a.prism_hz[r])))
    return parts


def _prism_distance_py(x: float, y: float, z: float, shape: tuple) -> float:
    """Signed distance from a point to one convex prism, plain Python (the arithmetic of
    `_prism_keys` and `vertical_prism_key`, same doubles); shape = (edges, zc, hz)."""
    edges, zc, hz = shape
    side = -math.inf
    seg2 = math.inf
    for vx, vy, ex, ey, nx, ny, inv in edges:
        rx, ry = x - vx, y - vy
        s = rx * nx + ry * ny
        if s > side:
            side = s
        t = (rx * ex + ry * ey) * inv
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        ox, oy = rx - t * ex, ry - t * ey
        o2 = ox * ox + oy * oy
        if o2 < seg2:
            seg2 = o2
    qz = abs(z - zc) - hz
    if side <= 0.0 and qz <= 0.0:
        return max(side, qz)
    out2 = (seg2 if side > 0.0 else 0.0) + (qz * qz if qz > 0.0 else 0.0)
    return math.sqrt(out2)
