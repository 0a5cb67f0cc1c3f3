"""The onboard estimation of N vehicles at once: `Onboard`'s sensors and navigation filter for a training batch.

`uam_fdm.sensing.onboard.Onboard` turns one vehicle's flown control periods into sensor readings and a navigation
estimate. `BatchOnboard` does the same for N slots (the episodes a batched environment steps together): per slot its
own sensing seed and random streams, its own atmosphere (barometer), city (GNSS lines of sight in the urban canyon)
and, when lidar casters are given, true world for the lidar (`uam_fdm.sensing.batch_lidar.BatchLidar`), and its own
clock; a slot is reset on its own when its episode ends. Without lidar casters no lidar is simulated (and nothing
else changes: the lidar draws from its own stream). Each control period:

* the IMU samples the physics substeps every `round(physics_hz / imu.rate_hz)` steps (their mean acceleration and
  rates, as `Onboard.advance` averages them) and the batched filter (`BatchNavFilter`) predicts with each sample;
* the barometer, heading aid, GNSS receiver and lidar sample at the period's end when their epoch has come, in
  that order, and the filter fuses the first three.

A slot's numbers are `Onboard`'s for the same seed and true states, bit for bit, and do not depend on the other
slots or on N (tests/uam_fdm/sensing/test_batch_onboard.py): the same Generators drawn in the same order
(`SlotStreams`), the same floating-point operations per slot, and a filter whose rows never mix.

Latency: `Onboard.observation` hands a decision the current estimate (the filter fuses each reading at its own
time and carries the estimate to the present with the IMU, as EKF2's output predictor does); the sensing latency
delays only the readings handed over (lidar scans, fixes). So `estimates` is the estimate at the end of the last
period sensed, as `Onboard.observation(t).x` is, and `lidar_scans(t)` are the scans `Onboard.observation(t)` hands
over (those at least `latency_s` old not handed over before); a `BatchOnboard` hands over no other readings.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.sensing.batch_gnss import BatchGnss
from uam_fdm.sensing.batch_lidar import BatchLidar
from uam_fdm.sensing.batch_sensors import BatchBarometer, BatchHeading, BatchImu, yaw_rad
from uam_fdm.sensing.gnss import GnssFix
from uam_fdm.sensing.lidar import LidarScan
from uam_fdm.sensing.nav_filter import BatchNavFilter, NavEstimate
from uam_fdm.sensing.onboard import _STREAMS, GRAVITY_M_S2, filter_tuning, initial_estimate
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import SensingConfig
from uam_fdm.vehicle.attitude import rotation_matrices

N_ESTIMATED = 13  # [p (3), v (3), q (4), ω (3)]: the vehicle-state layout's first 13 elements


@dataclass(frozen=True)
class SlotEstimates:
    """The navigation estimates of M slots.

    Attributes:
        t_s: (M,) each estimate's time on its slot's clock: the end of the last period sensed [s] (the filter
            stands at the last IMU sample, at most one IMU interval before it, as `Onboard`'s).
        state: (M, 13) the estimated vehicle state in `uam_fdm.vehicle.model`'s layout: position [m] and velocity
            [m/s], world ENU; attitude quaternion [w, x, y, z], body FLU -> world ENU; body rates [rad/s], body
            FLU, as the autopilot sees them (the last gyro sample minus the estimated gyro bias; the true rates
            before the first sample). Rotor speeds (the ESCs report them) are the caller's.
        position_covariance_m2: (M, 3, 3) the filter's covariance of the position error, world ENU [m²].
    """

    t_s: np.ndarray
    state: np.ndarray
    position_covariance_m2: np.ndarray

    @property
    def sigma_max_m(self) -> np.ndarray:
        """(M,) the standard deviation along the position error ellipsoid's longest axis [m] (computed when asked:
        an eigen-decomposition per slot)."""
        return np.sqrt(np.maximum(np.linalg.eigvalsh(self.position_covariance_m2)[:, -1], 0.0))


class BatchOnboard:
    """The sensors (the lidar when asked for) and navigation filters of N vehicle slots.

    Args:
        config: the sensing level (not `perfect`: nothing would be simulated).
        physics_dt_s: the physics step [s] (the substeps `advance` receives).
        n: number of slots.
        atmospheres: the pool of true atmospheres the slots fly in (the barometer reads their pressure); a slot's
            is chosen at `reset`.
        cities: the pool of TRUE cities (GNSS reflections); needed when `config.gnss.urban_canyon`.
        casters: one ray caster per city of `cities` (GNSS lines of sight; built once per city by the caller);
            needed when `config.gnss.urban_canyon`.
        compiled: the filter's backend (`BatchNavFilter`): None compiles when a compiler exists.
        lidar_casters: one ray caster per TRUE world the slots may fly in (buildings, unmapped obstacles, ground),
            for the lidar `config.lidar` (a slot's world is chosen at `reset`); empty: no lidar is simulated.

    Raises:
        ValueError: `perfect` sensing, a non-positive step or slot count, no atmosphere, an urban canyon
            without one caster per city, or a lidar spec out of range.
    """

    def __init__(self, config: SensingConfig, physics_dt_s: float, n: int, atmospheres: Sequence[Atmosphere], *,
                 cities: Sequence[BuildingMap] = (), casters: Sequence[RayCaster] = (),
                 compiled: bool | None = None, lidar_casters: Sequence[RayCaster] = ()) -> None:
        if config.perfect:
            raise ValueError("perfect sensing simulates nothing onboard: fly on the truth instead")
        if not physics_dt_s > 0.0 or not np.isfinite(physics_dt_s):
            raise ValueError(f"physics_dt_s must be a positive number of seconds, got {physics_dt_s!r}")
        if int(n) < 1:
            raise ValueError(f"n must be at least 1 slot, got {n!r}")
        if not atmospheres:
            raise ValueError("atmospheres: at least one atmosphere is needed (the barometer reads its pressure)")
        self.config, self.dt, self.n = config, float(physics_dt_s), int(n)
        self.n_cities = len(cities)
        self.imu = BatchImu(config.imu, self.n)
        self.baro = BatchBarometer(config.baro, atmospheres, self.n)
        self.heading = BatchHeading(config.heading, self.n)
        self.gnss = BatchGnss(config.gnss, self.n, cities, casters)
        self.lidar = BatchLidar(config.lidar, self.n, lidar_casters) if lidar_casters else None
        self.imu_stride = max(1, int(round(1.0 / (config.imu.rate_hz * self.dt))))
        # a placeholder start per slot until its first reset (a slot never reset cannot advance)
        still = NavEstimate.initial(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), config.imu)
        # tuned as Onboard tunes its filter (the same keyword options, whatever they become)
        self.filter = BatchNavFilter(config.imu, config.baro, config.heading, [still] * self.n,
                                     compiled=compiled, **filter_tuning(config))  # type: ignore[arg-type]
        self.active = np.zeros(self.n, dtype=bool)
        self._rate0 = np.zeros((self.n, 3))  # the true body rates at the start [rad/s]
        self._last_gyro = np.zeros((self.n, 3))  # each slot's last gyro sample [rad/s], body
        self._has_gyro = np.zeros(self.n, dtype=bool)
        # the physics steps since each slot's last IMU sample: their ENU accelerations [m/s²] and body rates [rad/s]
        self._pending_a = np.zeros((self.n, self.imu_stride, 3))
        self._pending_w = np.zeros((self.n, self.imu_stride, 3))
        self._pending = np.zeros(self.n, dtype=np.intp)
        sensors = ("baro", "heading", "gnss") + (("lidar",) if self.lidar is not None else ())
        self._next = {name: np.zeros(self.n) for name in sensors}  # each sensor's next epoch [s]
        self._t_sensed = np.zeros(self.n)  # the end of each slot's last period sensed [s]

    @property
    def latency_s(self) -> float:
        """The level's sensing latency [s] (it delays readings, not the estimate: see the module docstring)."""
        return self.config.latency_s

    # ---- episodes ------------------------------------------------------------------------------------------------
    def reset(self, slots: Sequence[int] | np.ndarray, seeds: Sequence[int] | np.ndarray, x0: np.ndarray, *,
              city: Sequence[int] | np.ndarray | None = None, field: Sequence[int] | np.ndarray | None = None,
              t0_s: float | np.ndarray = 0.0, truth: Sequence[int] | np.ndarray | None = None) -> None:
        """Start a new episode in each of `slots`, as `Onboard.__init__` starts one: the slot's sensors re-seeded
        from its sensing seed, the first barometer reading taken, the filter started from the pad's survey (and
        the lidar's scans not handed over dropped).

        Args:
            slots: (M,) distinct slot indices.
            seeds: (M,) each episode's sensing seed (non-negative integers).
            x0: (M, 13 + n_rotors) the true initial states (`uam_fdm.vehicle.model` layout).
            city: (M,) each slot's city, an index of `cities` (None: 0).
            field: (M,) each slot's atmosphere, an index of `atmospheres` (None: 0).
            t0_s: the start time(s) on each slot's clock [s], scalar or (M,).
            truth: (M,) each slot's true world for the lidar, an index of `lidar_casters` (None: its city index);
                only with lidar casters.

        Raises:
            ValueError: naming the argument: shapes that do not match `slots`, repeated or out-of-range slots,
                negative seeds, non-finite states, out-of-range city, field or truth indices, a truth without lidar.
        """
        idx = self._slot_array(slots)
        m = len(idx)
        seed = _integers("seeds", seeds, m, 0, None)
        x = _finite_rows("x0", x0, m)
        where = _integers("city", np.zeros(m, int) if city is None else city, m, 0, max(self.n_cities, 1) - 1)
        air = _integers("field", np.zeros(m, int) if field is None else field, m, 0, self.baro.fields - 1)
        t0 = _times("t0_s", t0_s, m)
        world = self._lidar_worlds(truth, where, m)
        initial = []
        for k, i in enumerate(idx.tolist()):
            # Onboard's streams: one child of the seed per sensor (`_STREAMS` names them, in Onboard's order)
            rngs = dict(zip(_STREAMS, (np.random.default_rng(s)
                                       for s in np.random.SeedSequence(int(seed[k])).spawn(len(_STREAMS)))))
            self.imu.restart(i, rngs["imu"])
            self.baro.restart(i, rngs["baro"], int(air[k]), float(x[k, 2]))
            self.gnss.restart(i, rngs["gnss"], int(where[k]))
            self.heading.restart(i, rngs["heading"])
            if self.lidar is not None:
                self.lidar.restart(i, rngs["lidar"], int(world[k]))
            initial.append(rngs["initial"])
        self._pending[idx], self._has_gyro[idx] = 0, False
        self._rate0[idx], self._t_sensed[idx] = x[:, 10:13], t0
        for name in self._next:
            self._next[name][idx] = t0
        first = self.baro.measure(idx, t0, x[:, 2]).tolist()  # the reading the filter's height is aligned to
        for k, i in enumerate(idx.tolist()):
            self.filter.restart(i, initial_estimate(self.config, x[k], float(t0[k]), first[k], initial[k]))
        self.active[idx] = True

    def _lidar_worlds(self, truth: Sequence[int] | np.ndarray | None, city: np.ndarray, m: int) -> np.ndarray:
        """Each slot's lidar world (M,) from `reset`'s `truth` (None: the city index), checked."""
        if self.lidar is None:
            if truth is not None:
                raise ValueError("truth picks a lidar world, but no lidar_casters were given (no lidar is simulated)")
            return city
        return _integers("truth (None: the city index)", city if truth is None else truth, m, 0,
                         self.lidar.worlds - 1)

    # ---- the truth of one control period in ----------------------------------------------------------------------
    def advance(self, x_start: np.ndarray, states: np.ndarray, t_start_s: float | np.ndarray,
                slots: Sequence[int] | np.ndarray | None = None) -> None:
        """Sense and fuse one flown control period of each of `slots` (`Onboard.advance`).

        Args:
            x_start: (M, nx) the true states at the period's start (`uam_fdm.vehicle.model` layout).
            states: (M, S, nx) the true states after each of the period's S physics steps (`PeriodResult.states`).
            t_start_s: the period's start on each slot's clock [s], scalar or (M,).
            slots: (M,) the slots that flew the period, each reset before (None: all N).

        Raises:
            ValueError: naming the argument: shapes that do not match, slots not reset, non-finite states (a
                slot whose flight diverged has ended: leave it out).
        """
        idx = np.arange(self.n) if slots is None else self._slot_array(slots)
        if not self.active[idx].all():
            raise ValueError(f"slots {idx[~self.active[idx]].tolist()} were never reset: call reset first")
        m = len(idx)
        x0 = _finite_rows("x_start", x_start, m)
        xs = np.asarray(states, dtype=np.float64)
        if xs.ndim != 3 or xs.shape[0] != m or xs.shape[1] < 1 or xs.shape[2] != x0.shape[1]:
            raise ValueError(f"states must be (M={m}, S, nx={x0.shape[1]}) physics-step states, got {xs.shape}")
        bad = ~np.isfinite(xs).all(axis=(1, 2))
        if bad.any():
            raise ValueError(f"states of slots {idx[bad].tolist()} are not finite (a diverged flight has ended)")
        t0 = _times("t_start_s", t_start_s, m)
        t_end = t0 + xs.shape[1] * self.dt
        self._predict(idx, x0, xs, t0)
        self._sense(idx, xs[:, -1], t_end)
        self._t_sensed[idx] = t_end

    def _predict(self, idx: np.ndarray, x_start: np.ndarray, states: np.ndarray, t_start: np.ndarray) -> None:
        """IMU samples of the period from the physics steps, and the filter's prediction with each."""
        stride = self.imu_stride
        accel = np.diff(np.concatenate((x_start[:, None, 3:6], states[:, :, 3:6]), axis=1), axis=1) / self.dt
        pending = self._pending[idx]
        for c in np.unique(pending).tolist():  # slots with as many steps carried over sample alike
            g = np.flatnonzero(pending == c)
            whole = len(g) == len(idx)  # the common case: no copies of the group's rows
            s, st, t_g = (idx, states, t_start) if whole else (idx[g], states[g], t_start[g])
            a_all = np.concatenate((self._pending_a[s, :c], accel if whole else accel[g]), axis=1)
            w_all = np.concatenate((self._pending_w[s, :c], st[:, :, 10:13]), axis=1)
            k = a_all.shape[1] // stride
            if k:
                last = np.arange(1, k + 1) * stride - 1 - c  # each sample's last physics step in this period
                mg = len(g)
                rot = rotation_matrices(st[:, last, 6:10].reshape(-1, 4))
                # the mean over each sample's steps as np.mean computes it (sum, then / count), without its overhead
                a_mean = np.add.reduce(a_all[:, :k * stride].reshape(mg, k, stride, 3), axis=2) / stride + np.array(
                    [0.0, 0.0, GRAVITY_M_S2])
                force = np.einsum("kji,kj->ki", rot, a_mean.reshape(-1, 3)).reshape(mg, k, 3)  # Rᵀ (a - g), FLU
                w_mean = np.add.reduce(w_all[:, :k * stride].reshape(mg, k, stride, 3), axis=2) / stride
                t = t_g[:, None] + (last + 1) * self.dt
                accel_m, gyro_m = self.imu.measure(s, t, force, w_mean)
                self._predict_samples(s, t, accel_m, gyro_m)
                self._last_gyro[s], self._has_gyro[s] = gyro_m[:, -1], True
            rest = a_all.shape[1] - k * stride
            self._pending_a[s, :rest] = a_all[:, k * stride:]
            self._pending_w[s, :rest] = w_all[:, k * stride:]
            self._pending[s] = rest

    def _predict_samples(self, s: np.ndarray, t: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> None:
        """The filter through each of slots s's K samples (t (M, K) [s], accel (M, K, 3), gyro (M, K, 3)), one
        batched call per sample; the other slots keep their time, so the filter leaves them as they are."""
        nav = self.filter
        a_full, g_full = np.zeros((self.n, 3)), np.zeros((self.n, 3))
        for j in range(t.shape[1]):
            t_full = nav.t_s.copy()
            t_full[s], a_full[s], g_full[s] = t[:, j], accel[:, j], gyro[:, j]
            nav.predict(t_full, a_full, g_full)

    def _sense(self, idx: np.ndarray, x_end: np.ndarray, t_end: np.ndarray) -> None:
        """The barometer, heading aid and GNSS of slots idx at the period's end t_end (M,) [s], when due, fused."""
        cfg, nav = self.config, self.filter
        due = _due(self._next["baro"], idx, cfg.baro.rate_hz, t_end)
        if due.any():
            nav.fuse_baro(idx[due], self.baro.measure(idx[due], t_end[due], x_end[due, 2]))
        due = _due(self._next["heading"], idx, cfg.heading.rate_hz, t_end)
        if due.any():
            nav.fuse_heading(idx[due], self.heading.measure(idx[due], t_end[due], yaw_rad(x_end[due, 6:10])))
        due = _due(self._next["gnss"], idx, cfg.gnss.rate_hz, t_end)
        if due.any():
            fixes = self.gnss.measure(idx[due], t_end[due], x_end[due, 0:3], x_end[due, 3:6])
            if any(f is not None for f in fixes):
                every: list[GnssFix | None] = [None] * self.n
                for i, f in zip(idx[due].tolist(), fixes):
                    every[i] = f
                nav.update_gnss(every)
        if self.lidar is not None:
            due = _due(self._next["lidar"], idx, cfg.lidar.rate_hz, t_end)
            if due.any():
                at = idx[due]  # stamped with each filter's pose now, the period's readings fused (as `Onboard`)
                self.lidar.measure(at, t_end[due], x_end[due, 0:3], x_end[due, 6:10],
                                   np.concatenate((nav.x[at, 0:3], nav.x[at, 6:10]), axis=1))

    # ---- belief out ----------------------------------------------------------------------------------------------
    def estimates(self, slots: Sequence[int] | np.ndarray | None = None) -> SlotEstimates:
        """The current estimates of `slots` (None: all N), as a decision receives them (see the module docstring)."""
        idx = np.arange(self.n) if slots is None else self._slot_array(slots)
        nav = self.filter
        state = np.concatenate((nav.x[idx, 0:10], self._measured_rate(idx)), axis=1)
        return SlotEstimates(self._t_sensed[idx].copy(), state, nav.P[idx, 0:3, 0:3].copy())

    def lidar_scans(self, t_s: float | np.ndarray, slots: Sequence[int] | np.ndarray | None = None
                    ) -> list[tuple[LidarScan, ...]]:
        """The lidar scans handed to a decision at `t_s` on each slot's clock, as `Onboard.observation(t_s)` hands
        them over: per slot, in time order, its scans at least `latency_s` old that no earlier call took (each is
        handed over once, then dropped).

        Args:
            t_s: the decision's time(s) [s], scalar or (M,).
            slots: (M,) the slots, each reset before (None: all N).

        Returns:
            per slot a tuple of its scans (body FLU directions, measured ranges [m]).

        Raises:
            ValueError: no lidar casters were given, or slots not reset, or times that do not match the slots.
        """
        if self.lidar is None:
            raise ValueError("no lidar is simulated: give BatchOnboard lidar_casters to get scans")
        idx = np.arange(self.n) if slots is None else self._slot_array(slots)
        if not self.active[idx].all():
            raise ValueError(f"slots {idx[~self.active[idx]].tolist()} were never reset: call reset first")
        # the same float expression as `Onboard.observation`'s, so a scan at the boundary goes the same way
        seen = _times("t_s", t_s, len(idx)) - self.config.latency_s + 1e-9
        return self.lidar.hand_over(idx, seen)

    def _measured_rate(self, idx: np.ndarray) -> np.ndarray:
        """Body rates as the autopilot sees them (M, 3) [rad/s]: the last gyro sample minus the estimated bias."""
        rate = self._last_gyro[idx] - self.filter.x[idx, 13:16]
        return np.where(self._has_gyro[idx, None], rate, self._rate0[idx])

    def controller_offset(self, x_true: np.ndarray, slots: Sequence[int] | np.ndarray | None = None) -> np.ndarray:
        """The current estimates' errors (M, `uam_fdm.vehicle.dynamics.N_SEEN_OFFSET`) for the velocity controller,
        as `Onboard.controller_offset`: [δp m, δv m/s world ENU, δq = q_true⁻¹ ⊗ q_est, δω = measured minus true
        body rate rad/s], against the true states x_true (M, nx)."""
        idx = np.arange(self.n) if slots is None else self._slot_array(slots)
        x = _finite_rows("x_true", x_true, len(idx))
        est = self.filter.x[idx]
        a = x[:, 6:10] * np.array([1.0, -1.0, -1.0, -1.0])  # q_true⁻¹ of a unit quaternion
        b = est[:, 6:10]
        av, bv = a[:, 1:4], b[:, 1:4]
        # the vector dot product as a stacked matmul: BLAS's dot per slot, as `Onboard`'s `av @ bv` computes it
        w = a[:, 0] * b[:, 0] - (av[:, None, :] @ bv[:, :, None])[:, 0, 0]
        vec = a[:, 0:1] * bv + b[:, 0:1] * av + np.cross(av, bv)
        return np.concatenate((est[:, 0:3] - x[:, 0:3], est[:, 3:6] - x[:, 3:6], w[:, None], vec,
                               self._measured_rate(idx) - x[:, 10:13]), axis=1)

    @property
    def gnss_availability(self) -> np.ndarray:
        """(N,) each slot's share of GNSS epochs with a fix since its reset (NaN before its first epoch)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.gnss.epochs > 0, self.gnss.fixes / np.maximum(self.gnss.epochs, 1), np.nan)

    # ---- checks --------------------------------------------------------------------------------------------------
    def _slot_array(self, slots: Sequence[int] | np.ndarray) -> np.ndarray:
        idx = np.asarray(slots)
        if idx.ndim != 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
            raise ValueError(f"slots must be a 1-D sequence of slot indices, got {np.asarray(slots)!r:.80}")
        idx = idx.astype(np.intp)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n):
            raise ValueError(f"slots must lie in [0, {self.n}), got {idx[(idx < 0) | (idx >= self.n)].tolist()}")
        if len(np.unique(idx)) != len(idx):
            raise ValueError(f"slots must be distinct, got {idx.tolist()}")
        return idx


def _due(next_t: np.ndarray, idx: np.ndarray, rate_hz: float, t_s: np.ndarray) -> np.ndarray:
    """Which of slots idx have a sensor epoch at t_s (M,) [s], moving their next epoch on (`Onboard._due`)."""
    nxt = next_t[idx]
    due = ~(t_s + 1e-9 < nxt)
    if due.any():
        periods = np.maximum(1.0, np.floor((t_s[due] - nxt[due]) * rate_hz + 1e-9) + 1.0)
        next_t[idx[due]] = nxt[due] + 1.0 / rate_hz * periods
    return due


def _finite_rows(name: str, value: np.ndarray, m: int) -> np.ndarray:
    """`value` as (m, nx) finite float64 states with nx >= 13, or ValueError naming `name`."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != m or a.shape[1] < N_ESTIMATED:
        raise ValueError(f"{name} must be (M={m}, 13 + n_rotors) states, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} has non-finite values in rows {np.flatnonzero(~np.isfinite(a).all(axis=1)).tolist()}")
    return a


def _integers(name: str, value: Sequence[int] | np.ndarray, m: int, low: int, high: int | None) -> np.ndarray:
    """`value` as (m,) integers in [low, high] (high None: unbounded), or ValueError naming `name`."""
    a = np.asarray(value)
    if a.shape != (m,) or (m and not np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{name} must be {m} integers (one per slot), got {np.asarray(value)!r:.80}")
    out = (a < low) | ((a > high) if high is not None else False)
    if np.any(out):
        bound = f"[{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"{name} must be {bound}, got {a[out].tolist()}")
    return a.astype(np.int64)


def _times(name: str, value: float | np.ndarray, m: int) -> np.ndarray:
    """`value` as (m,) finite times [s] (a scalar for all), or ValueError naming `name`."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(m, float(a))
    if a.shape != (m,) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be a finite time or {m} of them (one per slot) [s], "
                         f"got {np.asarray(value)!r:.80}")
    return a
