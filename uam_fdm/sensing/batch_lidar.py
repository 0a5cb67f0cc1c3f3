"""The lidars of N vehicles at once (`uam_fdm.sensing.lidar.Lidar`'s model), each slot in its own true world.

A slot's scans are those of a `Lidar` built from the same spec, caster and Generator and scanning from the same
true poses, bit for bit (tests/uam_fdm/sensing/test_batch_lidar.py):

* per slot the same beam directions in the world (the same (rays, 3) @ (3, 3) product as `Lidar.scan`, one slot at
  a time: a stacked product might sum in another order);
* the same first hits: the slots that scan at once in one world are cast together (`CAST_RAYS` rays a call at
  most). Embree (through embreex) traces ray by ray, so a ray's range does not depend on the rays cast beside it,
  and `ranges_m` gives the range `first_hits` gives (what the ray hit is the simulator's, not the scan's, and is
  not kept here);
* the same draws from the slot's own Generator in the same order (dropout, then noise, one call each per scan: the
  two kinds share one Generator, so they cannot be drawn ahead in blocks as `SlotStreams` does);
* the same element-wise arithmetic (exact in IEEE floats however it is vectorised).

The scans wait in each slot's queue until a decision takes them (`hand_over`), as `Onboard` keeps its readings
until `Onboard.observation` hands them over; what has been handed over is dropped.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from uam_fdm.sensing.lidar import LidarScan, beam_directions_body, check_lidar_spec
from uam_fdm.sensing.raycast import RayCaster
from uam_fdm.sensing.specs import LidarSpec
from uam_fdm.vehicle.attitude import rotation_matrices

# Rays cast in one `RayCaster` call at most: slots in one world are cast together up to this many rays, which saves
# a call's overhead (~5 µs) per slot for a coarse scan; beyond it the per-ray origins no longer fit in cache and a
# slot's own call (one origin) is cheaper (a 28,800-ray scan: 1.2 ms alone, 2.0 ms eight slots together).
CAST_RAYS = 4096


class BatchLidar:
    """N lidars, one per slot, each reading its slot's true world through that world's `RayCaster`.

    Args:
        spec: the lidar (every slot carries the same).
        n: slots.
        casters: one ray caster per TRUE world a slot may fly in (buildings, unmapped obstacles, ground).

    Raises:
        ValueError: a spec out of range (as `Lidar` refuses it), or no caster.
    """

    def __init__(self, spec: LidarSpec, n: int, casters: Sequence[RayCaster]) -> None:
        check_lidar_spec(spec)
        if not casters:
            raise ValueError("lidar casters: at least one RayCaster (one per true world) is needed")
        self.spec = spec
        self._casters = list(casters)
        self._dirs = beam_directions_body(spec)
        self._dirs.setflags(write=False)
        self._world = np.zeros(n, dtype=np.intp)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._queued: list[deque[LidarScan]] = [deque() for _ in range(n)]

    @property
    def worlds(self) -> int:
        """How many true worlds (casters) the slots may fly in."""
        return len(self._casters)

    @property
    def directions_body(self) -> np.ndarray:
        """All beam directions of a scan: (rays_per_scan, 3) unit, body FLU (read-only)."""
        return self._dirs

    def queued(self, slots: Sequence[int] | np.ndarray | None = None) -> np.ndarray:
        """(M,) how many scans each of `slots` (None: all N) holds that no decision has taken yet."""
        idx = range(len(self._queued)) if slots is None else np.asarray(slots).tolist()
        return np.array([len(self._queued[i]) for i in idx], dtype=np.int64)

    def restart(self, i: int, rng: np.random.Generator, world: int) -> None:
        """Switch slot i's lidar on in true world `world` (an index of `casters`), drawing from `rng` from now on
        (as a new `Lidar` would); the scans it held are dropped."""
        self._rngs[i] = rng
        self._world[i] = world
        self._queued[i].clear()

    def measure(self, slots: np.ndarray, t_s: np.ndarray, position_m: np.ndarray,
                quaternion: np.ndarray, pose_estimate: np.ndarray | None = None) -> list[LidarScan]:
        """One scan of each of `slots` from its true pose (`Lidar.scan`), queued for `hand_over`.

        Args:
            slots: (M,) distinct slots, each restarted before.
            t_s: (M,) scan times on each slot's clock [s].
            position_m: (M, 3) true positions of the lidars, world ENU [m].
            quaternion: (M, 4) true attitudes [w, x, y, z], body FLU -> world ENU.
            pose_estimate: (M, 7) each vehicle's own estimate of its pose now (`LidarScan.pose_estimate`), stamped
                on its scan; None: not stamped.

        Returns:
            per slot its scan (returned beams only).
        """
        # element-wise, so each row is `rotation_matrix` of that slot's quaternion, bit for bit
        rot = rotation_matrices(np.asarray(quaternion, dtype=float))
        pos = np.asarray(position_m, dtype=float)
        times = np.asarray(t_s, dtype=float).tolist()
        world = self._world[slots]
        per_call = max(1, CAST_RAYS // self.spec.rays_per_scan)
        scans: dict[int, LidarScan] = {}
        for w in np.unique(world).tolist():
            members = np.flatnonzero(world == w)
            for first in range(0, len(members), per_call):
                g = members[first:first + per_call]
                for k, scan in zip(g.tolist(), self._scan_together(w, slots[g], [times[k] for k in g.tolist()],
                                                                   pos[g], rot[g])):
                    scans[k] = scan
        out = [scans[k] for k in range(len(slots))]
        if pose_estimate is not None:
            poses = np.array(pose_estimate, dtype=float).reshape(len(out), 7)
            poses.setflags(write=False)
            out = [replace(scan, pose_estimate=poses[k]) for k, scan in enumerate(out)]
        for i, scan in zip(slots.tolist(), out):
            self._queued[i].append(scan)
        return out

    def _scan_together(self, world: int, slots: np.ndarray, times: list[float], pos: np.ndarray,
                       rot: np.ndarray) -> list[LidarScan]:
        """The scans of slots (G,) in one true world, cast in one call: times [s], positions (G, 3) world ENU [m],
        rotations (G, 3, 3) body FLU -> world ENU."""
        spec, rays, g = self.spec, self.spec.rays_per_scan, len(slots)
        if g == 1:  # one origin for all rays: `Lidar.scan`'s own call
            origins, d_world = pos[0], self._dirs @ rot[0].T
        else:
            origins = np.repeat(pos, rays, axis=0)
            d_world = np.concatenate([self._dirs @ r.T for r in rot])
        r_true = self._casters[world].ranges_m(origins, d_world, spec.max_range_m)
        hit = np.flatnonzero((r_true >= spec.min_range_m) & (r_true <= spec.max_range_m))  # a miss is inf
        bounds = np.searchsorted(hit, np.arange(g + 1) * rays).tolist()  # slot j's beams: hit[bounds[j]:bounds[j+1]]
        kept, normal = [], []
        for j, i in enumerate(slots.tolist()):
            rng = self._rngs[i]
            assert rng is not None, "a slot scans only after its restart"
            idx = hit[bounds[j]:bounds[j + 1]]
            idx = idx[rng.random(len(idx)) >= spec.dropout]
            # noise is drawn even when 0 (a noiseless spec): the draws do not depend on the figures
            normal.append(rng.standard_normal(len(idx)))
            kept.append(idx)
        beam = np.concatenate(kept)  # indices into the G slots' rays
        r = r_true[beam]
        sigma = spec.range_noise_m + spec.range_noise_per_m * r
        measured = np.maximum(r + sigma * np.concatenate(normal), 0.0)
        dirs = self._dirs[beam % rays]
        for a in (dirs, measured):
            a.setflags(write=False)  # each slot's scan is a view of these
        ends = np.cumsum([0] + [len(k) for k in kept]).tolist()
        return [LidarScan(t, dirs[a:b], measured[a:b]) for t, a, b in zip(times, ends[:-1], ends[1:])]

    def hand_over(self, slots: np.ndarray, seen_t_s: np.ndarray) -> list[tuple[LidarScan, ...]]:
        """Take each of `slots`' queued scans up to its time `seen_t_s` (M,) [s] inclusive, in time order (dropped
        from the queue: a scan is handed over once)."""
        out = []
        for i, seen in zip(slots.tolist(), np.asarray(seen_t_s, dtype=float).tolist()):
            queue, taken = self._queued[i], []
            while queue and queue[0].t_s <= seen:
                taken.append(queue.popleft())
            out.append(tuple(taken))
        return out
