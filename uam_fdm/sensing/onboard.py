"""The vehicle's sensors and navigation filter, stepped beside the simulator: truth in, belief out.

Each control period the runner hands `Onboard` the true physics-rate states it just flew; `Onboard` turns them
into what the vehicle's sensors report and fuses them in the navigation filter:

* the IMU samples the specific force and body rates every `round(physics_hz / imu.rate_hz)` physics steps (the
  mean acceleration over the sample's steps, as a real IMU's anti-aliasing filter averages), and the filter
  predicts with each sample;
* the barometer, heading aid, GNSS receiver and lidar sample at the period's end when their next epoch has come
  (so none samples faster than the control rate; the shipped rates are all at or below it), and the filter fuses
  the readings in that order;
* the filter fuses each reading at its own time and hands out the estimate propagated to the present with the
  IMU: EKF2's design (a delayed fusion horizon and an output predictor), so neither a decision nor the velocity
  controller (`controller_offset`) acts on a stale state;
* the readings a decision receives (lidar scans, GNSS fixes, barometer and heading) are those at least
  `latency_s` old: what the perception stack has had time to deliver.

Nothing here is a pilot's: `Observation` carries only the estimate, its covariance and the readings.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from uam_fdm.air.atmosphere import Atmosphere
from uam_fdm.city.buildings import BuildingMap
from uam_fdm.pilot import Observation, SensorData
from uam_fdm.sensing.baro import Barometer
from uam_fdm.sensing.gnss import Gnss
from uam_fdm.sensing.heading import HeadingSensor
from uam_fdm.sensing.imu import Imu
from uam_fdm.sensing.lidar import Lidar, LidarTruth
from uam_fdm.sensing.nav_filter import NavEstimate, NavFilter
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import SensingConfig
from uam_fdm.vehicle.attitude import rotation_matrices, rotation_matrix

GRAVITY_M_S2 = 9.80665
LIDAR_HITS_KEPT = 32  # true hit points kept per scan for the viewer's lidar layer (a thinned, even subset)
NEES_95 = (0.2158, 9.3484)  # the chi-square distribution's 2.5 % and 97.5 % quantiles at 3 degrees of freedom
_STREAMS = ("imu", "baro", "gnss", "heading", "lidar", "initial")


@dataclass(frozen=True)
class NavRecord:
    """What the onboard estimation did over an episode (the simulator's record: it holds the truth's errors).

    Attributes:
        t_s: (E,) times of the estimates, one per control period's end [s].
        position_m: (E, 3) estimated position, world ENU [m].
        error_m: (E, 3) estimated minus true position, world ENU [m].
        sigma_m: (E, 3) the filter's standard deviation of each position component [m].
        nees: (E,) the position error's normalised squared size under the filter's position covariance (3 dof).
        gnss_epochs: GNSS epochs in the episode; gnss_fixes: those with a fix.
        satellites: (G,) satellites tracked at each epoch.
        lidar_hits: (H, 4) [t_s, x, y, z] a thinned set of the lidar's true hit points, world ENU [m].
        first_sensed: for each obstacle the prior map lacks that a returned lidar beam hit, sorted by building id:
            (building id, time of the first scan with such a beam [s], true range of that scan's nearest such
            beam [m]); obstacles never hit are left out.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    error_m: np.ndarray
    sigma_m: np.ndarray
    nees: np.ndarray
    gnss_epochs: int
    gnss_fixes: int
    satellites: np.ndarray
    lidar_hits: np.ndarray
    first_sensed: tuple[tuple[int, float, float], ...] = ()

    @property
    def nees_in_bounds(self) -> float:
        """Share of the estimates whose position NEES lies inside its two-sided 95 % chi-square interval (3 dof):
        about 0.95 for a consistent filter (NaN without estimates)."""
        if not len(self.nees):
            return math.nan
        return float(np.mean((self.nees >= NEES_95[0]) & (self.nees <= NEES_95[1])))

    @property
    def gnss_availability(self) -> float:
        """Share of GNSS epochs with a fix (NaN without epochs)."""
        return self.gnss_fixes / self.gnss_epochs if self.gnss_epochs else math.nan


class Onboard:
    """One vehicle's sensors and navigation filter over one episode.

    Args:
        config: the sensing level (not `perfect`: a perfect vehicle has nothing onboard to simulate).
        city: the TRUE city (lines of sight, lidar hits).
        caster: a ray caster over `city` (built once per city by the caller).
        atmosphere: the true atmosphere (the barometer reads its pressure).
        x0: the true initial state (13 + n,); the vehicle waits on the pad at t0_s.
        physics_dt_s: physics step [s].
        seed: the episode's sensing seed (every sensor's noise and the initial estimate).
        t0_s: time of the start [s].
        unmapped_ids: building ids of the obstacles in `city` the prior map lacks (when each was first sensed is
            recorded; every part of a building shares its id).
    """

    def __init__(self, config: SensingConfig, city: BuildingMap, caster: RayCaster, atmosphere: Atmosphere,
                 x0: np.ndarray, physics_dt_s: float, seed: int, t0_s: float = 0.0, *,
                 unmapped_ids: Iterable[int] = ()) -> None:
        if config.perfect:
            raise ValueError("perfect sensing simulates nothing onboard: fly on the truth instead")
        rngs = dict(zip(_STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6))))
        self.config, self.dt = config, float(physics_dt_s)
        self.imu = Imu(config.imu, rngs["imu"])
        self.baro = Barometer(config.baro, atmosphere, float(x0[2]), rngs["baro"])
        self.gnss = Gnss(config.gnss, city, caster if config.gnss.urban_canyon else None, rngs["gnss"])
        self.heading = HeadingSensor(config.heading, rngs["heading"])
        self.lidar = Lidar(config.lidar, caster, rngs["lidar"])
        self.imu_stride = max(1, int(round(1.0 / (config.imu.rate_hz * self.dt))))
        first_baro = self.baro.measure(t0_s, float(x0[2]))
        self.filter = NavFilter(config.imu, config.baro, config.heading,
                                initial_estimate(config, x0, t0_s, first_baro.altitude_m, rngs["initial"]),
                                **filter_tuning(config))
        self._rotors = np.asarray(x0[13:], float).copy()
        self._rate = np.asarray(x0[10:13], float).copy()
        # the physics steps since the last IMU sample: mean ENU acceleration [m/s²] and body rates [rad/s] of each
        self._pending_a, self._pending_w = np.zeros((0, 3)), np.zeros((0, 3))
        self._last_gyro: np.ndarray | None = None
        self._next = {name: t0_s for name in ("baro", "heading", "gnss", "lidar")}
        self._readings: deque[tuple[float, str, object]] = deque()
        self._t: list[float] = []
        self._pos: list[np.ndarray] = []
        self._err: list[np.ndarray] = []
        self._sig: list[np.ndarray] = []
        self._nees: list[float] = []
        self._sats: list[int] = []
        self._fixes = 0
        self._hits: list[np.ndarray] = []
        # each part of the true city: its building id, and whether the prior map lacks it (the lidar names parts)
        unmapped = {int(i) for i in unmapped_ids}
        self._part_id = np.array([int(b.id) for b in city.buildings], dtype=np.int64)
        self._part_unmapped = np.isin(self._part_id, np.fromiter(unmapped, np.int64, len(unmapped)))
        self._first_sensed: dict[int, tuple[float, float]] = {}
        self._remember(t0_s, x0)

    # ---- the truth of one control period in ------------------------------------------------------------------
    def advance(self, x_start: np.ndarray, states: np.ndarray, t_start_s: float) -> None:
        """Sense and fuse one flown control period: `states` (n_sub, nx) after each physics step from `x_start`."""
        n = states.shape[0]
        accel = np.diff(np.vstack([x_start[3:6], states[:, 3:6]]), axis=0) / self.dt  # mean ENU accel per step
        a_all = np.vstack([self._pending_a, accel])
        w_all = np.vstack([self._pending_w, states[:, 10:13]])
        stride, before = self.imu_stride, len(self._pending_a)
        k = len(a_all) // stride  # IMU samples completed in this period
        if k:
            last = np.arange(1, k + 1) * stride - 1 - before  # each sample's last physics step in this period
            rot = rotation_matrices(states[last, 6:10])
            a_mean = a_all[:k * stride].reshape(k, stride, 3).mean(axis=1) + np.array([0.0, 0.0, GRAVITY_M_S2])
            force = np.einsum("kji,kj->ki", rot, a_mean)  # Rᵀ (a - g): the specific force, body FLU
            w_mean = w_all[:k * stride].reshape(k, stride, 3).mean(axis=1)
            samples = self.imu.measure(t_start_s + (last + 1) * self.dt, force, w_mean)
            self.filter.predict(samples)
            self._last_gyro = samples.gyro_rad_s[-1]
        self._pending_a, self._pending_w = a_all[k * stride:], w_all[k * stride:]
        x_end, t_end = states[-1], t_start_s + n * self.dt
        self._rotors = x_end[13:].copy()
        self._sense(x_end, t_end)
        self._remember(t_end, x_end)

    def _due(self, name: str, rate_hz: float, t_s: float) -> bool:
        if t_s + 1e-9 < self._next[name]:
            return False
        self._next[name] += 1.0 / rate_hz * max(1, math.floor((t_s - self._next[name]) * rate_hz + 1e-9) + 1)
        return True

    def _sense(self, x: np.ndarray, t_s: float) -> None:
        cfg = self.config
        if self._due("baro", cfg.baro.rate_hz, t_s):
            reading = self.baro.measure(t_s, float(x[2]))
            self.filter.update_baro(reading)
            self._readings.append((t_s, "baro", reading))
        if self._due("heading", cfg.heading.rate_hz, t_s):
            h = self.heading.measure(t_s, _yaw(x[6:10]))
            self.filter.update_heading(h)
            self._readings.append((t_s, "heading", h))
        if self._due("gnss", cfg.gnss.rate_hz, t_s):
            fix = self.gnss.measure(t_s, x[0:3], x[3:6])
            self._sats.append(int(self.gnss.last_satellites))
            if fix is not None:
                self._fixes += 1
                self.filter.update_gnss(fix)
                self._readings.append((t_s, "gnss", fix))
        if self._due("lidar", cfg.lidar.rate_hz, t_s):
            scan, truth = self.lidar.scan(t_s, x[0:3], rotation_matrix(x[6:10]), truth_points=LIDAR_HITS_KEPT)
            est = self.filter.estimate  # its pose as the filter has it now, the period's readings fused
            scan = replace(scan, pose_estimate=np.concatenate((est.position_m, est.quaternion)))
            self._readings.append((t_s, "lidar", scan))
            if len(truth.points_m):
                self._hits.append(np.column_stack([np.full(len(truth.points_m), t_s), truth.points_m]))
            self._note_unmapped(t_s, truth)

    def _note_unmapped(self, t_s: float, truth: LidarTruth) -> None:
        """Remember the scan at `t_s` [s] for each unmapped obstacle its returned beams hit for the first time."""
        part = truth.part_index
        on_part = part >= 0  # not the ground
        hit = np.zeros(len(part), dtype=bool)
        hit[on_part] = self._part_unmapped[part[on_part]]
        if not hit.any():
            return
        ids, ranges = self._part_id[part[hit]], truth.ranges_m[hit]
        for bid in np.unique(ids).tolist():
            if bid not in self._first_sensed:
                self._first_sensed[bid] = (float(t_s), float(ranges[ids == bid].min()))

    def _remember(self, t_s: float, x_true: np.ndarray) -> None:
        est = self.filter.estimate
        self._current = (t_s, est, self._measured_rate())
        self._t.append(t_s)
        self._pos.append(np.asarray(est.position_m, float).copy())
        self._err.append(np.asarray(est.position_m, float) - x_true[0:3])
        self._sig.append(np.sqrt(np.clip(np.diag(est.covariance)[0:3], 0.0, None)))
        err = self._err[-1]
        self._nees.append(float(err @ np.linalg.solve(est.covariance[0:3, 0:3], err)))

    def _measured_rate(self) -> np.ndarray:
        """Body rates as the autopilot sees them: the last gyro sample minus the estimated gyro bias [rad/s]."""
        if self._last_gyro is None:
            return self._rate.copy()
        return self._last_gyro - np.asarray(self.filter.estimate.gyro_bias_rad_s, float)

    # ---- belief out --------------------------------------------------------------------------------------------
    def observation(self, t_s: float) -> Observation:
        """What a decision at `t_s` acts on: the current estimate in the vehicle-state layout, its covariance, and
        the readings at least `latency_s` old not yet handed over."""
        seen_t = t_s - self.config.latency_s + 1e-9
        t_est, est, rate = self._current
        x = est.state(self._rotors, rate)
        lists: dict[str, list] = {"lidar": [], "imu": [], "gnss": [], "baro": [], "heading": []}
        while self._readings and self._readings[0][0] <= seen_t:
            _, kind, reading = self._readings.popleft()
            lists[kind].append(reading)
        sensors = SensorData(**{k: tuple(v) for k, v in lists.items()})
        return Observation(t_s, x, covariance=np.array(est.covariance, copy=True), sensors=sensors, estimate_t_s=t_est)

    def controller_offset(self, x_true: np.ndarray) -> np.ndarray:
        """The current estimate's error (`uam_fdm.vehicle.dynamics.N_SEEN_OFFSET`,) for the velocity controller:
        [δp m, δv m/s ENU, δq = q_true⁻¹ ⊗ q_est, δω = measured minus true body rate rad/s]."""
        est = self.filter.estimate
        dq = _quat_product(_quat_conjugate(x_true[6:10]), np.asarray(est.quaternion, float))
        return np.concatenate([np.asarray(est.position_m) - x_true[0:3], np.asarray(est.velocity_m_s) - x_true[3:6],
                               dq, self._measured_rate() - x_true[10:13]])

    def estimated_position_m(self) -> np.ndarray:
        """The current estimate's position, world ENU [m]."""
        return np.asarray(self.filter.estimate.position_m, float).copy()

    def record(self) -> NavRecord:
        """The episode's estimation record so far."""
        hits = np.concatenate(self._hits) if self._hits else np.zeros((0, 4))
        first = tuple((bid, t, r) for bid, (t, r) in sorted(self._first_sensed.items()))
        return NavRecord(np.asarray(self._t), np.asarray(self._pos), np.asarray(self._err), np.asarray(self._sig),
                         np.asarray(self._nees),
                         len(self._sats), self._fixes, np.asarray(self._sats, dtype=np.int64), hits, first)


BARO_SCALE_WALK_M_RTHZ = 0.05  # the baro offset's walk for a non-standard day's scale error [m/√s]


def filter_tuning(config: SensingConfig) -> dict[str, float]:
    """How the flight controller's filter is tuned for its parts, as an integrator tunes EKF2: the receiver's
    position error is time-correlated (its correlation time known from the receiver's model), so each fix is
    de-weighted by 2τ/Δt rather than averaged as if white; the barometer's offset may walk by
    `BARO_SCALE_WALK_M_RTHZ` beyond the part's drift, for pressure altitude's scale error on a non-standard day
    (±7 % at ±20 K: 0.7 m in a 10 m climb), which no datasheet drift covers."""
    return {"gnss_correlation_time_s": config.gnss.correlation_time_s,
            "baro_offset_walk_m_rthz": math.hypot(config.baro.drift_m_rthz, BARO_SCALE_WALK_M_RTHZ)}


def initial_estimate(config: SensingConfig, x0: np.ndarray, t0_s: float, baro_m: float,
                     rng: np.random.Generator) -> NavEstimate:
    """The filter's state at the start of the task, as a vehicle that took off from a surveyed pad below it has it:
    position to the pad's survey (`PAD_SIGMA_H_M`, `PAD_SIGMA_V_M`: the errors a run measures are made in flight,
    not drawn at the start), at the start's velocity to 0.1 m/s, levelled to 1° and headed by the heading aid,
    biases from their power-on σ, and the barometer's offset set so that its first reading `baro_m` [m] agrees with
    the estimated height (as EKF2 aligns its height sources)."""
    cov = initial_covariance(config)
    err = rng.standard_normal(cov.shape[0]) * np.sqrt(np.diag(cov))
    position = x0[0:3] + err[0:3]
    q = _quat_product(np.asarray(x0[6:10], float), _small_rotation(err[6:9]))
    return NavEstimate(t_s=t0_s, position_m=position, velocity_m_s=x0[3:6] + err[3:6],
                       quaternion=q / np.linalg.norm(q), accel_bias_m_s2=np.zeros(3), gyro_bias_rad_s=np.zeros(3),
                       covariance=cov, baro_offset_m=float(baro_m - position[2]))


PAD_SIGMA_H_M = 0.3  # a surveyed pad's horizontal position, σ [m]
PAD_SIGMA_V_M = 0.1  # ... and its height (the barometer zeroed on it), σ [m]


def initial_covariance(config: SensingConfig) -> np.ndarray:
    """Error-state covariance at the start [δp, δv, δθ, δb_a, δb_g, δb_baro]: the pad's survey, velocity 0.1 m/s,
    attitude 1° (roll, pitch) and the heading aid's σ, biases from the IMU's power-on σ. The barometer's offset is
    set from the estimated height (`initial_estimate`), so its error is the height's error with the other sign plus
    the first reading's noise: the two are correlated, not independent (independent, the first readings would
    shrink the height's σ far below its error)."""
    imu, head, baro = config.imu, config.heading, config.baro
    yaw = math.hypot(head.noise_rad, head.disturbance_rad)
    sig = [PAD_SIGMA_H_M, PAD_SIGMA_H_M, PAD_SIGMA_V_M, 0.1, 0.1, 0.1, math.radians(1.0), math.radians(1.0), yaw,
           *[imu.accel_bias_initial_m_s2] * 3, *[imu.gyro_bias_initial_rad_s] * 3, 0.0]
    cov = np.diag(np.square(sig))
    cov[15, 15] = PAD_SIGMA_V_M ** 2 + baro.noise_m ** 2
    cov[2, 15] = cov[15, 2] = -PAD_SIGMA_V_M ** 2
    return cov


def _yaw(q: np.ndarray) -> float:
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, av, bw, bv = a[0], a[1:4], b[0], b[1:4]
    return np.concatenate([[aw * bw - av @ bv], aw * bv + bw * av + np.cross(av, bv)])


def _quat_conjugate(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _small_rotation(theta: np.ndarray) -> np.ndarray:
    """The unit quaternion of rotation vector `theta` [rad]."""
    angle = float(np.linalg.norm(theta))
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * theta / angle])
