"""Perception (rl.sensing.perception): rays against brute force and closed forms, the height map's bounds,
the heading frame, and batched == single."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rl.sensing.perception import Perception, PerceptionConfig
from rl.task.cities import CityDistribution
from uam_fdm.city.buildings import Building, BuildingMap

R = 0.42  # collision radius [m]
CFG = PerceptionConfig()


@pytest.fixture(scope="module")
def cities() -> list[BuildingMap]:
    return [CityDistribution().city(s) for s in (3, 4, 7)]


@pytest.fixture(scope="module")
def perception(cities) -> Perception:
    return Perception(cities, R, CFG)


# ------------------------------------------------------------------------------- references

def ray_reference(city: BuildingMap, p, heading: float, j: int, n_rays: int, r: float,
                  range_m: float) -> float:
    """Entry distance of ray j into the nearest inflated footprint, one building at a time (plain Python)."""
    ang = heading + 2.0 * math.pi * j / n_rays
    d = (math.cos(ang), math.sin(ang))
    best = range_m
    for b in city.buildings:
        if b.height_m + r <= p[2]:
            continue
        co, si = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
        ox, oy = p[0] - b.center_xy_m[0], p[1] - b.center_xy_m[1]
        o = (ox * co + oy * si, oy * co - ox * si)
        u = (d[0] * co + d[1] * si, d[1] * co - d[0] * si)
        h = (0.5 * b.size_xy_m[0] + r, 0.5 * b.size_xy_m[1] + r)
        t_in, t_out, parallel_miss = -math.inf, math.inf, False
        for a in range(2):
            if u[a] == 0.0:
                parallel_miss |= abs(o[a]) > h[a]
                continue
            t1, t2 = (-h[a] - o[a]) / u[a], (h[a] - o[a]) / u[a]
            t_in, t_out = max(t_in, min(t1, t2)), min(t_out, max(t1, t2))
        if not parallel_miss and t_in <= t_out and t_out >= 0.0:
            best = min(best, max(t_in, 0.0))
    return best


def ray_march(city: BuildingMap, p, heading: float, r: float, range_m: float, step_m: float = 1e-3) -> float:
    """First sample at `step_m` spacing along the ray inside an inflated footprint (range if none)."""
    t = np.arange(0.0, range_m + step_m, step_m)
    x, y = p[0] + t * math.cos(heading), p[1] + t * math.sin(heading)
    inside = np.zeros(len(t), dtype=bool)
    for b in city.buildings:
        if b.height_m + r > p[2]:
            inside |= in_footprint(b, x, y, r)
    return float(t[np.argmax(inside)]) if inside.any() else range_m


def in_footprint(b: Building, x, y, grow: float = 0.0):
    """Whether points (x, y) lie in b's footprint grown by `grow` on each side (closed)."""
    co, si = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
    dx, dy = x - b.center_xy_m[0], y - b.center_xy_m[1]
    return ((np.abs(dx * co + dy * si) <= 0.5 * b.size_xy_m[0] + grow)
            & (np.abs(dy * co - dx * si) <= 0.5 * b.size_xy_m[1] + grow))


def rect_params(b: Building):
    """(cx, cy, cos, sin, hx, hy) of b's footprint."""
    hx, hy = 0.5 * b.size_xy_m[0], 0.5 * b.size_xy_m[1]
    return (*b.center_xy_m, math.cos(b.yaw_rad), math.sin(b.yaw_rad), hx, hy)


def rect_distance(a, b):
    """Distance between rectangles a, b = (cx, cy, cos, sin, hx, hy) (arrays broadcast; 0 on overlap)."""
    def corners(q):
        cx, cy, co, si, hx, hy = q
        return [(cx + ex * hx * co - ey * hy * si, cy + ex * hx * si + ey * hy * co)
                for ex, ey in ((-1, -1), (1, -1), (1, 1), (-1, 1))]

    def point_dist(px, py, q):
        cx, cy, co, si, hx, hy = q
        dx, dy = px - cx, py - cy
        return np.hypot(np.maximum(np.abs(dx * co + dy * si) - hx, 0.0),
                        np.maximum(np.abs(dy * co - dx * si) - hy, 0.0))

    def radius(q, ux, uy):  # half-length of q's projection on the unit axis u
        _, _, co, si, hx, hy = q
        return hx * np.abs(co * ux + si * uy) + hy * np.abs(-si * ux + co * uy)

    dx, dy = b[0] - a[0], b[1] - a[1]
    overlap = True
    for ux, uy in ((a[2], a[3]), (-a[3], a[2]), (b[2], b[3]), (-b[3], b[2])):
        overlap = overlap & (np.abs(dx * ux + dy * uy) <= radius(a, ux, uy) + radius(b, ux, uy))
    d = np.minimum(np.min([point_dist(x, y, b) for x, y in corners(a)], axis=0),
                   np.min([point_dist(x, y, a) for x, y in corners(b)], axis=0))
    return np.where(overlap, 0.0, d)


def cell_centres(p, heading: float, cfg: PerceptionConfig) -> np.ndarray:
    """World centres (g*g, 2) of the height-map cells of a point, in the reading's order (a slow)."""
    c, s = math.cos(heading), math.sin(heading)
    o = (np.arange(cfg.grid_cells) - cfg.grid_cells // 2) * cfg.cell_m
    a, b = np.meshgrid(o, o, indexing="ij")
    return np.stack([p[0] + a * c - b * s, p[1] + a * s + b * c], axis=-1).reshape(-1, 2)


def random_queries(city: BuildingMap, n: int, rng, outside_m: float = 0.0, z=(0.5, 80.0)):
    lo, hi = np.asarray(city.bounds_min_m), np.asarray(city.bounds_max_m)
    pts = rng.uniform([lo[0] - outside_m, lo[1] - outside_m, z[0]],
                      [hi[0] + outside_m, hi[1] + outside_m, z[1]], size=(n, 3))
    return pts, rng.uniform(-math.pi, math.pi, n)


def near_wall_points(city: BuildingMap, n: int, rng):
    """Points just inside / outside inflated footprints (1e-7..0.3 m across a face), below the roof."""
    out = []
    for _ in range(n):
        b = city.buildings[int(rng.integers(len(city.buildings)))]
        cx, cy, co, si, hx, hy = rect_params(b)
        side = int(rng.integers(4))
        off = float(rng.choice([-1, 1])) * 10.0 ** rng.uniform(-7, -0.5)
        along = rng.uniform(-1, 1)
        lx, ly = ((hx + R + off, along * hy) if side == 0 else (-(hx + R + off), along * hy) if side == 1
                  else (along * hx, hy + R + off) if side == 2 else (along * hx, -(hy + R + off)))
        out.append((cx + lx * co - ly * si, cy + lx * si + ly * co, rng.uniform(0.5, b.height_m)))
    return np.array(out)


def long_shots(city: BuildingMap, n: int, rng):
    """Points 30-40 m out from a random point of an inflated footprint, facing back at it, below the roof."""
    pts, hd = [], []
    for _ in range(n):
        b = city.buildings[int(rng.integers(len(city.buildings)))]
        cx, cy, co, si, hx, hy = rect_params(b)
        lx, ly = rng.uniform(-1, 1) * (hx + R), rng.uniform(-1, 1) * (hy + R)
        phi, dist = rng.uniform(-math.pi, math.pi), rng.uniform(30.0, 40.5)
        pts.append((cx + lx * co - ly * si + dist * math.cos(phi),
                    cy + lx * si + ly * co + dist * math.sin(phi), rng.uniform(0.5, b.height_m)))
        hd.append(phi + math.pi)
    return np.array(pts), np.array(hd)


def outside_points(city: BuildingMap, n: int, rng):
    """Points outside the bounds (up to 35 m, corners included) within 35 m of a footprint, below 30 m."""
    lo, hi = np.asarray(city.bounds_min_m), np.asarray(city.bounds_max_m)
    xy = rng.uniform(lo[:2] - 35.0, hi[:2] + 35.0, size=(20000, 2))
    xy = xy[((xy < lo[:2]) | (xy > hi[:2])).any(axis=1)]
    rects = [np.array(v)[:, None] for v in zip(*[rect_params(b) for b in city.buildings])]
    d = rect_distance((xy[None, :, 0], xy[None, :, 1], 1.0, 0.0, 0.0, 0.0), rects).min(axis=0)
    xy = xy[d < 35.0][:n]
    assert len(xy) == n
    pts = np.column_stack([xy, rng.uniform(0.5, 30.0, n)])
    return pts, rng.uniform(-math.pi, math.pi, n)


# ------------------------------------------------------------------------------------- rays

def test_rays_match_brute_force(cities, perception):
    rng = np.random.default_rng(0)
    hits = zeros = 0
    for ci, city in enumerate(cities):
        spread, hd1 = random_queries(city, 60, rng, outside_m=40.0)
        walls = near_wall_points(city, 60, rng)
        far_out, hd3 = outside_points(city, 30, rng)
        far_shots, hd4 = long_shots(city, 60, rng)
        spread, hd1 = np.concatenate([spread, far_shots]), np.concatenate([hd1, hd4])
        # above low roofs: right over a building, just above and just below roof + r
        blds = sorted(city.buildings, key=lambda b: b.height_m)[:20]
        over = np.array([(*b.center_xy_m, b.height_m + R + (0.01 if k % 2 else -0.01))
                         for k, b in enumerate(blds)])
        pts = np.concatenate([spread, walls, far_out, over])
        hd = np.concatenate([hd1, rng.uniform(-math.pi, math.pi, len(walls)), hd3,
                             rng.uniform(-math.pi, math.pi, len(over))])
        got = perception.observe(pts, hd, np.full(len(pts), ci)).ray_m
        assert got.shape == (len(pts), CFG.n_rays) and got.dtype == np.float64
        ref = np.array([[ray_reference(city, p, h, j, CFG.n_rays, R, CFG.ray_range_m)
                         for j in range(CFG.n_rays)] for p, h in zip(pts, hd)])
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
        hits += int((ref < CFG.ray_range_m).sum())
        zeros += int((ref == 0).all(axis=1).sum())
        # points just above roof + r see past their own building; just below, they are inside it
        above = got[len(pts) - len(over):]
        assert np.all(above[1::2] > 0) and np.all(above[0::2] == 0)
        # far outside the bounds, some rays still reach the city
        assert (got[len(spread) + len(walls):len(spread) + len(walls) + len(far_out)] < CFG.ray_range_m).any()
    assert hits > 1000 and zeros > 20  # the sample does exercise hits and inside points


def test_reference_agrees_with_a_fine_ray_march(cities, perception):
    city, rng = cities[0], np.random.default_rng(1)
    pts, hd = random_queries(city, 200, rng, z=(0.5, 15.0))
    got = perception.observe(pts, hd, np.zeros(len(pts), dtype=int)).ray_m[:, 0]
    pick = np.flatnonzero((got > 0) & (got < CFG.ray_range_m))[:8]
    assert len(pick) >= 5
    for i in pick:
        t = ray_march(city, pts[i], hd[i], R, CFG.ray_range_m)
        assert got[i] <= t <= got[i] + 1.001e-3


def test_points_inside_inflated_footprints_read_zero(cities, perception):
    rng = np.random.default_rng(2)
    for ci, city in enumerate(cities):
        pts = []
        for b in city.buildings:
            cx, cy, co, si, hx, hy = rect_params(b)
            lx, ly = rng.uniform(-1, 1) * (hx + R), rng.uniform(-1, 1) * (hy + R)
            pts.append((cx + lx * co - ly * si, cy + lx * si + ly * co, rng.uniform(0.1, b.height_m + R)))
        pts = np.array(pts)
        ray = perception.observe(pts, rng.uniform(-4, 4, len(pts)), np.full(len(pts), ci)).ray_m
        assert np.all(ray == 0.0)


def one_box_city(yaw: float = 0.0) -> BuildingMap:
    return BuildingMap([Building(0, (50.0, 50.0), (10.0, 20.0), 30.0, yaw)], (0, 0, 0), (100, 100, 120))


def test_one_box_closed_form_and_frame():
    r, n = 0.5, 16
    per = Perception([one_box_city()], r, PerceptionConfig(n_rays=n, ray_range_m=40.0))
    # box x in [45, 55], y in [40, 60]; inflated by 0.5. Point 10 m west of its west face, facing east.
    ray = per.observe(np.array([[35.0, 50.0, 10.0]]), np.array([0.0]), np.array([0])).ray_m[0]
    face = 45.0 - 35.0 - r
    expect = np.full(n, 40.0)
    for j in (-2, -1, 0, 1, 2):  # up to +-45 deg the rays reach the west face
        expect[j % n] = face / math.cos(2 * math.pi * j / n)
    np.testing.assert_allclose(ray, expect, rtol=0, atol=1e-12)
    assert ray[0] == pytest.approx(9.5, abs=1e-12)
    # heading +90 deg: ray 0 points north. South of the box, 14.5 m from the inflated south face.
    ray = per.observe(np.array([[50.0, 25.0, 10.0]]), np.array([math.pi / 2]), np.array([0])).ray_m[0]
    assert ray[0] == pytest.approx(40.0 - 25.0 - r, abs=1e-12)
    assert ray[n // 2] == 40.0
    # east of the box facing north: ray n/4 points to the left (west) and meets the east face
    ray = per.observe(np.array([[65.0, 50.0, 10.0]]), np.array([math.pi / 2]), np.array([0])).ray_m[0]
    assert ray[n // 4] == pytest.approx(65.0 - 55.0 - r, abs=1e-12)
    assert ray[0] == 40.0 and ray[3 * n // 4] == 40.0
    # the roof: counted while z < height + r
    pts = np.array([[35.0, 50.0, 30.49], [35.0, 50.0, 30.51]])
    ray = per.observe(pts, np.zeros(2), np.zeros(2, dtype=int)).ray_m
    assert ray[0, 0] == pytest.approx(9.5) and np.all(ray[1] == 40.0)
    # beyond the range, and from inside (inflated) footprint
    pts = np.array([[2.0, 50.0, 10.0], [44.6, 50.0, 10.0]])
    ray = per.observe(pts, np.zeros(2), np.zeros(2, dtype=int)).ray_m
    assert np.all(ray[0] == 40.0) and np.all(ray[1] == 0.0)


def test_rotated_box_in_its_own_frame():
    yaw, r = math.radians(30.0), 0.5
    per = Perception([one_box_city(yaw)], r, PerceptionConfig(n_rays=8))
    c, s = math.cos(yaw), math.sin(yaw)
    # 15 m from the centre along the box's -x axis, facing the box; 12 m along its -y axis, facing it
    p = np.array([[50.0 - 15.0 * c, 50.0 - 15.0 * s, 5.0], [50.0 + 12.0 * s, 50.0 - 12.0 * c, 5.0]])
    ray = per.observe(p, np.array([yaw, yaw + math.pi / 2]), np.zeros(2, dtype=int)).ray_m
    assert ray[0, 0] == pytest.approx(15.0 - 5.0 - r, abs=1e-12)
    assert ray[1, 0] == pytest.approx(12.0 - 10.0 - r, abs=1e-12)
    assert ray[0, 4] == 40.0  # behind


def test_candidate_grid_covers_every_reachable_building(cities, perception):
    """White box: the rays' grid spans the bounds widened by r*sqrt(2) (so every inflated footprint), and
    each grid cell lists every building whose inflated footprint is within the ray range of the cell."""
    per, g = perception, perception.ray_cell_m
    for ci, city in enumerate(cities):
        org, dims = per._g_origin[ci], per._g_dims[ci]
        assert np.all(org <= np.asarray(city.bounds_min_m[:2]) - R * math.sqrt(2))
        assert np.all(org + g * dims >= np.asarray(city.bounds_max_m[:2]) + R * math.sqrt(2))
        ix, iy = np.meshgrid(np.arange(dims[0]), np.arange(dims[1]))
        centres = org + g * (np.column_stack([ix.ravel(), iy.ravel()]) + 0.5)  # row-major, x fastest
        cells = (centres[None, :, 0], centres[None, :, 1], 1.0, 0.0, 0.5 * g, 0.5 * g)
        rects = [np.array(v)[:, None] for v in zip(*[rect_params(b) for b in city.buildings])]
        rects[4], rects[5] = rects[4] + R, rects[5] + R
        need = rect_distance(cells, rects) <= CFG.ray_range_m  # (B, cells)
        row0 = per._row0[ci]
        for k in range(len(centres)):
            cell = per._g_cell0[ci] + k
            listed = per._cand[per._cell_start[cell]:per._cell_start[cell + 1]] - row0
            assert set(np.flatnonzero(need[:, k])) <= set(listed.tolist())


# ------------------------------------------------------------------------------- height map

def test_tall_box_ahead_and_inside_cells():
    edge = [Building(1, (5.0, 90.0), (10.0, 20.0), 50.0), Building(2, (115.0, 90.0), (10.0, 20.0), 50.0)]
    city = BuildingMap([Building(0, (60.0, 50.0), (12.0, 12.0), 80.0)] + edge, (0, 0, 0), (120, 100, 120))
    per = Perception([city], R)
    g, c = CFG.grid_cells, CFG.grid_cells // 2
    p = np.array([[35.0, 50.0, 10.0]])
    ahead = per.observe(p, np.array([0.0]), np.array([0])).roof_m.reshape(g, g)
    assert ahead[c + 1:].max() == 80.0 and ahead[: c + 1].max() == 0.0  # only cells ahead (a > c)
    # footprint x in [54, 66], y in [44, 56]: cell a = c + 4 (x in [56, 62]), b = c (y in [47, 53]) is inside
    assert ahead[c + 4, c] == 80.0
    assert ahead[c + 4, c - 2] == 0.0 and ahead[c + 4, c + 2] == 0.0  # y in [35, 41] and [59, 65]: open
    # turned around, the box is behind; turned left (+90 deg), it is on the right (b < c)
    behind = per.observe(p, np.array([math.pi]), np.array([0])).roof_m.reshape(g, g)
    assert behind[:c].max() == 80.0 and behind[c:].max() == 0.0
    left = per.observe(p, np.array([math.pi / 2]), np.array([0])).roof_m.reshape(g, g)
    assert left[:, :c].max() == 80.0 and left[:, c:].max() == 0.0
    assert left[c, c - 4] == 80.0  # 25 m to the right: y' in [-27, -21], x' in [-3, 3]
    # far outside the bounds: open ground
    # outside the bounds: open ground beyond the edge buildings (on the bounds), and far away
    out = np.array([[-60.0, 90.0, 10.0], [-40.0, 120.0, 10.0], [180.0, 90.0, 10.0], [160.0, 130.0, 10.0],
                    [60.0, -60.0, 10.0], [1e4, -1e4, 10.0]])
    far = per.observe(out, np.array([0.0, 0.3, 0.0, 2.0, 1.0, 0.0]), np.zeros(len(out), dtype=int)).roof_m
    assert np.all(far == 0.0)
    pts = np.array([[-10.0, 90.0, 10.0], [125.0, 90.0, 10.0]])
    near = per.observe(pts, np.zeros(2), np.zeros(2, dtype=int))
    assert near.roof_m[0].reshape(g, g)[c + 2, c] == 50.0 and near.roof_m[1].reshape(g, g)[c - 2, c] == 50.0


def test_height_map_sees_slivers():
    """A box poking 1 mm - 5 cm into a cell (corner or edge first, any heading) raises that cell."""
    rng = np.random.default_rng(5)
    g, half = CFG.grid_cells, 0.5 * CFG.cell_m
    cities, pts, hd, target, height = [], [], [], [], []
    for k in range(60):
        # every 4th: axis-aligned heading from a whole-metre point (cell edges on raster lines)
        theta = (rng.choice([0.0, 0.5, 1.0, -0.5]) * math.pi if k % 4 == 0 else
                 rng.choice([0.25, 0.75, -0.25, -0.75]) * math.pi if k % 4 == 1 else
                 rng.uniform(-math.pi, math.pi))
        p = np.array([100.0, 100.0, 10.0]) + (0.0 if k % 4 == 0 else rng.uniform(-1, 1, 3))
        a, b = (int(v) for v in rng.integers(0, g, 2))
        ctr = cell_centres(p, theta, CFG)[a * g + b]
        ux, uy = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta), math.cos(theta)])
        # a point of the square 1 mm - 5 cm from its boundary, and a box with that corner, lying outwards
        dep = 10.0 ** rng.uniform(-3, math.log10(0.05))
        su, sv = rng.choice([-1, 1], 2)
        along = half - dep if k % 2 else rng.uniform(-half, half)
        q = ctr + su * (half - dep) * ux + sv * along * uy
        yaw = rng.uniform(-math.pi, math.pi)
        bu, bv = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
        size = rng.uniform(0.5, 8.0, 2)
        out = q - ctr
        centre = q + 0.5 * size[0] * bu * np.sign(out @ bu) + 0.5 * size[1] * bv * np.sign(out @ bv)
        h = float(rng.integers(3, 150))
        box = Building(0, tuple(centre), tuple(size), h, yaw)
        cities.append(BuildingMap([box], (0, 0, 0), (200, 200, 120)))
        pts.append(p), hd.append(theta), target.append(a * g + b), height.append(h)
    per = Perception(cities, R)
    roof = per.observe(np.array(pts), np.array(hd), np.arange(len(cities))).roof_m
    assert np.all(roof[np.arange(len(cities)), target] == height)


@pytest.mark.parametrize("cfg", [CFG, PerceptionConfig(n_rays=7, grid_cells=5, cell_m=4.5, raster_m=0.75),
                                 PerceptionConfig(grid_cells=7, cell_m=1.0, raster_m=1.0)],
                         ids=["default", "coarse", "fine"])
def test_height_map_bounds(cities, cfg):
    """Never below the highest roof over the cell (dense samples), never above the tallest building
    within half a cell diagonal + raster_m of the cell, nor above the tallest one reaching the cell's
    world-axis bounding box widened by raster_m (the documented bound); cells inside one footprint
    with nothing else near read its height (rounded up)."""
    per = Perception(cities, R, cfg)
    rng = np.random.default_rng(3)
    g, half = cfg.grid_cells, 0.5 * cfg.cell_m
    u = np.linspace(-half, half, 13)
    su, sv = [a.ravel() for a in np.meshgrid(u, u, indexing="ij")]
    su = np.concatenate([su, rng.uniform(-half, half, 200)])
    sv = np.concatenate([sv, rng.uniform(-half, half, 200)])
    n_inside = 0
    for ci, city in enumerate(cities):
        pts, hd = random_queries(city, 24, rng, outside_m=30.0)
        hd[:4] = [0.0, math.pi / 2, math.pi / 4, -math.pi]  # aligned and diagonal headings too
        roof = per.observe(pts, hd, np.full(len(pts), ci)).roof_m
        assert roof.shape == (len(pts), g * g)
        heights = np.array([b.height_m for b in city.buildings])
        rects = [np.array(v)[:, None] for v in zip(*[rect_params(b) for b in city.buildings])]  # (B, 1)
        for i, (p, h) in enumerate(zip(pts, hd)):
            centres = cell_centres(p, h, cfg)  # (G, 2)
            co, si = math.cos(h), math.sin(h)
            # dense samples of each cell (G, S): highest roof containing one
            sx = centres[:, 0:1] + su * co - sv * si
            sy = centres[:, 1:2] + su * si + sv * co
            low = np.zeros(len(centres))
            for b in city.buildings:
                low = np.maximum(low, np.where(in_footprint(b, sx, sy).any(axis=1), b.height_m, 0.0))
            assert np.all(roof[i] >= low), (ci, i)
            # squares (1, G) against footprints (B, 1)
            sq = (centres[None, :, 0], centres[None, :, 1], co, si, half, half)
            near = rect_distance(sq, rects) <= half * math.sqrt(2) + cfg.raster_m
            top = np.ceil(np.max(np.where(near, heights[:, None], 0.0), axis=0))
            assert np.all(roof[i] <= top), (ci, i)
            e = half * (abs(co) + abs(si)) + cfg.raster_m + 1e-5
            box = (centres[None, :, 0], centres[None, :, 1], 1.0, 0.0, e, e)
            touching = rect_distance(box, rects) <= 0.0
            tight = np.ceil(np.max(np.where(touching, heights[:, None], 0.0), axis=0))
            assert np.all(roof[i] <= tight), (ci, i)
            # a cell inside one footprint, with no other building reaching its box, reads that height
            only = (touching.sum(axis=0) == 1) & (low > 0)
            n_inside += int(only.sum())
            assert np.all(roof[i][only] == np.ceil(low[only]))
    assert n_inside > 20


def test_raster_is_compact(cities, perception):
    assert perception._table.dtype == np.uint8
    per_city = perception.nbytes / len(cities)
    assert per_city < 200e6 / 1000  # 1000 cities well under 200 MB


# ------------------------------------------------------------------------------ batch, config

def test_batched_equals_single_calls(cities, perception):
    rng = np.random.default_rng(4)
    pts, hd, ci = [], [], []
    for c, city in enumerate(cities):
        p, h = random_queries(city, 40, rng, outside_m=50.0)
        pts.append(np.concatenate([p, near_wall_points(city, 10, rng)]))
        hd.append(np.concatenate([h, rng.uniform(-10, 10, 10)]))
        ci.append(np.full(50, c))
    order = rng.permutation(150)
    pts, hd, ci = np.concatenate(pts)[order], np.concatenate(hd)[order], np.concatenate(ci)[order]
    batch = perception.observe(pts, hd, ci)
    for k in range(len(pts)):
        one = perception.observe(pts[k:k + 1], hd[k:k + 1], ci[k:k + 1])
        assert np.array_equal(one.ray_m[0], batch.ray_m[k]) and np.array_equal(one.roof_m[0], batch.roof_m[k])
    sub = perception.observe(pts[:7], hd[:7], ci[:7])
    assert np.array_equal(sub.ray_m, batch.ray_m[:7]) and np.array_equal(sub.roof_m, batch.roof_m[:7])
    empty = perception.observe(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=int))
    assert empty.ray_m.shape == (0, CFG.n_rays) and empty.roof_m.shape == (0, CFG.grid_cells ** 2)


def test_bad_config_rejected():
    with pytest.raises(ValueError, match="grid_cells"):
        PerceptionConfig(grid_cells=8)
    with pytest.raises(ValueError, match="n_rays"):
        PerceptionConfig(n_rays=0)
    with pytest.raises(ValueError, match="raster_m"):
        PerceptionConfig(raster_m=0.0)
    with pytest.raises(ValueError, match="radius"):
        Perception([], -1.0)


def test_free_distance_is_a_ray_at_any_bearing(cities, perception):
    """`free_distance` along an arbitrary bearing = the reference ray (j = 0 of that heading), batched and single."""
    rng = np.random.default_rng(11)
    ci = rng.integers(0, len(cities), 60)
    pts = np.array([[*rng.uniform(cities[c].bounds_min_m[:2], cities[c].bounds_max_m[:2]), rng.uniform(1.0, 30.0)]
                    for c in ci])
    bearing = rng.uniform(-math.pi, math.pi, 60)
    got = perception.free_distance(pts, bearing, ci)
    ref = [ray_reference(cities[c], p, b, 0, 1, R, CFG.ray_range_m) for c, p, b in zip(ci, pts, bearing)]
    assert got == pytest.approx(ref, abs=1e-9)
    assert 0 < (got < CFG.ray_range_m).sum() < len(got)  # hits and misses both exercised
    one = [perception.free_distance(pts[k:k + 1], bearing[k:k + 1], ci[k:k + 1])[0] for k in range(5)]
    assert one == pytest.approx(got[:5], abs=1e-12)
    # the configured rays are untouched: ray 0 of a heading is the free distance along it
    assert perception.rays(pts, bearing, ci)[:, 0] == pytest.approx(got, abs=1e-12)
