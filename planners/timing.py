"""From a geometric path to a smooth, time-parameterised reference within the vehicle's limits.

Frames: world ENU, metres, seconds.

1. Corners are rounded with a uniform cubic B-spline whose control polygon is the path with four
   extra control points per corner, at d and 2d before and after the corner vertex.  Between
   corners the control points are collinear, so the curve runs exactly on the path; near a corner
   it stays inside the triangle (V - 2d u_in, V, V + 2d u_out) and cuts the corner by at most d/3.
   The curve is C2, starts at the start and ends at the goal.
2. Clearance: the curve is sampled every <= `check_spacing_m` and its clearance measured against
   the map (exact, `BuildingMap.clearance`).  Where a rounded corner comes closer than
   R(p) = radius + margin (narrowed towards a start or goal by its taper, relaxed near one that is
   itself inside the margin: `planners.clearance`, the planner's rule), that corner's d is halved
   and the check repeated;
   a corner that still fails after `max_refinements` halvings becomes a stop: the reference comes
   to rest on the corner vertex and turns there.  For a path from the planner (clear by R on every
   segment) this always succeeds; the whole curve is checked once more at the end.
3. Speed profile along the arc length s (forward-backward pass on v^2): the speed limit is
   min(v_h / |t_h|, v_v / |t_z|) for the unit tangent t; the normal acceleration v^2 k (k the
   curvature vector) may use `lateral_fraction` of the horizontal and vertical acceleration
   limits; the tangential acceleration a is bounded so that |a t_h + v^2 k_h| <= a_h and
   |a t_z + v^2 k_z| <= a_v for every admissible speed.  Start and end (and stops) are at rest.
   With a `speed_limit` (the inverse of the margin's speed dependence), the speed at each sample
   is also capped at the fastest whose margin fits the clearance there.
4. The profile is sampled in time every `sample_dt_s`: position, velocity v t and acceleration
   a t + v^2 k.
"""
from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from planners.clearance import MarginTaper, RequiredClearance
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.vehicle.params import GRAVITY_M_S2, VehicleParams

logger = logging.getLogger(__name__)

_MIN_SEGMENT_M = 1e-6  # shorter path segments are merged (duplicate waypoints)
_CUSP_TURN_RAD = math.radians(150.0)  # sharper turns always stop: rounding them would make a cusp


@dataclass(frozen=True)
class TimingLimits:
    """Kinematic limits of the reference (world ENU).

    Attributes:
        max_speed_m_s: horizontal speed limit [m/s].
        max_vertical_speed_m_s: vertical speed limit [m/s].
        max_accel_m_s2: horizontal acceleration limit [m/s^2].
        max_vertical_accel_m_s2: vertical acceleration limit [m/s^2] (both directions).
    """

    max_speed_m_s: float
    max_vertical_speed_m_s: float
    max_accel_m_s2: float
    max_vertical_accel_m_s2: float

    def __post_init__(self) -> None:
        for name in ("max_speed_m_s", "max_vertical_speed_m_s", "max_accel_m_s2", "max_vertical_accel_m_s2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")

    @classmethod
    def from_vehicle(cls, params: VehicleParams, speed_fraction: float = 0.8,
                     accel_fraction: float = 0.5, density_ratio: float = 1.0, gust_m_s: float = 0.0,
                     thrust_fraction: float = 0.85) -> TimingLimits:
        """Limits as fractions of a vehicle's capabilities in air of density ratio σ (the rest is the
        tracker's headroom).

        Args:
            params: the vehicle.
            speed_fraction: share of the controller's horizontal and vertical speed caps.
            accel_fraction: share of the accelerations: vertical g (σ T_max / W - 1), the climb
                acceleration at full thrust; horizontal g tan(max tilt), or, where thin air leaves less
                thrust than level flight at the tilt limit needs (σ T_max / W < 1 / cos(max tilt)),
                g sqrt((σ T_max / W)^2 - 1), the most it can do without sinking.
            density_ratio: σ = ρ/ρ0 where it flies [-] (thrust scales with it). A reference planned
                with sea-level thrust in hot-and-high air asks for climbs the vehicle cannot fly:
                the small quad at σ = 0.71 tracked it with up to 4.6 m of error in moderate turbulence
                and hit buildings (docs/planner.md).
            gust_m_s: airspeed allowance for gusts [m/s] (e.g. `planners.margins.forecast_gust_m_s`).
            thrust_fraction: the horizontal speed is also capped so that level flight at that speed
                plus `gust_m_s` of airspeed needs at most this share of the thrust (drag on the body's
                x axis): the rest is the tracker's authority against the gusts. At sea level this
                never binds for the presets (the speed caps do); in thin air it does: the small quad at
                σ = 0.71 flew its reference at 9.6 m/s into 8 m/s gusts with every rotor at its limit.
        """
        if not (0 < speed_fraction <= 1 and 0 < accel_fraction <= 1):
            raise ValueError("speed_fraction and accel_fraction must be in (0, 1]")
        if not (math.isfinite(density_ratio) and density_ratio > 0):
            raise ValueError(f"density_ratio must be positive and finite, got {density_ratio!r}")
        c = params.controller
        thrust_to_weight = density_ratio * params.max_thrust_N() / params.weight_N
        if thrust_to_weight <= 1.0:
            raise ValueError(f"vehicle {params.name!r} cannot hover at density ratio {density_ratio:.3f} "
                             f"(thrust/weight {thrust_to_weight:.2f})")
        a_h = GRAVITY_M_S2 * min(math.tan(math.radians(c.max_tilt_deg)), math.sqrt(thrust_to_weight ** 2 - 1.0))
        a_v = GRAVITY_M_S2 * (thrust_to_weight - 1.0)
        v_h = min(speed_fraction * c.max_speed_m_s, _cruise_airspeed_m_s(params, density_ratio, thrust_fraction)
                  - max(0.0, float(gust_m_s)))
        # thinner air than this leaves no authority at any useful speed: fly slowly rather than fail
        v_h = max(v_h, min(1.0, speed_fraction * c.max_speed_m_s))
        return cls(v_h, speed_fraction * c.max_vertical_speed_m_s, accel_fraction * a_h, accel_fraction * a_v)


def _cruise_airspeed_m_s(params: VehicleParams, density_ratio: float, thrust_fraction: float) -> float:
    """The airspeed [m/s] at which level flight needs `thrust_fraction` of the thrust at σ: solves
    W² + D(v)² = (f σ T_max)², D(v) = d1 v + d2 v² (the body x axis's drag); inf when it never does."""
    thrust = thrust_fraction * density_ratio * params.max_thrust_N()
    if thrust <= params.weight_N:
        return 0.0
    drag = math.sqrt(thrust ** 2 - params.weight_N ** 2)
    d1, d2 = float(params.drag_linear_N_s_m[0]), float(params.drag_quadratic_N_s2_m2[0])
    if d2 > 0:
        return (-d1 + math.sqrt(d1 * d1 + 4.0 * d2 * drag)) / (2.0 * d2)
    return drag / d1 if d1 > 0 else math.inf


@dataclass(frozen=True)
class TimingConfig:
    """Settings of the time-parameterisation.

    Attributes:
        sample_dt_s: time step of the output arrays [s].
        check_spacing_m: largest arc-length spacing of the clearance samples (and of the speed
            profile's grid) [m].
        lateral_fraction: share of the acceleration limits the normal (turning) acceleration may
            use; the rest is left for speeding up and slowing down in turns.
        corner_fraction: initial corner size d as a share of the shorter adjacent segment (< 0.25
            keeps neighbouring corners apart).
        max_corner_m: largest initial corner size d [m].
        min_corner_m: a corner refined below this becomes a stop [m].
        max_refinements: rounds of halving before the remaining offending corners become stops.
    """

    sample_dt_s: float = 0.02
    check_spacing_m: float = 0.05
    lateral_fraction: float = 0.7
    corner_fraction: float = 0.24
    max_corner_m: float = 60.0
    min_corner_m: float = 0.05
    max_refinements: int = 12

    def __post_init__(self) -> None:
        for name in ("sample_dt_s", "check_spacing_m", "max_corner_m", "min_corner_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be positive and finite, got {v!r}")
        if not 0 < self.lateral_fraction < 1:
            raise ValueError(f"lateral_fraction must be in (0, 1), got {self.lateral_fraction}")
        if not 0 < self.corner_fraction < 0.25:
            raise ValueError(f"corner_fraction must be in (0, 0.25), got {self.corner_fraction}")
        if self.max_refinements < 0:
            raise ValueError("max_refinements must be >= 0")


@dataclass(frozen=True)
class Reference:
    """A time-parameterised reference (world ENU; ends at rest; starts at rest unless planned from a moving
    vehicle, see `time_parameterize`).

    Attributes:
        t_s: (M,) sample times from 0 to `duration_s` [s].
        pos_m: (M, 3) positions [m].
        vel_m_s: (M, 3) velocities [m/s].
        acc_m_s2: (M, 3) accelerations [m/s^2].
        duration_s: time to reach the goal [s].
        status: "ok", or "clearance_violation" (a sample of the curve is closer than required;
            only possible when the input path itself is not clear by radius + margin).
        length_m: arc length of the curve [m].
        min_clearance_m: smallest clearance of the vehicle sphere (collision radius) along the
            curve, sampled every `check_spacing_m` [m].
        required_clearance_m: the margin asked for [m].
        refinements: corner-halving rounds used.
        stops: corners where the reference comes to rest (sharp or not roundable safely).
    """

    t_s: np.ndarray
    pos_m: np.ndarray
    vel_m_s: np.ndarray
    acc_m_s2: np.ndarray
    duration_s: float
    status: str
    length_m: float
    min_clearance_m: float
    required_clearance_m: float
    refinements: int
    stops: int

    @property
    def ok(self) -> bool:
        """True when the clearance requirement holds along the whole curve."""
        return self.status == "ok"

    def sample(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at time t (linear interpolation).

        Before 0 the reference is the start at rest; after `duration_s` the goal at rest.

        Returns:
            pos (3,) [m], vel (3,) [m/s], acc (3,) [m/s^2], world ENU.
        """
        p, v, a = self.sample_horizon(float(t_s), 0.0, 1)
        return p[0], v[0], a[0]

    def sample_horizon(self, t0_s: float, dt_s: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The reference at times t0 + k dt, k = 0 .. n-1 (for an MPC horizon).

        Returns:
            pos (n, 3) [m], vel (n, 3) [m/s], acc (n, 3) [m/s^2], world ENU; at rest outside
            [0, duration].
        """
        t = float(t0_s) + float(dt_s) * np.arange(int(n))
        pos = np.column_stack([np.interp(t, self.t_s, self.pos_m[:, i]) for i in range(3)])
        vel = np.column_stack([np.interp(t, self.t_s, self.vel_m_s[:, i]) for i in range(3)])
        acc = np.column_stack([np.interp(t, self.t_s, self.acc_m_s2[:, i]) for i in range(3)])
        outside = (t < self.t_s[0]) | (t > self.t_s[-1])
        vel[outside] = 0.0
        acc[outside] = 0.0
        return pos, vel, acc

    def deviation_m(self, point_m: np.ndarray, t_s: float, window_s: float = 5.0) -> float:
        """Distance [m] from `point_m` (3,) to the reference curve within `window_s` of time `t_s`.

        The curve is the polyline of the 20 ms samples (their chords lie within millimetres of the
        smooth curve at these speeds). Unlike the error to the reference *at* t, this ignores lag
        along the path: it is how far the vehicle is from where the reference goes, i.e. how much
        of the clearance margin it has used. The window keeps a path that passes the same place
        twice from counting the other pass.
        """
        lo, hi = np.searchsorted(self.t_s, [t_s - window_s, t_s + window_s])
        pts = self.pos_m[max(0, lo - 1):min(len(self.t_s), hi + 1)]
        p = np.asarray(point_m, float)
        if len(pts) == 1:
            return float(np.linalg.norm(p - pts[0]))
        a, b = pts[:-1], pts[1:]
        ab = b - a
        den = np.einsum("ij,ij->i", ab, ab)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(den > 0, np.einsum("ij,ij->i", p - a, ab) / den, 0.0)
        s = np.clip(s, 0.0, 1.0)
        return float(np.sqrt(np.min(np.sum((a + s[:, None] * ab - p) ** 2, axis=1))))


# ---- the curve ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Curve:
    """A densely sampled piece of the smoothed path (rest to rest).

    pts (N, 3) positions, s (N,) arc length, tan (N, 3) unit tangents, kappa (N, 3) curvature
    vectors dt/ds, corner (N,) index (into the path) of the corner a sample rounds, -1 on the path.
    """

    pts: np.ndarray
    s: np.ndarray
    tan: np.ndarray
    kappa: np.ndarray
    corner: np.ndarray


def _bspline_piece(path: np.ndarray, first: int, d: np.ndarray, spacing: float) -> _Curve:
    """Round the interior corners of `path` (K, 3) with sizes d (K,) and sample the curve.

    `first` is the index of path[0] in the whole path (for the corner labels).
    """
    k = len(path)
    ctrl = [path[0]]
    for i in range(1, k - 1):
        u_in = (path[i] - path[i - 1]) / np.linalg.norm(path[i] - path[i - 1])
        u_out = (path[i + 1] - path[i]) / np.linalg.norm(path[i + 1] - path[i])
        ctrl += [path[i] - 2 * d[i] * u_in, path[i] - d[i] * u_in, path[i], path[i] + d[i] * u_out,
                 path[i] + 2 * d[i] * u_out]
    ctrl.append(path[-1])
    # Phantom end points make the curve start and end exactly on the end points, with a tangent.
    c = np.vstack([2 * ctrl[0] - ctrl[1], *ctrl, 2 * ctrl[-1] - ctrl[-2]])
    n_seg = len(c) - 3
    # Corner i's centre control point is c[5 i - 1].  Segment j (control points j..j+3) leaves the
    # path only when that centre has neighbours on both legs: j = 5 i - 3 and 5 i - 2.
    seg_corner = np.full(n_seg, -1)
    for i in range(1, k - 1):
        seg_corner[5 * i - 3:5 * i - 1] = first + i
    diffs = np.linalg.norm(np.diff(c, axis=0), axis=1)
    # |C'| <= the largest control-point difference of the window, so this many steps keep chords <= spacing.
    # At least 32 steps per segment, so that the curvature of small corners is resolved too.
    n_u = np.maximum(32, np.ceil(np.array([diffs[j:j + 3].max() for j in range(n_seg)]) / spacing)).astype(int)
    seg = np.repeat(np.arange(n_seg), n_u)
    u = np.concatenate([np.arange(n) / n for n in n_u])
    seg = np.append(seg, n_seg - 1)
    u = np.append(u, 1.0)
    p0, p1, p2, p3 = c[seg], c[seg + 1], c[seg + 2], c[seg + 3]
    uu = u[:, None]
    pts = ((1 - uu) ** 3 * p0 + (3 * uu**3 - 6 * uu**2 + 4) * p1 + (-3 * uu**3 + 3 * uu**2 + 3 * uu + 1) * p2
           + uu**3 * p3) / 6.0
    d1 = (-(1 - uu) ** 2 * p0 + (3 * uu**2 - 4 * uu) * p1 + (-3 * uu**2 + 2 * uu + 1) * p2 + uu**2 * p3) / 2.0
    d2 = (1 - uu) * p0 + (3 * uu - 2) * p1 + (1 - 3 * uu) * p2 + uu * p3
    speed = np.linalg.norm(d1, axis=1)
    tan = d1 / speed[:, None]
    kappa = (d2 - np.sum(d2 * tan, axis=1)[:, None] * tan) / speed[:, None] ** 2
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return _Curve(pts, s, tan, kappa, seg_corner[seg])


# ---- clearance check and refinement ---------------------------------------------------------------
def _offending_corners(curve: _Curve, city: BuildingMap, required: RequiredClearance) -> set[int]:
    """Corners whose rounded samples come closer than required."""
    idx = np.flatnonzero(curve.corner >= 0)
    if len(idx) == 0:
        return set()
    pts = curve.pts[idx]
    bad = city.clearance(pts, 0.0).distance_m <= required.at(pts)
    return {int(c) for c in np.unique(curve.corner[idx][bad])}


def _clean(path_m: np.ndarray) -> np.ndarray:
    """Drop repeated waypoints and exactly collinear interior ones."""
    p = np.asarray(path_m, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0 or not np.all(np.isfinite(p)):
        raise ValueError(f"path_m must be a non-empty (K, 3) array of finite ENU positions, got shape {p.shape}")
    keep = [p[0]]
    for q in p[1:]:
        if np.linalg.norm(q - keep[-1]) > _MIN_SEGMENT_M:
            keep.append(q)
    out = [keep[0]]
    for i in range(1, len(keep) - 1):
        a, b = keep[i] - out[-1], keep[i + 1] - keep[i]
        if np.linalg.norm(np.cross(a, b)) > 1e-9 * np.linalg.norm(a) * np.linalg.norm(b) or np.dot(a, b) < 0:
            out.append(keep[i])
    if len(keep) > 1:
        out.append(keep[-1])
    return np.array(out)


def _turn_angles(path: np.ndarray) -> np.ndarray:
    """Turn angle at every vertex (K,) [rad]; 0 at the end points."""
    ang = np.zeros(len(path))
    if len(path) > 2:
        a = np.diff(path, axis=0)
        a /= np.linalg.norm(a, axis=1)[:, None]
        ang[1:-1] = np.arccos(np.clip(np.sum(a[:-1] * a[1:], axis=1), -1.0, 1.0))
    return ang


def _smooth(path: np.ndarray, city: BuildingMap, required: RequiredClearance, config: TimingConfig
            ) -> tuple[list[_Curve], int, int]:
    """Round the corners, halving those that come too close: (pieces, refinements, stops)."""
    seg_len = np.linalg.norm(np.diff(path, axis=0), axis=1)
    d = np.zeros(len(path))
    if len(path) > 2:
        d[1:-1] = np.minimum(config.corner_fraction * np.minimum(seg_len[:-1], seg_len[1:]), config.max_corner_m)
    d[_turn_angles(path) > _CUSP_TURN_RAD] = 0.0
    refinements = 0
    while True:
        curves = _pieces(path, d, config.check_spacing_m)
        bad = set().union(*(_offending_corners(c, city, required) for c in curves))
        if not bad:
            break
        if refinements >= config.max_refinements:
            d[list(bad)] = 0.0  # stop on the corner vertex instead of rounding it
            curves = _pieces(path, d, config.check_spacing_m)
            break
        refinements += 1
        for i in bad:
            d[i] = 0.5 * d[i] if 0.5 * d[i] >= config.min_corner_m else 0.0
    return curves, refinements, int(np.sum(d[1:-1] == 0.0))


def _pieces(path: np.ndarray, d: np.ndarray, spacing: float) -> list[_Curve]:
    """Split the path at its stops (corners with d = 0) and smooth each piece."""
    stops = [0] + [i for i in range(1, len(path) - 1) if d[i] == 0.0] + [len(path) - 1]
    return [_bspline_piece(path[a:b + 1], a, d[a:b + 1], spacing) for a, b in itertools.pairwise(stops)]


# ---- speed profile -----------------------------------------------------------------------------------
def _interval_abs_le(h: np.ndarray, g: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the interval of a with |a h + g| <= limit (h, g: (N, m)); (-inf, inf) if h = 0."""
    hh = np.sum(h * h, axis=1)
    hg = np.sum(h * g, axis=1)
    gg = np.sum(g * g, axis=1)
    disc = hg**2 - hh * (gg - limit**2)
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = np.where(hh > 1e-12, (-hg - root) / hh, -np.inf)
        hi = np.where(hh > 1e-12, (-hg + root) / hh, np.inf)
    # Infeasible rows (cannot happen below the curvature speed limit) get a = 0 only.
    empty = (disc < 0) | ((hh <= 1e-12) & (gg > limit**2))
    return np.where(empty, 0.0, lo), np.where(empty, 0.0, hi)


def _speed_profile(curve: _Curve, limits: TimingLimits, config: TimingConfig,
                   start_speed_m_s: float = 0.0, speed_cap_m_s: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Squared speed w (N,) at the samples and tangential acceleration a (N-1,) on each interval; the piece
    starts at `start_speed_m_s` if its limits and the stop at its end allow, else as fast as they do;
    `speed_cap_m_s` (N,) is a further cap per sample (the speed the clearance there allows)."""
    t, k = curve.tan, curve.kappa
    th, tz = np.linalg.norm(t[:, :2], axis=1), np.abs(t[:, 2])
    kh, kz = np.linalg.norm(k[:, :2], axis=1), np.abs(k[:, 2])
    f = config.lateral_fraction
    with np.errstate(divide="ignore"):
        w_max = np.minimum.reduce([
            np.where(th > 0, (limits.max_speed_m_s / th) ** 2, np.inf),
            np.where(tz > 0, (limits.max_vertical_speed_m_s / tz) ** 2, np.inf),
            np.where(kh > 0, f * limits.max_accel_m_s2 / kh, np.inf),
            np.where(kz > 0, f * limits.max_vertical_accel_m_s2 / kz, np.inf)])
    if speed_cap_m_s is not None:
        w_max = np.minimum(w_max, np.asarray(speed_cap_m_s, float) ** 2)
    # Between grid points the geometry is interpolated: hold each sample to its neighbours' limits too.
    w_max[1:-1] = np.minimum.reduce([w_max[:-2], w_max[1:-1], w_max[2:]])
    # Tangential bounds valid for every speed up to the limit (the constraint set is convex in (a, v^2)).
    lo = np.full(len(t), -np.inf)
    hi = np.full(len(t), np.inf)
    for w in (np.zeros(len(t)), w_max):
        for h, g, lim in ((t[:, :2], w[:, None] * k[:, :2], limits.max_accel_m_s2),
                          (t[:, 2:], w[:, None] * k[:, 2:], limits.max_vertical_accel_m_s2)):
            l_, h_ = _interval_abs_le(h, g, lim)
            lo, hi = np.maximum(lo, l_), np.minimum(hi, h_)
    a_up = np.minimum(hi[:-1], hi[1:])
    a_down = -np.maximum(lo[:-1], lo[1:])
    ds = np.diff(curve.s)
    w_max[0] = min(w_max[0], float(start_speed_m_s) ** 2)  # rest at the start unless already moving
    w_max[-1] = 0.0  # rest at the end
    w = _cap_growth(w_max, 2.0 * np.maximum(a_up, 0.0) * ds)
    w = _cap_growth(w[::-1], (2.0 * np.maximum(a_down, 0.0) * ds)[::-1])[::-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(ds > 0, np.diff(w) / (2.0 * ds), 0.0)
    return w, a


def _cap_growth(cap: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The largest w <= cap with w[i+1] <= w[i] + step[i], w[0] = cap[0] (a min-plus scan)."""
    b = np.concatenate([[0.0], np.cumsum(step)])
    return b + np.minimum.accumulate(cap - b)


# ---- sampling in time --------------------------------------------------------------------------------
def _timed(curve: _Curve, w: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Time at each sample of a piece (N,) [s]."""
    v = np.sqrt(np.maximum(w, 0.0))
    ds = np.diff(curve.s)
    vs = v[:-1] + v[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(vs > 0, 2.0 * ds / vs, 0.0)
    return np.concatenate([[0.0], np.cumsum(dt)])


def _sample_piece(curve: _Curve, w: np.ndarray, a: np.ndarray, t_piece: np.ndarray, t: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact constant-acceleration kinematics within each interval, then geometry by interpolation."""
    i = np.clip(np.searchsorted(t_piece, t, side="right") - 1, 0, len(t_piece) - 2)
    tau = t - t_piece[i]
    v0 = np.sqrt(np.maximum(w[i], 0.0))
    ai = a[i]
    s = np.minimum(curve.s[i] + v0 * tau + 0.5 * ai * tau**2, curve.s[i + 1])
    v = np.maximum(v0 + ai * tau, 0.0)
    pos = np.column_stack([np.interp(s, curve.s, curve.pts[:, j]) for j in range(3)])
    tan = np.column_stack([np.interp(s, curve.s, curve.tan[:, j]) for j in range(3)])
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    kap = np.column_stack([np.interp(s, curve.s, curve.kappa[:, j]) for j in range(3)])
    return pos, v[:, None] * tan, ai[:, None] * tan + (v**2)[:, None] * kap


# ---- the public entry point ----------------------------------------------------------------------------
def time_parameterize(path_m: np.ndarray, limits: TimingLimits, city: BuildingMap, radius_m: float,
                      margin_m: float, config: TimingConfig = TimingConfig(), start_speed_m_s: float = 0.0,
                      tapers: Sequence[MarginTaper] = (),
                      speed_limit: Callable[[np.ndarray], np.ndarray] | None = None) -> Reference:
    """Smooth a collision-free path and time it within the limits, keeping the clearance.

    Args:
        path_m: (K, 3) waypoints from start to goal, world ENU metres (e.g. `PlanResult.path_m`).
        limits: speed and acceleration limits.
        city: the map the clearance is checked against (its no-fly volumes included, as in the
            planner: `BuildingMap.planning_map`).
        radius_m: vehicle collision radius [m].
        margin_m: clearance required beyond the radius [m] (as used by the planner).
        config: smoothing and sampling settings.
        start_speed_m_s: speed along the path at its start [m/s] (a replan from a moving vehicle): the
            reference starts at it where the limits and the first stop allow, else as fast as they do.
        tapers: the margin narrowing towards the start or goal, as given to the planner
            (`planners.clearance.MarginTaper`).
        speed_limit: the fastest speed [m/s] at which the reference may pass a point whose clearance
            beyond the collision radius is x [m], vectorised over x
            (`planners.margins.SpeedMargins.speed_limit_m_s`): the margin in force follows the speed,
            so the reference slows where it passes closer than the cruise margin. None: no such cap.

    Returns:
        A Reference from the path's start (at rest unless `start_speed_m_s`) to its end, at rest.  Its status is
        "clearance_violation" when some sample of the curve is closer than radius + margin (less
        near a close start or goal: `endpoint_allowance`), which a path from `plan_path` never is.

    Raises:
        ValueError: on a malformed path or negative radius/margin.
    """
    if not (math.isfinite(radius_m) and radius_m >= 0 and math.isfinite(margin_m) and margin_m >= 0):
        raise ValueError(f"radius_m and margin_m must be finite and >= 0, got {radius_m}, {margin_m}")
    if not (math.isfinite(start_speed_m_s) and start_speed_m_s >= 0):
        raise ValueError(f"start_speed_m_s must be finite and >= 0, got {start_speed_m_s}")
    city = city.planning_map()
    path = _clean(path_m)
    if len(path) == 1:
        return _at_rest(path[0], city, radius_m, margin_m)
    required = RequiredClearance(city, radius_m, margin_m, (path[0], path[-1]), tapers)
    curves, refinements, stops = _smooth(path, city, required, config)
    # clearance of every sample of the final curve: the speed cap and the final check both use it
    clear = [city.clearance(c.pts, 0.0).distance_m for c in curves]
    t_all, pos_all, vel_all, acc_all = [], [], [], []
    t_offset = 0.0
    for k, curve in enumerate(curves):
        cap = None if speed_limit is None else speed_limit(clear[k] - float(radius_m))
        w, a = _speed_profile(curve, limits, config, start_speed_m_s if k == 0 else 0.0, cap)
        t_piece = _timed(curve, w, a)
        n = max(1, math.ceil(t_piece[-1] / config.sample_dt_s))
        t = np.minimum(np.arange(n) * config.sample_dt_s, t_piece[-1])
        pos, vel, acc = _sample_piece(curve, w, a, t_piece, t)
        t_all.append(t + t_offset)
        pos_all.append(pos)
        vel_all.append(vel)
        acc_all.append(acc)
        t_offset += t_piece[-1]
    last = curves[-1]
    t_all.append(np.array([t_offset]))
    pos_all.append(last.pts[-1:].copy())
    vel_all.append(np.zeros((1, 3)))
    acc_all.append(np.zeros((1, 3)))
    dense = np.vstack([c.pts for c in curves])
    d_dense = np.concatenate(clear)
    ok = bool(np.all(d_dense > required.at(dense) - 1e-9))
    min_clear = float(np.min(d_dense)) - float(radius_m)
    length = float(sum(c.s[-1] for c in curves))
    ref = Reference(
        t_s=_frozen(np.concatenate(t_all)), pos_m=_frozen(np.vstack(pos_all)), vel_m_s=_frozen(np.vstack(vel_all)),
        acc_m_s2=_frozen(np.vstack(acc_all)), duration_s=float(t_offset), status="ok" if ok else "clearance_violation",
        length_m=length, min_clearance_m=min_clear, required_clearance_m=float(margin_m), refinements=refinements,
        stops=stops)
    logger.debug("reference: %.1f m in %.1f s, %d refinements, %d stops, min clearance %.2f m (%s)",
                 length, ref.duration_s, refinements, stops, min_clear, ref.status)
    return ref


def braking_reference(position_m: np.ndarray, velocity_m_s: np.ndarray, decel_m_s2: float, step_s: float = 0.02,
                      floor_z_m: float = -math.inf) -> Reference:
    """A straight stop: from `position_m` (3,) at `velocity_m_s` (3,) world ENU, slowing at `decel_m_s2` [m/s²]
    along the velocity until at rest, then holding there (a hover). Its clearance is not checked (NaN): it is what
    the vehicle flies while a replan runs, or holding when none succeeds.

    A descent that would stop below `floor_z_m` [m] (the ground plus what must be kept from it) stops its vertical
    speed harder, at v_z² / 2 (z - floor), to rest on the floor (at once when already below it); the horizontal speed
    still slows at its share of `decel_m_s2`, so the two end at different times."""
    p0 = np.asarray(position_m, float).reshape(3)
    v0 = np.asarray(velocity_m_s, float).reshape(3)
    speed = float(np.linalg.norm(v0))
    if not (math.isfinite(decel_m_s2) and decel_m_s2 > 0.0):
        raise ValueError(f"decel_m_s2 must be positive and finite, got {decel_m_s2!r}")
    # each axis slows at its share of the deceleration (a straight stop), the vertical one harder above a floor
    decel = decel_m_s2 * np.abs(v0) / speed if speed > 0.0 else np.zeros(3)
    if v0[2] < 0.0 and p0[2] - v0[2] ** 2 / (2.0 * decel[2]) < floor_z_m:
        room = float(p0[2] - floor_z_m)
        decel[2] = v0[2] ** 2 / (2.0 * room) if room > 0.0 else math.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        stop_axis = np.where(decel > 0.0, np.abs(v0) / decel, 0.0)
    stop_s = float(np.max(stop_axis))
    t = np.append(np.arange(0.0, stop_s, step_s), stop_s) if stop_s > 0.0 else np.zeros(1)
    tau = np.minimum(t[:, None], stop_axis[None, :])  # (M, 3): each axis at rest after its own stop
    sign = np.sign(v0)
    finite = np.where(np.isfinite(decel), decel, 0.0)
    pos = p0 + v0 * tau - 0.5 * sign * finite * tau * tau
    vel = np.where(t[:, None] < stop_axis[None, :], v0 - sign * finite * tau, 0.0)
    acc = np.where(t[:, None] < stop_axis[None, :], -sign * finite, 0.0)
    acc[-1] = 0.0
    length = float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))) if len(pos) > 1 else 0.0
    return Reference(t_s=_frozen(t), pos_m=_frozen(pos), vel_m_s=_frozen(vel), acc_m_s2=_frozen(acc),
                     duration_s=float(stop_s), status="ok", length_m=length, min_clearance_m=math.nan,
                     required_clearance_m=math.nan, refinements=0, stops=1)


def braking_along(reference: Reference, t_s: float, decel_m_s2: float, step_s: float = 0.02) -> Reference:
    """A stop along a reference's own path: from where `reference` is at its time `t_s` [s], at its speed there,
    slowing at `decel_m_s2` [m/s²] along the same curve until at rest (or at the curve's end), then holding there.
    The curve was clear in the map it was planned on, a straight line along the velocity need not be (a vehicle
    braking in a turn). Clearance not checked (NaN), as `braking_reference`'s."""
    if not (math.isfinite(decel_m_s2) and decel_m_s2 > 0.0):
        raise ValueError(f"decel_m_s2 must be positive and finite, got {decel_m_s2!r}")
    pos = np.asarray(reference.pos_m, float)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    tau = min(max(float(t_s), 0.0), reference.duration_s)
    s0 = float(np.interp(tau, reference.t_s, arc))
    speed = float(np.linalg.norm(reference.sample(tau)[1]))
    stop_s = speed / decel_m_s2
    t = np.append(np.arange(0.0, stop_s, step_s), stop_s) if stop_s > 0.0 else np.zeros(1)
    s = np.minimum(s0 + speed * t - 0.5 * decel_m_s2 * t * t, arc[-1])  # ends at the curve's end at the latest
    keep = np.concatenate([[True], np.diff(arc) > 0.0])  # the curve's points where it moves (np.interp's abscissa)
    p = np.column_stack([np.interp(s, arc[keep], pos[keep, k]) for k in range(3)])
    ahead = np.column_stack([np.interp(np.minimum(s + 0.01, arc[-1]), arc[keep], pos[keep, k]) for k in range(3)])
    span = np.linalg.norm(ahead - p, axis=1)
    unit = np.where(span[:, None] > 0.0, (ahead - p) / np.maximum(span, 1e-12)[:, None], 0.0)
    v = np.maximum(speed - decel_m_s2 * t, 0.0)
    v[s >= arc[-1]] = 0.0
    acc = -decel_m_s2 * unit * (v > 0.0)[:, None]
    return Reference(t_s=_frozen(t), pos_m=_frozen(p), vel_m_s=_frozen(v[:, None] * unit), acc_m_s2=_frozen(acc),
                     duration_s=float(t[-1]), status="ok", length_m=float(s[-1] - s0), min_clearance_m=math.nan,
                     required_clearance_m=math.nan, refinements=0, stops=1)


def then_straight(reference: Reference, point_m: np.ndarray, max_speed_m_s: float, accel_m_s2: float,
                  step_s: float = 0.02) -> Reference:
    """`reference`, then from its end at rest a straight move to `point_m` (3,) [m] world ENU, accelerating and
    slowing at `accel_m_s2` [m/s²] up to `max_speed_m_s` [m/s] (rest to rest), holding there. Clearance not checked
    (NaN), as `braking_reference`'s."""
    if not all(math.isfinite(x) and x > 0.0 for x in (max_speed_m_s, accel_m_s2)):
        raise ValueError(f"max_speed_m_s and accel_m_s2 must be positive and finite, got {max_speed_m_s!r}, "
                         f"{accel_m_s2!r}")
    start = np.asarray(reference.pos_m[-1], float)
    span = np.asarray(point_m, float).reshape(3) - start
    d = float(np.linalg.norm(span))
    if d <= 0.0:
        return reference
    unit = span / d
    t_acc = min(max_speed_m_s / accel_m_s2, math.sqrt(d / accel_m_s2))  # trapezoid, or a triangle when short
    v_top = accel_m_s2 * t_acc
    t_cruise = (d - v_top * t_acc) / v_top
    total = 2.0 * t_acc + t_cruise
    t = np.append(np.arange(step_s, total, step_s), total)
    t1, t2 = np.minimum(t, t_acc), np.clip(t - t_acc - t_cruise, 0.0, t_acc)
    s_along = 0.5 * accel_m_s2 * t1 ** 2 + v_top * np.clip(t - t_acc, 0.0, t_cruise) + v_top * t2 \
        - 0.5 * accel_m_s2 * t2 ** 2
    v_along = np.where(t < t_acc, accel_m_s2 * t, np.where(t < t_acc + t_cruise, v_top, v_top - accel_m_s2 * t2))
    a_along = np.where(t < t_acc, accel_m_s2, np.where(t < t_acc + t_cruise, 0.0, -accel_m_s2))
    a_along[-1], v_along[-1] = 0.0, 0.0
    return dataclasses.replace(
        reference, t_s=_frozen(np.append(reference.t_s, reference.duration_s + t)),
        pos_m=_frozen(np.vstack([reference.pos_m, start + s_along[:, None] * unit])),
        vel_m_s=_frozen(np.vstack([reference.vel_m_s, v_along[:, None] * unit])),
        acc_m_s2=_frozen(np.vstack([reference.acc_m_s2, a_along[:, None] * unit])),
        duration_s=float(reference.duration_s + total), length_m=float(reference.length_m + d),
        min_clearance_m=math.nan, required_clearance_m=math.nan, stops=reference.stops + 1)


def _at_rest(p: np.ndarray, city: BuildingMap, radius_m: float, margin_m: float) -> Reference:
    z = np.zeros((1, 3))
    clear = float(city.clearance(p[None, :], radius_m).distance_m[0])
    return Reference(t_s=_frozen(np.zeros(1)), pos_m=_frozen(p[None, :].copy()), vel_m_s=_frozen(z.copy()),
                     acc_m_s2=_frozen(z.copy()), duration_s=0.0, status="ok", length_m=0.0,
                     min_clearance_m=clear, required_clearance_m=float(margin_m), refinements=0, stops=0)


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a
