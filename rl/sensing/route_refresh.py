"""The learned pilot's route redrawn around what its lidar sensed: the prior map's route field is only as good as the
map, and a building the map lacks would keep the route (distance to go and direction) pointing through it.

Every `RouteConfig.refresh_s` of flight (a whole number of decisions, counted from the episode's first) a slot's
height memory (`rl.sensing.lidar_view.LidarView.columns`: the highest non-ground return per memory cell around the
estimate) is read as columns standing on the ground. The route is redrawn when a column is news: it stands where
the slot's current route is open (its cell's centre falls in a route-grid cell not blocked at a flight level its
height blocks), it is higher than the ground band lifted by how far a return at its range may be misplaced
(`PLACEMENT_ERROR`), the prior does not explain it (its top is farther than a memory cell and a half-diagonal, plus
that misplacement, from every obstacle of the prior) and it was not drawn before. The new route is drawn on the prior
map plus every column sensed so far this episode (kept after it leaves the memory's window, the highest return per
cell); otherwise the route is kept. A column is a memory cell's square, so a sensed wall blocks up to a memory cell
beyond it, and the route's usual inflation (radius + margin) is added around it.

The env's slots and the runner's pilot use this one class on the same memories, so their routes are the same bit
for bit. Cost: a check is a few vector operations on the window; a redraw is `route_for` on the prior plus the
columns (about 2-5 ms for the small quad). Frames: world ENU metres.
"""
from __future__ import annotations

import numpy as np

from rl.sensing.lidar_view import LidarView
from rl.sensing.route import LeveledRoute, RouteConfig
from rl.sensing.senses import route_for
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Task

_KEY = 1 << 32  # a cell's key: ix * _KEY + iy (|ix|, |iy| < 2**31 cells)
PLACEMENT_ERROR = 0.05
"""How far a return may be misplaced per metre of its horizontal range [m/m] (tan 3 degrees): a scan is placed on
the estimate at its decision, and between the scan and the decision the vehicle turns (measured on the small quad
flying its policy at 20-40 degrees of tilt: attitude errors of 0.5-1.3 degrees at the decision, and returns from the
ground lifted up to 2.4 m at 30-50 m), on top of the estimate's attitude error."""


def refresh_decisions(config: RouteConfig, decision_hz: float) -> int:
    """Decisions between route checks (0: never), `config.refresh_s` at `decision_hz` [Hz].

    Raises:
        ValueError: a period that is not a whole number of decisions.
    """
    if config.refresh_s == 0.0:
        return 0
    k = config.refresh_s * decision_hz
    if abs(k - round(k)) > 1e-9 or round(k) < 1:
        raise ValueError(f"route.refresh_s {config.refresh_s:g} s is not a whole number of decisions at "
                         f"{decision_hz:g} Hz")
    return int(round(k))


class RouteRefresh:
    """The routes of N slots, each redrawn around its sensed columns (see the module docstring).

    Args:
        n: slots.
        config: the route's settings (`refresh_s` the checks' period; the grid and inflation as drawn).
        decision_hz: decisions per second [Hz].
        radius_m: the vehicle's collision radius [m].

    Raises:
        ValueError: `config.refresh_s` is 0 or not a whole number of decisions.
    """

    def __init__(self, n: int, config: RouteConfig, decision_hz: float, radius_m: float) -> None:
        self.every = refresh_decisions(config, decision_hz)
        if self.every == 0:
            raise ValueError("route.refresh_s is 0: the route is never redrawn")
        self.config, self.radius_m = config, float(radius_m)
        self.decisions = np.zeros(int(n), dtype=np.int64)  # decisions taken this episode, per slot
        self.redraws = np.zeros(int(n), dtype=np.int64)  # routes redrawn this episode, per slot
        self._prior: list[BuildingMap | None] = [None] * int(n)
        self._task: list[Task | None] = [None] * int(n)
        self._route: list[LeveledRoute | None] = [None] * int(n)
        self._keys: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * int(n)
        self._heights: list[np.ndarray] = [np.zeros(0)] * int(n)

    def start(self, slot: int, prior: BuildingMap, task: Task, route: LeveledRoute) -> None:
        """Slot `slot`'s new episode: its prior map, its task and the route drawn on the prior."""
        self._prior[slot], self._task[slot], self._route[slot] = prior, task, route
        self._keys[slot], self._heights[slot] = np.zeros(0, dtype=np.int64), np.zeros(0)
        self.decisions[slot] = 0
        self.redraws[slot] = 0

    def decide(self, slots: np.ndarray, view: LidarView, view_slots: np.ndarray, position_m: np.ndarray,
               position_sigma_m: np.ndarray) -> list[tuple[int, LeveledRoute]]:
        """One decision of `slots` (M,) (their scans already in `view`, slot k as `view_slots[k]`) at estimated
        positions (M, 3) [m, world ENU] with position sigmas (M,) [m]: the routes redrawn at it, as (slot, route)
        pairs (the caller stores them; `route_of` gives them too)."""
        out = []
        p, sigma = np.asarray(position_m, dtype=float).reshape(-1, 3), np.asarray(position_sigma_m).reshape(-1)
        for k, (slot, at) in enumerate(zip(np.asarray(slots).tolist(), np.asarray(view_slots).tolist())):
            j = int(self.decisions[slot])
            self.decisions[slot] = j + 1
            if j == 0 or j % self.every:
                continue
            route = self._check(slot, view, at, p[k], float(sigma[k]))
            if route is not None:
                out.append((slot, route))
        return out

    def route_of(self, slot: int) -> LeveledRoute:
        """Slot `slot`'s route now."""
        route = self._route[slot]
        assert route is not None, "a slot has a route once started"
        return route

    def _check(self, slot: int, view: LidarView, at: int, p: np.ndarray, sigma: float) -> LeveledRoute | None:
        """Redraw slot `slot`'s route when a column of its memory (view slot `at`) stands where it is open and the
        map does not explain it; p (3,) [m] and sigma [m]: the estimate's position and its sigma."""
        ix, iy, height = view.columns(at)
        if not len(height):
            return None
        cell = view.sensed_cell_m
        x, y = (ix + 0.5) * cell, (iy + 0.5) * cell
        # how far a return this far away may have been misplaced (`PLACEMENT_ERROR`): a column no higher than
        # the ground band lifted by it may be the ground, one that near a mapped obstacle may be that obstacle
        slack = PLACEMENT_ERROR * np.hypot(x - p[0], y - p[1]) + view.config.ground_sigmas * sigma
        ground = height <= view.config.ground_band_m + slack
        route = self.route_of(slot)
        reach = self.radius_m + self.config.margin_m
        new = np.zeros(len(height), dtype=bool)
        for z, field in zip(route.levels_m, route.fields):
            ny, nx = field.shape
            gx = np.rint((x - field.origin_m[0]) / field.cell_m).astype(np.int64)
            gy = np.rint((y - field.origin_m[1]) / field.cell_m).astype(np.int64)
            inside = (gx >= 0) & (gx < nx) & (gy >= 0) & (gy < ny)
            open_ = np.zeros(len(height), dtype=bool)
            open_[inside] = ~field.blocked[gy[inside], gx[inside]]
            new |= open_ & (height > z - reach)
        new &= ~ground
        if not new.any():
            return None
        # a column the map explains (within a memory cell of its obstacles, or sensed and drawn before) is no news
        rows = np.flatnonzero(new)
        prior = self._prior[slot]
        assert prior is not None
        top = np.stack([x[rows], y[rows], height[rows]], axis=1)
        known = prior.obstacle_clearance_m(top) <= cell * (0.5 * np.sqrt(2.0) + 1.0) + slack[rows]
        drawn = np.isin(ix[rows] * _KEY + iy[rows], self._keys[slot])
        if np.all(known | drawn):
            return None
        keys = np.concatenate([self._keys[slot], ix * _KEY + iy])
        heights = np.concatenate([self._heights[slot], height])
        order = np.lexsort((-heights, keys))  # per key, the highest first
        keys, first = np.unique(keys[order], return_index=True)
        self._keys[slot], self._heights[slot] = keys, heights[order][first]
        kx = np.floor_divide(keys + (_KEY >> 1), _KEY)  # keys of negative iy round down: undo the offset
        ky = keys - kx * _KEY
        columns = np.stack([kx * cell, ky * cell, (kx + 1) * cell, (ky + 1) * cell, self._heights[slot]], axis=1)
        task = self._task[slot]
        assert task is not None
        route = route_for(prior, task, self.radius_m, self.config, columns)
        self._route[slot] = route
        self.redraws[slot] += 1
        return route

