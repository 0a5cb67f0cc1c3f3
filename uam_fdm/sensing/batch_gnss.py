"""The GNSS receivers of N vehicles at once (`uam_fdm.sensing.gnss.Gnss`'s model), each slot in its own city.

Per slot: its own sky, pseudorange errors (first-order Gauss-Markov), outages and, in the urban canyon, lines of
sight cast against its city with that city's `RayCaster` and reflections off its walls. A slot's fixes are those
of a `Gnss` built from the same Generator, bit for bit (tests/uam_fdm/sensing/test_batch_onboard.py): the same
draws in each of its child streams, and per slot the same floating-point operations. The least-squares fix is
solved for slots grouped by how many satellites they track, one stacked call per group: stacked `matmul`,
`cond`, `inv` and `solve` run LAPACK/BLAS matrix by matrix on the same (n, 4) geometry a single receiver builds,
so they give its numbers (a zero-padded geometry would change BLAS's summation order, and the last bits).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from uam_fdm.city.buildings import BuildingMap
from uam_fdm.sensing.batch_sensors import SlotStreams
from uam_fdm.sensing.gnss import _MAX_COND, _WALLS, GnssFix, draw_sky, line_of_sight_enu
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import GnssSpec


class BatchGnss:
    """N GNSS receivers.

    Args:
        spec: the receiver (every slot carries the same).
        n: slots.
        cities: the TRUE cities (walls for reflections); needed with `spec.urban_canyon`.
        casters: one ray caster per city (lines of sight); needed with `spec.urban_canyon`.

    Attributes:
        satellites: (N,) satellites tracked at each slot's last epoch (0 in an outage).
        epochs, fixes: (N,) epochs since each slot's restart, and those with a fix.

    Raises:
        ValueError: a spec out of range, or an urban canyon without one caster per city.
    """

    def __init__(self, spec: GnssSpec, n: int, cities: Sequence[BuildingMap] = (),
                 casters: Sequence[RayCaster] = ()) -> None:
        if spec.satellites < 0 or spec.correlation_time_s <= 0.0 or not 0.0 <= spec.nlos_probability <= 1.0:
            raise ValueError(f"GNSS spec out of range: {spec}")
        if spec.urban_canyon and (not cities or len(casters) != len(cities)):
            raise ValueError(f"an urban-canyon GNSS needs the true cities and one RayCaster per city; got "
                             f"{len(cities)} cities and {len(casters)} casters")
        self.spec = spec
        self._cities, self._casters = list(cities), list(casters)
        s = spec.satellites
        self._city = np.zeros(n, dtype=np.intp)
        self._los = np.zeros((n, s, 3))  # unit lines of sight, world ENU
        self._cos_el = np.zeros((n, s))
        self._err = np.zeros((n, s))  # pseudorange errors [m]
        self._blocked = np.zeros((n, s), dtype=bool)
        self._reflected = np.zeros((n, s), dtype=bool)
        self._t = np.full(n, np.nan)  # last epoch [s]; NaN: none yet
        self._next_outage = np.full(n, math.inf)
        self._outage_end = np.full(n, -math.inf)
        self._outage_rng: list[np.random.Generator | None] = [None] * n
        # a block of 10 epochs ahead per slot for the per-epoch draws
        self._range = SlotStreams(n, max(1, 10 * s))
        self._nlos = SlotStreams(n, max(1, 10 * s), uniform=True)
        self._vel = SlotStreams(n, 30)
        # each slot's last geometry (tracked set, HᵀH, usable, HDOP and VDOP): an open sky's never changes, a
        # canyon's seldom between epochs, and recomputing the same matrices gives the same numbers
        self._geo_tracked = np.zeros((n, s), dtype=bool)
        self._geo_valid = np.zeros(n, dtype=bool)
        self._geo_hth = np.zeros((n, 4, 4))
        self._geo_ok = np.zeros(n, dtype=bool)
        self._geo_dop = np.zeros((n, 2))
        self.satellites = np.zeros(n, dtype=np.int64)
        self.epochs = np.zeros(n, dtype=np.int64)
        self.fixes = np.zeros(n, dtype=np.int64)

    def restart(self, i: int, rng: np.random.Generator, city: int = 0) -> None:
        """Switch slot i's receiver on in city `city` (an index of `cities`), drawing from `rng` as `Gnss` does:
        the sky from its first child, then ranges, reflections, outages and velocities from one child each."""
        sky, range_rng, nlos_rng, outage_rng, vel_rng = rng.spawn(5)
        az, el = draw_sky(self.spec.satellites, self.spec.elevation_mask_deg, sky)
        self._los[i] = line_of_sight_enu(az, el)
        self._cos_el[i] = np.cos(el)
        self._city[i] = city
        self._err[i] = 0.0
        self._blocked[i] = False
        self._reflected[i] = False
        self._t[i] = np.nan
        self._geo_valid[i] = False
        self._next_outage[i], self._outage_end[i] = math.inf, -math.inf
        self._outage_rng[i] = outage_rng
        self._range.restart(i, range_rng)
        self._nlos.restart(i, nlos_rng)
        self._vel.restart(i, vel_rng)
        self.satellites[i] = self.epochs[i] = self.fixes[i] = 0

    def measure(self, slots: np.ndarray, t_s: np.ndarray, position_m: np.ndarray,
                velocity_m_s: np.ndarray) -> list[GnssFix | None]:
        """The fixes of slots (M,) at their epochs t_s (M,) [s] (`Gnss.measure`, each slot's epochs in time order).

        Args:
            slots: (M,) the slots.
            t_s: (M,) epoch times [s].
            position_m: (M, 3) true antenna positions, world ENU [m].
            velocity_m_s: (M, 3) true velocities, world ENU [m/s].

        Returns:
            per slot its fix, or None (outage, fewer than `min_satellites` tracked, degenerate geometry).
        """
        spec, m = self.spec, len(slots)
        self._propagate(slots, t_s)
        outage = self._in_outage(slots, t_s)
        self._t[slots] = t_s
        tracked, extra = self._sky_at(slots, position_m)
        vel = velocity_m_s + spec.velocity_sigma_m_s * self._vel.take(slots, 3)
        count = np.where(outage, 0, np.count_nonzero(tracked, axis=1))
        self.satellites[slots] = count
        self.epochs[slots] += 1
        fixes: list[GnssFix | None] = [None] * m
        solvable = ~outage & (count >= max(spec.min_satellites, 4))
        for n_sat in np.unique(count[solvable]):
            rows = np.flatnonzero(solvable & (count == n_sat))
            for r, fix in zip(rows.tolist(), self._solve(slots[rows], t_s[rows], position_m[rows], vel[rows],
                                                         tracked[rows], extra[rows], int(n_sat))):
                fixes[r] = fix
        self.fixes[slots] += np.array([f is not None for f in fixes], dtype=np.int64)
        return fixes

    def _propagate(self, slots: np.ndarray, t_s: np.ndarray) -> None:
        """Every satellite's pseudorange error to t_s (exact Gauss-Markov discretisation; stationary at the first)."""
        s = self.spec
        w = self._range.take(slots, s.satellites)
        last = self._t[slots]
        if np.any(t_s < last):
            raise ValueError(f"GNSS epochs must not go back in time: slots {slots[t_s < last].tolist()}")
        first = np.isnan(last)
        phi = np.array([math.exp(-v / s.correlation_time_s) for v in np.where(first, 0.0, t_s - last).tolist()])
        drive = np.array([s.pseudorange_sigma_m * math.sqrt(1.0 - p * p) for p in phi.tolist()])
        err = phi[:, None] * self._err[slots] + drive[:, None] * w
        err[first] = s.pseudorange_sigma_m * w[first]
        self._err[slots] = err

    def _in_outage(self, slots: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Whether each slot's receiver has lost lock at t_s (M,): Poisson starts, uniform lengths (`Gnss`)."""
        s = self.spec
        rate_per_s = s.outage_rate_per_min / 60.0
        if rate_per_s <= 0.0 or s.max_outage_s <= 0.0:
            return np.zeros(len(slots), dtype=bool)
        first = np.isnan(self._t[slots])
        # the draws are rare (a start, then one per outage): each slot's own Generator, called as `Gnss` calls it
        for k in np.flatnonzero(first | (t_s >= self._next_outage[slots])).tolist():
            i, t = int(slots[k]), float(t_s[k])
            rng = self._outage_rng[i]
            assert rng is not None
            if first[k]:
                self._next_outage[i] = t + rng.exponential(1.0 / rate_per_s)
            while t >= self._next_outage[i]:
                length = s.max_outage_s * (1.0 - rng.random())
                self._outage_end[i] = self._next_outage[i] + length
                self._next_outage[i] = self._outage_end[i] + rng.exponential(1.0 / rate_per_s)
        return t_s < self._outage_end[slots]

    def _sky_at(self, slots: np.ndarray, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which satellites each slot tracks from its position (M, S), and each one's extra (NLOS) range [m]."""
        m, n = len(slots), self.spec.satellites
        if not self.spec.urban_canyon or n == 0:
            return np.ones((m, n), dtype=bool), np.zeros((m, n))
        blocked = np.zeros((m, n), dtype=bool)
        city = self._city[slots]
        for c in np.unique(city).tolist():  # one cast per city: every satellite of every slot flying in it
            rows = np.flatnonzero(city == c)
            origins = np.repeat(position_m[rows], n, axis=0)
            hit = self._casters[c].hits_any(origins, self._los[slots[rows]].reshape(-1, 3))
            blocked[rows] = hit.reshape(len(rows), n)
        newly = blocked & ~self._blocked[slots]
        draws = self._nlos.take(slots, n)  # n draws every epoch: the stream does not depend on the geometry
        reflected = np.where(newly, draws < self.spec.nlos_probability, self._reflected[slots] & blocked)
        self._reflected[slots], self._blocked[slots] = reflected, blocked
        extra = np.zeros((m, n))
        rows = np.flatnonzero(reflected.any(axis=1))
        if len(rows):
            twice = 2.0 * self._wall_distance_m(slots[rows], position_m[rows])
            extra[rows] = np.where(reflected[rows], twice[:, None] * self._cos_el[slots[rows]], 0.0)
        return ~blocked | reflected, extra

    def _wall_distance_m(self, slots: np.ndarray, position_m: np.ndarray) -> np.ndarray:
        """Horizontal distance (M,) [m] from each position to the nearest wall of its city reaching its height."""
        out = np.zeros(len(slots))
        city = self._city[slots]
        for c in np.unique(city).tolist():
            rows = np.flatnonzero(city == c)
            bmap = self._cities[c]
            k = min(_WALLS, len(bmap.building_ids))
            if k == 0:
                continue
            p = position_m[rows]
            pts, _, _ = bmap.nearest_obstacles_batch(p, k)
            horiz = np.hypot(pts[:, :, 0] - p[:, 0:1], pts[:, :, 1] - p[:, 1:2])
            tall = pts[:, :, 2] >= p[:, 2:3] - 1e-9  # the nearest point is on a wall, not on a roof below
            out[rows] = np.where(tall.any(axis=1), np.where(tall, horiz, np.inf).min(axis=1), horiz.min(axis=1))
        return out

    def _solve(self, slots: np.ndarray, t_s: np.ndarray, position_m: np.ndarray, velocity_m_s: np.ndarray,
               tracked: np.ndarray, extra: np.ndarray, n_sat: int) -> list[GnssFix | None]:
        """Least-squares fixes of slots that each track n_sat satellites (`Gnss.measure`'s solution and DOP)."""
        m = len(slots)
        cols = np.nonzero(tracked)[1].reshape(m, n_sat)  # each slot's tracked satellites, in order
        los = self._los[slots[:, None], cols]
        h = np.concatenate((-los, np.ones((m, n_sat, 1))), axis=2)
        # Hᵀ as a view of H, as a single receiver's h.T: BLAS then sums in its order (a copy would not)
        rhs = h.transpose(0, 2, 1) @ (self._err[slots[:, None], cols] + extra[np.arange(m)[:, None], cols])[:, :, None]
        fresh = ~(self._geo_valid[slots] & (tracked == self._geo_tracked[slots]).all(axis=1))
        if fresh.any():
            self._geometry(slots[fresh], h[fresh], tracked[fresh])
        good = self._geo_ok[slots]
        out: list[GnssFix | None] = [None] * m
        if not good.any():
            return out
        err = np.linalg.solve(self._geo_hth[slots[good]], rhs[good])[:, :3, 0]
        pos = position_m[good] + err
        dop = self._geo_dop[slots[good]].tolist()
        sig, sig_v = self.spec.pseudorange_sigma_m, self.spec.velocity_sigma_m_s
        for k, r in enumerate(np.flatnonzero(good).tolist()):
            hdop, vdop = dop[k]
            p, v = pos[k], velocity_m_s[r].copy()
            p.setflags(write=False)
            v.setflags(write=False)
            out[r] = GnssFix(float(t_s[r]), p, v, n_sat, hdop, vdop, sig * hdop, sig * vdop, sig_v)
        return out

    def _geometry(self, slots: np.ndarray, h: np.ndarray, tracked: np.ndarray) -> None:
        """HᵀH of slots' geometries h (M, n, 4), whether each is usable, and its HDOP and VDOP (`gnss.dop`)."""
        hth = h.transpose(0, 2, 1) @ h
        ok = ~(np.linalg.cond(hth) > _MAX_COND)
        self._geo_hth[slots], self._geo_ok[slots] = hth, ok
        self._geo_tracked[slots], self._geo_valid[slots] = tracked, True
        if ok.any():
            g = np.linalg.inv(hth[ok])
            self._geo_dop[slots[ok]] = np.sqrt(np.stack((g[:, 0, 0] + g[:, 1, 1], g[:, 2, 2]), axis=1))
