"""A GNSS receiver: a sky of satellites, time-correlated pseudorange errors, blocking and reflections by the true
buildings, a least-squares position fix.

Model (per `GnssSpec`):

* Sky. `satellites` satellites above the elevation mask, azimuth uniform over 360°, elevation drawn so that
  sin(el) is uniform over [sin(mask), 1] (a uniform density over the visible cap of the sphere). The sky is fixed
  for a receiver's life: satellites move ~0.5° a minute and flights last minutes.
* Pseudorange errors. Each satellite's error (ephemeris, clock, ionosphere, troposphere, multipath in the open)
  is a first-order Gauss-Markov process of σ = `pseudorange_sigma_m` and correlation time `correlation_time_s`,
  stationary from the first epoch and propagated exactly between epochs: b' = φ b + σ √(1 - φ²) w with
  φ = exp(-Δt / τ), w ~ N(0, 1). Errors common to all satellites (the receiver clock) are absorbed by the fix.
* Urban canyon (`urban_canyon`). A satellite whose line of sight from the receiver hits a true building is
  lost, unless it is tracked through a reflection: with probability `nlos_probability`, drawn once when it
  becomes blocked and kept while it stays blocked (a redraw at every epoch would make a reflection flicker at the
  fix rate). A reflected signal is longer by the extra path of a reflection off a vertical wall at horizontal
  distance d from the receiver, 2 d cos(el) (the wall taken square to the satellite's azimuth; the classic
  single-reflector NLOS model). d is the receiver's horizontal distance to the nearest building whose wall
  reaches its height (a wall lower than the receiver cannot reflect a descending signal down to it); the same d
  serves every reflected satellite.
* Fix. With H the rows [-e_i, 1] over the tracked satellites (e_i the unit line of sight, ENU), the position error
  is the first three components of (HᵀH)⁻¹ Hᵀ δρ (δρ the tracked satellites' errors, NLOS biases included).
  No fix under `min_satellites` (or on a degenerate geometry). The receiver reports σ_h = σ_ρ · HDOP and
  σ_v = σ_ρ · VDOP: what a receiver believes from its geometry, not its true error (blind to NLOS biases).
* Outages (loss of lock): a Poisson process of rate `outage_rate_per_min`, each lasting uniform(0, max_outage_s].
* Velocity (Doppler): the true velocity plus white N(0, velocity_sigma_m_s²) per component.

Each part draws from its own child of the given Generator, so switching the canyon or the outages on leaves the
pseudorange noise of the same seed unchanged (paired comparisons).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from uam_fdm.city.buildings import BuildingMap
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import GnssSpec

logger = logging.getLogger(__name__)

_MAX_COND = 1e8  # a geometry this ill-conditioned gives no usable fix (a receiver's solution would diverge)
_WALLS = 8  # nearest buildings searched for a wall that reaches the receiver's height


@dataclass(frozen=True)
class GnssFix:
    """One fix as the receiver reports it (no truth).

    Attributes:
        t_s: time of the fix [s].
        position_m: (3,) position, world ENU metres.
        velocity_m_s: (3,) velocity, world ENU [m/s].
        satellites: satellites used.
        hdop, vdop: horizontal and vertical dilution of precision of those satellites.
        sigma_h_m: reported horizontal accuracy (σ_ρ · HDOP, the RMS of the 2D error) [m].
        sigma_v_m: reported vertical accuracy (σ_ρ · VDOP) [m].
        sigma_vel_m_s: reported σ of each velocity component [m/s].
    """

    t_s: float
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    satellites: int
    hdop: float
    vdop: float
    sigma_h_m: float
    sigma_v_m: float
    sigma_vel_m_s: float


def draw_sky(n: int, elevation_mask_deg: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A sky of n satellites above the mask: azimuths [rad] (from north, clockwise) and elevations [rad],
    sin(elevation) uniform over [sin(mask), 1]."""
    az = rng.uniform(0.0, 2.0 * math.pi, n)
    el = np.arcsin(rng.uniform(math.sin(math.radians(elevation_mask_deg)), 1.0, n))
    return az, el


def line_of_sight_enu(az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
    """Unit vectors from the receiver to the satellites: (n, 3), world ENU."""
    ce = np.cos(el_rad)
    return np.column_stack([ce * np.sin(az_rad), ce * np.cos(az_rad), np.sin(el_rad)])


def dop(los_enu: np.ndarray) -> tuple[float, float] | None:
    """HDOP and VDOP of satellites with these unit lines of sight (n, 3) ENU; None when fewer than 4 or degenerate."""
    if len(los_enu) < 4:
        return None
    h = np.column_stack([-los_enu, np.ones(len(los_enu))])
    hth = h.T @ h
    if np.linalg.cond(hth) > _MAX_COND:
        return None
    g = np.linalg.inv(hth)
    return math.sqrt(g[0, 0] + g[1, 1]), math.sqrt(g[2, 2])


class Gnss:
    """A GNSS receiver on the vehicle, reading the true city for its lines of sight.

    Args:
        spec: the receiver.
        city: the true city (for the reflecting walls' distance).
        caster: the true city's ray caster (for the lines of sight); may be None when `spec.urban_canyon` is False.
        rng: the source of the sky and of every error.

    Attributes:
        last_satellites: satellites tracked at the last call (0 during an outage).
        last_fix: whether the last call gave a fix.
    """

    def __init__(self, spec: GnssSpec, city: BuildingMap, caster: RayCaster | None, rng: np.random.Generator) -> None:
        if spec.urban_canyon and caster is None:
            raise ValueError("an urban-canyon GNSS needs the true city's RayCaster")
        if spec.satellites < 0 or spec.correlation_time_s <= 0.0 or not 0.0 <= spec.nlos_probability <= 1.0:
            raise ValueError(f"GNSS spec out of range: {spec}")
        self.spec = spec
        self._city = city
        self._caster = caster
        sky, self._range_rng, self._nlos_rng, self._outage_rng, self._vel_rng = rng.spawn(5)
        self.azimuth_rad, self.elevation_rad = draw_sky(spec.satellites, spec.elevation_mask_deg, sky)
        self._los = line_of_sight_enu(self.azimuth_rad, self.elevation_rad)
        self._err = np.zeros(spec.satellites)
        self._blocked = np.zeros(spec.satellites, dtype=bool)
        self._reflected = np.zeros(spec.satellites, dtype=bool)
        self._t: float | None = None
        self._next_outage_s = math.inf
        self._outage_end_s = -math.inf
        self.last_satellites = 0
        self.last_fix = False

    def _propagate(self, t_s: float) -> None:
        """Advance every satellite's pseudorange error to t_s (exact Gauss-Markov discretisation)."""
        s, n = self.spec, self.spec.satellites
        w = self._range_rng.standard_normal(n)
        if self._t is None:
            self._err = s.pseudorange_sigma_m * w  # stationary from the start
        else:
            if t_s < self._t:
                raise ValueError(f"GNSS epochs must not go back in time: {t_s} after {self._t}")
            phi = math.exp(-(t_s - self._t) / s.correlation_time_s)
            self._err = phi * self._err + s.pseudorange_sigma_m * math.sqrt(1.0 - phi * phi) * w

    def _in_outage(self, t_s: float) -> bool:
        """Whether the receiver has lost lock at t_s (outage starts: a Poisson process; lengths uniform)."""
        s = self.spec
        rate_per_s = s.outage_rate_per_min / 60.0
        if rate_per_s <= 0.0 or s.max_outage_s <= 0.0:
            return False
        if self._t is None:
            self._next_outage_s = t_s + self._outage_rng.exponential(1.0 / rate_per_s)
        while t_s >= self._next_outage_s:
            length = s.max_outage_s * (1.0 - self._outage_rng.random())  # uniform over (0, max]
            self._outage_end_s = self._next_outage_s + length
            self._next_outage_s = self._outage_end_s + self._outage_rng.exponential(1.0 / rate_per_s)
        return t_s < self._outage_end_s

    def _sky_at(self, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which satellites are tracked from here, and each one's extra (NLOS) range [m]."""
        n = self.spec.satellites
        if not self.spec.urban_canyon or n == 0:
            return np.ones(n, dtype=bool), np.zeros(n)
        assert self._caster is not None
        blocked = self._caster.hits_any(position_m, self._los)
        newly = blocked & ~self._blocked
        draws = self._nlos_rng.random(n)  # n draws every epoch: the stream does not depend on the geometry
        self._reflected = np.where(newly, draws < self.spec.nlos_probability, self._reflected & blocked)
        self._blocked = blocked
        extra = np.zeros(n)
        if np.any(self._reflected):
            d_m = self._wall_distance_m(position_m)
            extra[self._reflected] = 2.0 * d_m * np.cos(self.elevation_rad[self._reflected])
        return ~blocked | self._reflected, extra

    def _wall_distance_m(self, position_m: np.ndarray) -> float:
        """Horizontal distance [m] to the nearest building wall that reaches the receiver's height."""
        k = min(_WALLS, len(self._city.building_ids))
        if k == 0:
            return 0.0
        pts, _ = self._city.nearest_obstacles(position_m.tolist(), k)
        horiz = np.hypot(pts[:, 0] - position_m[0], pts[:, 1] - position_m[1])
        tall = pts[:, 2] >= position_m[2] - 1e-9  # the nearest point is on a wall, not on a roof below
        return float(np.min(horiz[tall])) if np.any(tall) else float(np.min(horiz))

    def measure(self, t_s: float, position_m: np.ndarray, velocity_m_s: np.ndarray) -> GnssFix | None:
        """The receiver's fix at epoch t_s (call at every epoch, `spec.rate_hz`, in time order).

        Args:
            t_s: time [s].
            position_m: (3,) true antenna position, world ENU metres.
            velocity_m_s: (3,) true velocity, world ENU [m/s].

        Returns:
            the fix, or None (outage, fewer than `min_satellites` tracked, degenerate geometry).
        """
        p = np.asarray(position_m, dtype=float).reshape(3)
        v = np.asarray(velocity_m_s, dtype=float).reshape(3)
        self._propagate(t_s)
        outage = self._in_outage(t_s)
        self._t = float(t_s)
        tracked, extra = self._sky_at(p)
        vel_noise = self.spec.velocity_sigma_m_s * self._vel_rng.standard_normal(3)
        self.last_satellites = 0 if outage else int(np.count_nonzero(tracked))
        self.last_fix = False
        if outage or self.last_satellites < max(self.spec.min_satellites, 4):
            return None
        los = self._los[tracked]
        d = dop(los)
        if d is None:
            return None
        h = np.column_stack([-los, np.ones(len(los))])
        err = np.linalg.solve(h.T @ h, h.T @ (self._err[tracked] + extra[tracked]))[:3]
        self.last_fix = True
        hdop, vdop = d
        sig = self.spec.pseudorange_sigma_m
        pos, vel = p + err, v + vel_noise
        pos.setflags(write=False)
        vel.setflags(write=False)
        return GnssFix(float(t_s), pos, vel, self.last_satellites, hdop, vdop, sig * hdop, sig * vdop,
                       self.spec.velocity_sigma_m_s)
