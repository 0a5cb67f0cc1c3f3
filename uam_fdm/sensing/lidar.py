"""A spinning multi-channel lidar: beams cast exactly against the true city, with range noise and dropout.

Model (per `LidarSpec`): `channels` beams spread evenly over the vertical field of view, `columns` azimuths over
360° (azimuth 0 straight ahead along body x, counter-clockwise towards body y, FLU); a whole scan is taken at
one instant from the true pose (the motion during a 0.1 s revolution is not modelled). A beam returns when its
first true hit (buildings, unmapped obstacles, ground) lies within [min_range_m, max_range_m]; a returning
beam is then lost with probability `dropout` (dark, glass or grazing surfaces), and its range carries Gaussian
noise of σ = range_noise_m + range_noise_per_m · range. Beams that return nothing are left out of the scan.
Beside the scan, `LidarTruth` keeps what each returned beam truly hit (the city's part and the true range): the
simulator's, for the viewer and the scorer (when an obstacle the prior map lacks was first seen).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import LidarSpec


@dataclass(frozen=True)
class LidarScan:
    """One scan as the lidar reports it (no truth).

    Attributes:
        t_s: time of the scan [s].
        directions_body: (K, 3) unit beam directions of the returned beams, body FLU.
        ranges_m: (K,) measured ranges [m] (noisy).
        pose_estimate: (7,) the vehicle's own estimate of its pose when the scan was taken, as a driver's timestamp
            and the navigation filter give it: position [m] world ENU and attitude quaternion [w, x, y, z] body FLU
            -> world ENU (`uam_fdm.sensing.onboard` stamps it; None: not stamped). A scan handed over later is
            placed on this pose, not on the newer estimate of the decision that receives it (the vehicle turns in
            between: up to several degrees in 0.1 s, metres at the lidar's range).
    """

    t_s: float
    directions_body: np.ndarray
    ranges_m: np.ndarray
    pose_estimate: np.ndarray | None = None

    def points_body_m(self) -> np.ndarray:
        """The returned points: (K, 3), body FLU metres, from the lidar (the vehicle's centre)."""
        return self.directions_body * self.ranges_m[:, None]


@dataclass(frozen=True)
class LidarTruth:
    """What a scan's returned beams truly hit: the simulator's record (the viewer, the scorer), never a pilot's.

    Attributes:
        points_m: (P, 3) true hit points, world ENU [m]: of every returned beam, or of the `truth_points` of them
            `Lidar.scan` was asked for (evenly spread over the scan).
        part_index: (K,) for each returned beam, in the scan's order, the index of the part it hit in the true
            city's `buildings` (-1: the ground).
        ranges_m: (K,) each returned beam's true range, before noise [m].
    """

    points_m: np.ndarray
    part_index: np.ndarray
    ranges_m: np.ndarray


def beam_directions_body(spec: LidarSpec) -> np.ndarray:
    """Unit beam directions of a full scan: (columns · channels, 3), body FLU, column by column.

    Channel elevations are evenly spaced from the lowest to the highest of `vertical_fov_deg`; column j is at
    azimuth j · horizontal_resolution_deg from body x, counter-clockwise.
    """
    lo, hi = spec.vertical_fov_deg
    el = np.radians(np.linspace(lo, hi, spec.channels) if spec.channels > 1 else np.array([0.5 * (lo + hi)]))
    az = np.radians(spec.horizontal_resolution_deg) * np.arange(spec.columns)
    ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
    ca, sa = np.cos(az)[:, None], np.sin(az)[:, None]
    d = np.stack([ca * ce, sa * ce, np.broadcast_to(se, (len(az), len(el)))], axis=-1)
    return d.reshape(-1, 3)


def check_lidar_spec(spec: LidarSpec) -> None:
    """Refuse a lidar spec the model cannot scan with (ValueError naming the field)."""
    if spec.channels < 1 or spec.columns < 1:
        raise ValueError(f"lidar needs at least one channel and one column: {spec}")
    if not 0.0 <= spec.dropout <= 1.0:
        raise ValueError(f"lidar dropout must be in [0, 1], got {spec.dropout}")
    if not 0.0 <= spec.min_range_m < spec.max_range_m:
        raise ValueError(f"lidar ranges must satisfy 0 <= min < max, got {spec.min_range_m}, {spec.max_range_m}")


class Lidar:
    """A lidar on the vehicle's centre, reading the true city through a `RayCaster`.

    Args:
        spec: the lidar.
        caster: the true city (buildings, unmapped obstacles, ground).
        rng: the source of noise and dropout.
    """

    def __init__(self, spec: LidarSpec, caster: RayCaster, rng: np.random.Generator) -> None:
        check_lidar_spec(spec)
        self.spec = spec
        self._caster = caster
        self._rng = rng
        self._dirs = beam_directions_body(spec)
        self._dirs.setflags(write=False)

    @property
    def directions_body(self) -> np.ndarray:
        """All beam directions of a scan: (rays_per_scan, 3) unit, body FLU (read-only)."""
        return self._dirs

    def scan(self, t_s: float, position_m: np.ndarray, rotation_body_to_world: np.ndarray,
             truth_points: int | None = None) -> tuple[LidarScan, LidarTruth]:
        """One scan from the true pose.

        Args:
            t_s: time [s].
            position_m: (3,) true position of the lidar, world ENU metres.
            rotation_body_to_world: (3, 3) true attitude, body FLU -> world ENU.
            truth_points: keep the true hit points of this many returned beams, evenly spread over the scan
                (None: of every returned beam).

        Returns:
            the scan (returned beams only), and what its returned beams truly hit (`LidarTruth`: not for pilots).
        """
        p = np.asarray(position_m, dtype=float).reshape(3)
        rot = np.asarray(rotation_body_to_world, dtype=float).reshape(3, 3)
        spec = self.spec
        d_world = self._dirs @ rot.T
        r_true, part = self._caster.first_hits(p, d_world, spec.max_range_m)
        idx = np.flatnonzero((r_true >= spec.min_range_m) & (r_true <= spec.max_range_m))  # a miss is inf
        idx = idx[self._rng.random(len(idx)) >= spec.dropout]
        r = r_true[idx]
        sigma = spec.range_noise_m + spec.range_noise_per_m * r
        # dropout and noise are drawn even when 0 (a noiseless spec): the draws do not depend on the figures
        measured = np.maximum(r + sigma * self._rng.standard_normal(len(idx)), 0.0)
        dirs = self._dirs[idx]
        shown = idx if truth_points is None or truth_points >= len(idx) else idx[
            np.linspace(0, len(idx) - 1, truth_points).astype(int)]
        truth = LidarTruth(p + d_world[shown] * r_true[shown, None], part[idx], r)
        for a in (dirs, measured, truth.points_m, truth.part_index, truth.ranges_m):
            a.setflags(write=False)
        return LidarScan(float(t_s), dirs, measured), truth
