"""The navigation filter: an error-state EKF (after PX4's EKF2 and Solà 2017) fusing the IMU with GNSS position and
velocity, barometric altitude and a heading aid, for one vehicle or N at once.

Model and Jacobians: `uam_fdm.sensing.ekf_model` (one CasADi graph); the prediction of N vehicles is one call into
compiled code (`uam_fdm.vehicle.codegen`, cached), or CasADi's `map` without a compiler. Updates (NumPy, batched
over the vehicles that have a measurement): Kalman gain, Joseph-form covariance, injection of the error into the
nominal state, then the covariance reset with the reset Jacobian G (Solà eq. 287; EKF2 uses identity).

Measurement noise:
- GNSS: each fix's reported accuracy (horizontal 2D RMS, split evenly over east and north; vertical; velocity
  per component). The receiver's position error is time-correlated;
  a filter that takes it as white averages it down and grows overconfident. With `gnss_correlation_time_s` = τ
  > 0 the position variance is inflated by max(1, 2τ/Δt) (Δt between fixes): white noise of that variance has
  the correlated error's low-frequency power (its spectral density at 0 is 2σ²τ). 0 (default): white, as EKF2.
- Heading: noise²; the aid's slowly varying disturbance is a filter state (Gauss-Markov, σ and τ from the
  HeadingSpec), internal to the filter: a `NavEstimate` carries the 16 navigation error states.
- Baro: noise²; its drift is a state (the baro offset), a random walk at the spec's rate.

Gating: an update whose normalised innovation squared exceeds the chi-square quantile `gate_probability` is
rejected and counted (`rejections`). GNSS rejected for longer than `gnss_reset_after_s` resets position and
velocity to the fix (counted in `gnss_resets`), as EKF2 does when its innovation checks keep failing.

Timing: an update applies at the filter's current time (the last IMU sample); the caller predicts up to a
measurement before fusing it.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import casadi as ca
import numpy as np
from scipy.special import chdtri  # the chi-square quantile, without importing scipy.stats (0.5 s)

from uam_fdm.sensing import ekf_model as em
from uam_fdm.sensing.baro import BaroReading
from uam_fdm.sensing.heading import HeadingReading, wrap_angle
from uam_fdm.sensing.imu import ImuSamples
from uam_fdm.sensing.specs import BaroSpec, HeadingSpec, ImuSpec
from uam_fdm.vehicle.codegen import compile_functions
from uam_fdm.vehicle.fastcall import BatchCaller, map_rows

log = logging.getLogger(__name__)

_ATT = em.D_ATT


class GnssFixLike(Protocol):
    """What the filter reads of a GNSS fix (`uam_fdm.sensing.gnss.GnssFix` has these): sigma_h_m is the RMS of the
    2D horizontal error (σ per axis: sigma_h_m/√2), sigma_v_m the vertical σ, sigma_vel_m_s each velocity
    component's σ."""

    @property
    def t_s(self) -> float: ...
    @property
    def position_m(self) -> np.ndarray: ...
    @property
    def velocity_m_s(self) -> np.ndarray: ...
    @property
    def sigma_h_m(self) -> float: ...
    @property
    def sigma_v_m(self) -> float: ...
    @property
    def sigma_vel_m_s(self) -> float: ...


@dataclass(frozen=True)
class NavEstimate:
    """The filter's belief at one time.

    Attributes:
        t_s: time [s].
        position_m: (3,) position [m], world ENU.
        velocity_m_s: (3,) velocity [m/s], world ENU.
        quaternion: (4,) attitude [w, x, y, z], body FLU -> world ENU.
        accel_bias_m_s2: (3,) accelerometer bias [m/s²], body.
        gyro_bias_rad_s: (3,) gyro bias [rad/s], body.
        covariance: (16, 16) error covariance of [δp, δv, δθ (body), δb_a, δb_g, δb_baro].
        baro_offset_m: barometer offset [m] (baro altitude = z + offset).
    """

    t_s: float
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    quaternion: np.ndarray
    accel_bias_m_s2: np.ndarray
    gyro_bias_rad_s: np.ndarray
    covariance: np.ndarray
    baro_offset_m: float = 0.0

    @classmethod
    def initial(cls, t_s: float, position_m: np.ndarray, velocity_m_s: np.ndarray, quaternion: np.ndarray,
                imu: ImuSpec, *, position_sigma_m: float = 1.0, velocity_sigma_m_s: float = 0.3,
                tilt_sigma_rad: float = 0.03, yaw_sigma_rad: float = 0.1,
                baro_offset_sigma_m: float = 0.2) -> NavEstimate:
        """A start: the given state, zero biases and offset, a diagonal covariance (bias σ from the IMU spec)."""
        sigma = np.concatenate((np.full(3, position_sigma_m), np.full(3, velocity_sigma_m_s),
                                [tilt_sigma_rad, tilt_sigma_rad, yaw_sigma_rad],
                                np.full(3, imu.accel_bias_initial_m_s2), np.full(3, imu.gyro_bias_initial_rad_s),
                                [baro_offset_sigma_m]))
        return cls(float(t_s), np.array(position_m, float), np.array(velocity_m_s, float),
                   np.array(quaternion, float), np.zeros(3), np.zeros(3), np.diag(sigma ** 2))

    def nominal(self) -> np.ndarray:
        """The filter's nominal state vector (17,)."""
        return np.concatenate((self.position_m, self.velocity_m_s, self.quaternion, self.accel_bias_m_s2,
                               self.gyro_bias_rad_s, [self.baro_offset_m]))

    def state(self, rotor_speeds_rad_s: np.ndarray, rate_body_rad_s: np.ndarray) -> np.ndarray:
        """The vehicle-state layout (13 + n,) of `uam_fdm.vehicle.model` with the estimated p, v, q and the given
        body rates [rad/s] (e.g. gyro minus estimated bias) and rotor speeds [rad/s]."""
        return np.concatenate((self.position_m, self.velocity_m_s, self.quaternion,
                               np.asarray(rate_body_rad_s, float).reshape(3),
                               np.asarray(rotor_speeds_rad_s, float).reshape(-1)))


def _quat_conj_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a* ⊗ b for quaternions [w, x, y, z]."""
    w0, x0, y0, z0 = a[0], -a[1], -a[2], -a[3]
    w1, x1, y1, z1 = b
    return np.array([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])


def error_state(estimate: NavEstimate, true_state: np.ndarray) -> np.ndarray:
    """The true error (9,) [δp m, δv m/s, δθ rad (body, log map)] of an estimate against a true vehicle state
    (13 + n,) in the `uam_fdm.vehicle.model` layout."""
    x = np.asarray(true_state, float)
    dq = _quat_conj_mul(estimate.quaternion, x[6:10])
    dq = dq if dq[0] >= 0.0 else -dq
    vec = dq[1:4]
    norm = float(np.linalg.norm(vec))
    dtheta = vec * (2.0 * np.arctan2(norm, dq[0]) / norm) if norm > 1e-12 else 2.0 * vec
    return np.concatenate((x[0:3] - estimate.position_m, x[3:6] - estimate.velocity_m_s, dtheta))


_BLOCKS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9), "pva": slice(0, 9)}


def nees(estimate: NavEstimate, true_state: np.ndarray, block: str = "pva") -> float:
    """Normalised estimation error squared eᵀ P⁻¹ e of one block ("position", "velocity", "attitude" or "pva")."""
    sel = _BLOCKS[block]
    e = error_state(estimate, true_state)[sel]
    return float(e @ np.linalg.solve(estimate.covariance[sel, sel], e))


@dataclass
class _Counts:
    accepted: dict[str, int] = field(default_factory=lambda: {"gnss": 0, "baro": 0, "heading": 0})
    rejected: dict[str, int] = field(default_factory=lambda: {"gnss": 0, "baro": 0, "heading": 0})


class BatchNavFilter:
    """The error-state EKF for N vehicles; every operation is vectorised over them.

    Args:
        imu, baro, heading: the specs of the parts flown (the filter's noise model).
        initial: one start per vehicle (see `NavEstimate.initial`).
        gate_probability: chi-square gate on the normalised innovation (None: no gating).
        gnss_correlation_time_s: correlation time of the receiver's position error assumed by the filter (see
            module docstring); 0: white.
        gnss_reset_after_s: reset position and velocity to GNSS after it was rejected this long [s].
        baro_offset_walk_m_rthz: the random walk of the barometer's offset the filter assumes [m/√s] (None: the
            part's drift); a larger one lets the offset follow errors a datasheet's drift leaves out, such as
            pressure altitude's scale error on a non-standard day.
        compiled: True to require compiled code, False for CasADi's virtual machine, None to compile when a
            compiler exists.
        cache_dir: cache of compiled libraries (default `codegen.default_cache_dir()`).
    """

    def __init__(self, imu: ImuSpec, baro: BaroSpec, heading: HeadingSpec, initial: Sequence[NavEstimate], *,
                 gate_probability: float | None = 0.9999, gnss_correlation_time_s: float = 0.0,
                 gnss_reset_after_s: float = 5.0, baro_offset_walk_m_rthz: float | None = None,
                 compiled: bool | None = None, cache_dir: Path | None = None) -> None:
        if not initial:
            raise ValueError("a BatchNavFilter needs at least one vehicle")
        self.imu_spec, self.baro_spec, self.heading_spec = imu, baro, heading
        self.n = len(initial)
        self.t_s = np.zeros(self.n)
        self.x = np.zeros((self.n, em.NX))
        self.P = np.zeros((self.n, em.NDX, em.NDX))
        self._last_fix_t = np.full(self.n, np.nan)
        self._gnss_rejected_since = np.full(self.n, np.nan)
        for i, e in enumerate(initial):
            self.restart(i, e)
        # a heading aid without correlation time: its disturbance is white (decay factor 0 at every step)
        tau = heading.correlation_time_s if heading.correlation_time_s > 0.0 else 1e-12
        self.noise = np.array([imu.accel_noise_density_m_s2_rthz, imu.gyro_noise_density_rad_s_rthz,
                               imu.accel_bias_walk_m_s3_rthz, imu.gyro_bias_walk_rad_s2_rthz,
                               baro.drift_m_rthz if baro_offset_walk_m_rthz is None else baro_offset_walk_m_rthz,
                               heading.disturbance_rad, tau])
        self.gate_probability = gate_probability
        # the gate's chi-square quantile per measurement dimension (scipy's ppf costs tens of µs a call)
        self._gate = {m: float(chdtri(m, 1.0 - gate_probability)) if gate_probability is not None else np.inf
                      for m in (1, 6)}
        self.gnss_correlation_time_s = float(gnss_correlation_time_s)
        self.gnss_reset_after_s = float(gnss_reset_after_s)
        self.counts = _Counts()
        self.gnss_resets = 0
        self._setup_backend(compiled, cache_dir)

    def restart(self, i: int, initial: NavEstimate) -> None:
        """Start vehicle i again from `initial` (a new episode in one slot of a batch; the others are untouched):
        its state, covariance and time, the heading aid's disturbance at 0 with its stationary σ, no GNSS history.

        Raises:
            ValueError: a covariance that is not (16, 16).
        """
        pub = em.NDX_PUBLIC
        cov = np.asarray(initial.covariance, dtype=np.float64)
        if cov.shape != (pub, pub):
            raise ValueError(f"covariance must be ({pub}, {pub}), got {cov.shape}")
        self.t_s[i] = initial.t_s
        self.x[i] = np.append(initial.nominal(), 0.0)
        self.P[i] = 0.0
        self.P[i, :pub, :pub] = cov
        self.P[i, pub, pub] = self.heading_spec.disturbance_rad ** 2
        self._last_fix_t[i] = np.nan
        self._gnss_rejected_since[i] = np.nan

    # -- backend -------------------------------------------------------------------------------------------------
    def _setup_backend(self, compiled: bool | None, cache_dir: Path | None) -> None:
        self.backend, self._functions, self._vm, self._callers = _backend(compiled, cache_dir)
        self._maps: dict[tuple[str, int], ca.Function] = {}

    def _eval(self, name: str, n: int, *inputs: np.ndarray | float) -> list[np.ndarray]:
        """Evaluate Function `name` for n vehicles; each output (n, rows·cols), column-major per vehicle."""
        caller = self._callers.get(name)
        if caller is not None:
            return caller(n, *inputs)
        return map_rows(self._vm[name], self._maps, n, *inputs)

    # -- prediction ----------------------------------------------------------------------------------------------
    def predict(self, t_s: float | np.ndarray, accel_m_s2: np.ndarray, gyro_rad_s: np.ndarray) -> None:
        """Propagate every vehicle to its IMU sample at t_s [s] (one time for all, or (N,)).

        Args:
            t_s: sample time(s) [s]; a vehicle whose sample is not after its current time is left unchanged.
            accel_m_s2: (N, 3) measured specific force [m/s²], body.
            gyro_rad_s: (N, 3) measured rates [rad/s], body.
        """
        t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), (self.n,))
        dt = t - self.t_s
        imu = np.concatenate((np.asarray(accel_m_s2, float).reshape(self.n, 3),
                              np.asarray(gyro_rad_s, float).reshape(self.n, 3)), axis=1)
        moving = dt > 0.0
        if moving.all():
            dt_in: np.ndarray | float = float(dt[0]) if np.all(dt == dt[0]) else dt[:, None]
            x_next, p_next = self._eval("nav_predict", self.n, self.x, self.P.reshape(self.n, -1), imu, dt_in,
                                        self.noise)
            self.x, self.P = x_next, p_next.reshape(self.n, em.NDX, em.NDX)
        elif moving.any():
            idx = np.flatnonzero(moving)
            x_next, p_next = self._eval("nav_predict", idx.size, self.x[idx], self.P[idx].reshape(idx.size, -1),
                                        imu[idx], dt[idx, None], self.noise)
            self.x[idx], self.P[idx] = x_next, p_next.reshape(idx.size, em.NDX, em.NDX)
        self.t_s = np.where(moving, t, self.t_s)

    def predict_samples(self, samples: Sequence[ImuSamples]) -> None:
        """Propagate vehicle i through samples[i] (all with the same number of samples)."""
        count = {s.t_s.size for s in samples}
        if len(samples) != self.n or len(count) != 1:
            raise ValueError("predict_samples needs one ImuSamples per vehicle, all of one length")
        t = np.stack([s.t_s for s in samples], axis=1)
        accel = np.stack([s.accel_m_s2 for s in samples], axis=1)
        gyro = np.stack([s.gyro_rad_s for s in samples], axis=1)
        for k in range(t.shape[0]):
            self.predict(t[k], accel[k], gyro[k])

    # -- updates -------------------------------------------------------------------------------------------------
    def _update(self, kind: str, idx: np.ndarray, z: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Fuse measurements z (M, m) with covariances r (M, m, m) into vehicles idx (M,); returns accepted (M,)."""
        if kind in em.SCALAR_AIDS:
            return self._update_scalar(kind, idx, z, r)
        m = idx.size
        x, p = self.x[idx], self.P[idx]
        h, h_jac = self._eval(f"nav_measure_{kind}", m, x)
        dim = z.shape[1]
        h_jac = h_jac.reshape(m, em.NDX, dim).transpose(0, 2, 1)
        y = z - h
        if kind == "heading":
            y = wrap_angle(y)
        pht = p @ h_jac.transpose(0, 2, 1)
        s = h_jac @ pht + r
        s_inv = np.linalg.inv(s)
        nis = np.einsum("mi,mij,mj->m", y, s_inv, y)
        accepted = nis <= self._gate[dim]
        self.counts.accepted[kind] += int(accepted.sum())
        self.counts.rejected[kind] += int(m - accepted.sum())
        if not accepted.any():
            return accepted
        sel = np.flatnonzero(accepted)
        gain = pht[sel] @ s_inv[sel]
        dx = np.einsum("mij,mj->mi", gain, y[sel])
        ikh = np.eye(em.NDX) - gain @ h_jac[sel]
        p_new = ikh @ p[sel] @ ikh.transpose(0, 2, 1) + gain @ r[sel] @ gain.transpose(0, 2, 1)
        (x_new,) = self._eval("nav_inject", sel.size, x[sel], dx)
        (g,) = self._eval("nav_reset_jacobian", sel.size, dx)
        g = g.reshape(sel.size, em.NDX, em.NDX).transpose(0, 2, 1)
        p_new = g @ p_new @ g.transpose(0, 2, 1)
        rows = idx[sel]
        self.x[rows] = x_new
        self.P[rows] = 0.5 * (p_new + p_new.transpose(0, 2, 1))
        return accepted

    def _update_scalar(self, kind: str, idx: np.ndarray, z: np.ndarray, r: np.ndarray) -> np.ndarray:
        """`_update` of a scalar aid in one compiled call per batch (the general path's arithmetic, generated)."""
        m = idx.size
        # every vehicle in order (a batch fusing all its barometers): views, not copies of (N, 17, 17)
        whole = m == self.n and bool((idx == np.arange(m)).all())
        x_in, p_in = (self.x, self.P.reshape(m, -1)) if whole else (self.x[idx], self.P[idx].reshape(m, -1))
        x_new, p_new, nis = self._eval(f"nav_update_{kind}", m, x_in, p_in, z.reshape(m, 1), r.reshape(m, 1))
        accepted = nis[:, 0] <= self._gate[1]
        self.counts.accepted[kind] += int(accepted.sum())
        self.counts.rejected[kind] += int(m - accepted.sum())
        rows = idx[accepted]
        if whole and rows.size == m:
            self.x, self.P = x_new, p_new.reshape(m, em.NDX, em.NDX)
        elif rows.size:
            self.x[rows] = x_new[accepted]
            self.P[rows] = p_new[accepted].reshape(rows.size, em.NDX, em.NDX)
        return accepted

    def update_gnss(self, fixes: Sequence[GnssFixLike | None]) -> np.ndarray:
        """Fuse fixes[i] (None: none) into vehicle i; returns (N,) True where a fix was fused."""
        idx = np.array([i for i, f in enumerate(fixes) if f is not None], dtype=np.intp)
        fused = np.zeros(self.n, bool)
        if idx.size == 0:
            return fused
        got = [fixes[i] for i in idx]
        z = np.array([np.concatenate((f.position_m, f.velocity_m_s)) for f in got])
        var = np.array([[0.5 * f.sigma_h_m ** 2] * 2 + [f.sigma_v_m ** 2] + [f.sigma_vel_m_s ** 2] * 3
                        for f in got])
        t_fix = np.array([f.t_s for f in got])
        if self.gnss_correlation_time_s > 0.0:
            gap = np.nan_to_num(t_fix - self._last_fix_t[idx], nan=np.inf)
            var[:, :3] *= np.maximum(1.0, 2.0 * self.gnss_correlation_time_s / np.maximum(gap, 1e-9))[:, None]
        self._last_fix_t[idx] = t_fix
        accepted = self._update("gnss", idx, z, _diag(var))
        fused[idx] = accepted
        self._gnss_recovery(idx, accepted, t_fix, z, var)
        return fused

    def _gnss_recovery(self, idx: np.ndarray, accepted: np.ndarray, t_fix: np.ndarray, z: np.ndarray,
                       var: np.ndarray) -> None:
        """Reset position and velocity to fixes that have been rejected for longer than gnss_reset_after_s."""
        since = self._gnss_rejected_since
        since[idx[accepted]] = np.nan
        first = ~accepted & np.isnan(since[idx])
        since[idx[first]] = t_fix[first]
        stale = ~accepted & (t_fix - since[idx] > self.gnss_reset_after_s)
        for k in np.flatnonzero(stale):
            i = idx[k]
            self.x[i, 0:6] = z[k]
            self.P[i, 0:6, :] = 0.0
            self.P[i, :, 0:6] = 0.0
            self.P[i, range(6), range(6)] = var[k]
            since[i] = np.nan
            self.gnss_resets += 1
            log.info("vehicle %d: GNSS rejected for over %.1f s; position and velocity reset to the fix",
                     i, self.gnss_reset_after_s)

    def update_baro(self, readings: Sequence[BaroReading | None]) -> np.ndarray:
        """Fuse readings[i] (None: none) into vehicle i; returns (N,) True where fused."""
        idx = np.array([i for i, r in enumerate(readings) if r is not None], dtype=np.intp)
        fused = np.zeros(self.n, bool)
        if idx.size:
            fused[idx] = self.fuse_baro(idx, np.array([readings[i].altitude_m for i in idx]))
        return fused

    def fuse_baro(self, idx: np.ndarray, altitude_m: np.ndarray) -> np.ndarray:
        """`update_baro` from arrays (a batch's readings, without a reading object each): barometric altitudes
        altitude_m (M,) [m above take-off] into vehicles idx (M,); returns (M,) True where fused."""
        idx = np.asarray(idx, dtype=np.intp)
        z = np.asarray(altitude_m, dtype=np.float64).reshape(idx.size, 1)
        r = np.full((idx.size, 1, 1), self.baro_spec.noise_m ** 2)
        return self._update("baro", idx, z, r)

    def update_heading(self, readings: Sequence[HeadingReading | None]) -> np.ndarray:
        """Fuse readings[i] (None: none) into vehicle i; returns (N,) True where fused."""
        idx = np.array([i for i, r in enumerate(readings) if r is not None], dtype=np.intp)
        fused = np.zeros(self.n, bool)
        if idx.size:
            fused[idx] = self.fuse_heading(idx, np.array([readings[i].yaw_rad for i in idx]))
        return fused

    def fuse_heading(self, idx: np.ndarray, yaw_rad: np.ndarray) -> np.ndarray:
        """`update_heading` from arrays: headings yaw_rad (M,) [rad, from east, counter-clockwise] into vehicles
        idx (M,); returns (M,) True where fused."""
        idx = np.asarray(idx, dtype=np.intp)
        z = np.asarray(yaw_rad, dtype=np.float64).reshape(idx.size, 1)
        r = np.full((idx.size, 1, 1), self.heading_spec.noise_rad ** 2)
        return self._update("heading", idx, z, r)

    # -- results -------------------------------------------------------------------------------------------------
    @property
    def rejections(self) -> dict[str, int]:
        """Updates rejected by the innovation gate so far, per aid."""
        return dict(self.counts.rejected)

    def estimate(self, i: int) -> NavEstimate:
        """Vehicle i's current estimate."""
        x, pub = self.x[i], em.NDX_PUBLIC
        return NavEstimate(float(self.t_s[i]), x[em.POS].copy(), x[em.VEL].copy(), x[em.QUAT].copy(),
                           x[em.ACC_BIAS].copy(), x[em.GYRO_BIAS].copy(), self.P[i, :pub, :pub].copy(),
                           float(x[16]))

    def states(self, rotor_speeds_rad_s: np.ndarray, rate_body_rad_s: np.ndarray) -> np.ndarray:
        """(N, 13 + n) vehicle states from the estimates with the given rates (N, 3) and rotor speeds (N, n)."""
        return np.concatenate((self.x[:, 0:10], np.asarray(rate_body_rad_s, float).reshape(self.n, 3),
                               np.asarray(rotor_speeds_rad_s, float).reshape(self.n, -1)), axis=1)


def _diag(var: np.ndarray) -> np.ndarray:
    """(M, m) variances -> (M, m, m) diagonal covariances."""
    out = np.zeros(var.shape + (var.shape[1],))
    idx = np.arange(var.shape[1])
    out[:, idx, idx] = var
    return out


_BACKENDS: dict[tuple[bool | None, Path | None], tuple[str, Any, dict[str, ca.Function], dict[str, BatchCaller]]] = {}


def _backend(compiled: bool | None, cache_dir: Path | None
             ) -> tuple[str, Any, dict[str, ca.Function], dict[str, BatchCaller]]:
    """The filter's Functions and their compiled callers, built once per process (an episode's filter then starts
    in microseconds, not the ~50 ms of generating and hashing the C code again)."""
    key = (compiled, cache_dir)
    if key not in _BACKENDS:
        functions = em.build_filter_functions()
        vm = {f.name(): f for f in functions.all()}
        lib = compile_functions(list(vm.values()), "uam_nav_ekf", cache_dir) if compiled is not False else None
        if lib is None and compiled:
            raise RuntimeError("compiled=True but the navigation filter could not be compiled (see the log)")
        callers = {name: BatchCaller(lib.path, f) for name, f in vm.items()} if lib is not None else {}
        _BACKENDS[key] = ("compiled" if lib is not None else "vm", functions, vm, callers)
    return _BACKENDS[key]


class NavFilter:
    """The error-state EKF for one vehicle (a `BatchNavFilter` of one: the same code path).

    Args:
        imu, baro, heading: the specs of the parts flown.
        initial: the start (see `NavEstimate.initial`).
        **options: `BatchNavFilter`'s keyword options.
    """

    def __init__(self, imu: ImuSpec, baro: BaroSpec, heading: HeadingSpec, initial: NavEstimate,
                 **options: object) -> None:
        self.batch = BatchNavFilter(imu, baro, heading, [initial], **options)  # type: ignore[arg-type]

    def predict(self, samples: ImuSamples) -> None:
        """Propagate through the IMU samples (in time order)."""
        for k in range(samples.t_s.size):
            self.batch.predict(samples.t_s[k], samples.accel_m_s2[k], samples.gyro_rad_s[k])

    def update_gnss(self, fix: GnssFixLike) -> bool:
        """Fuse a GNSS fix; False when the innovation gate rejected it."""
        return bool(self.batch.update_gnss([fix])[0])

    def update_baro(self, reading: BaroReading) -> bool:
        """Fuse a barometric altitude; False when rejected."""
        return bool(self.batch.update_baro([reading])[0])

    def update_heading(self, reading: HeadingReading) -> bool:
        """Fuse a heading; False when rejected."""
        return bool(self.batch.update_heading([reading])[0])

    @property
    def estimate(self) -> NavEstimate:
        return self.batch.estimate(0)

    @property
    def rejections(self) -> dict[str, int]:
        return self.batch.rejections

    def nees(self, true_state: np.ndarray, block: str = "pva") -> float:
        """NEES of the current estimate against a true vehicle state (13 + n,) (see `nees`)."""
        return nees(self.estimate, true_state, block)
