"""The rules that end an episode, written once for every place that flies one.

The comparison runner (`compare.flying.episode_loop`, one vehicle) and the learned pilot's environment
(`rl.env.world`, N vehicles) both call these after every control period, so an episode flown through
either ends at the same physics substep for the same reason (tests/rl/pilots/test_learned_pilot.py flies one
episode both ways and compares the states bit for bit).

After a control period of S physics substeps, in this order (the first that applies wins):

==============  =================================================================================
outcome         rule
==============  =================================================================================
nonfinite       any state element of any substep is NaN or infinite
collision       the collision sphere's signed clearance to a building or the ground is < 0 at
                any substep (the caller measures the clearance; see `collided`)
out_of_bounds   any substep's position lies outside the flight volume [lo, hi] (closed box)
success         the position at the end of the period is within the goal radius
timeout         none of the above and the clock has reached the task's time limit
==============  =================================================================================

Every way an episode can end is one `Outcome`, named once here for the runner, the learned pilot's
environment, the metrics and the report.
"""
from __future__ import annotations

import enum
import math

import numpy as np


class Outcome(str, enum.Enum):
    """How an episode ended. A `str` whose value is the name written in episode files and metrics.csv;
    it prints as that value (str, format and repr), so files, tables and logs read as before.

    The first five are the end rules of the module table. `PLANNER_FAILURE`: the pilot could not fly
    the task (its reset said so, e.g. no path found) and the episode ended before the first step.
    `SOLVER_FAILURE` is never the runner's outcome: it is the failure reason a pilot's end-of-episode
    report may give a failed episode (the classical pilot's MPC failed on many solves,
    `planners.report.ClassicalReport.failure_reason`), and older files may carry it as the outcome.
    """

    SUCCESS = "success"
    COLLISION = "collision"
    OUT_OF_BOUNDS = "out_of_bounds"
    NONFINITE = "nonfinite"
    TIMEOUT = "timeout"
    PLANNER_FAILURE = "planner_failure"
    SOLVER_FAILURE = "solver_failure"

    def __str__(self) -> str:
        return self.value

    def __repr__(self) -> str:
        return repr(self.value)

    @classmethod
    def parse(cls, value: object, where: str) -> Outcome:
        """The outcome named `value` (an `Outcome` or its name).

        Raises:
            ValueError: an unknown name, prefixed with `where` (e.g. the episode).
        """
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"{where}: unknown outcome {value!r}, expected one of "
                             f"{', '.join(o.value for o in cls)}") from None


RUNNING, SUCCESS, COLLISION, OUT_OF_BOUNDS, NONFINITE, TIMEOUT = range(6)
OUTCOME_OF_CODE: tuple[Outcome | None, ...] = (None, Outcome.SUCCESS, Outcome.COLLISION, Outcome.OUT_OF_BOUNDS,
                                               Outcome.NONFINITE, Outcome.TIMEOUT)
"""The outcome of each end-rule code (None: still running)."""
OUTCOMES: tuple[Outcome, ...] = OUTCOME_OF_CODE[1:]  # type: ignore[assignment]
"""The outcomes the end rules give (a flight in the simulator)."""

# Clocks accumulate a period of 1/control_hz at a time; a limit of e.g. 25.0 s is reached when the
# accumulated time is within this of it (rounding of the repeated addition).
TIME_EPS_S = 1e-9


def collided(clearance_m: np.ndarray) -> np.ndarray:
    """Whether each vehicle touched an obstacle: clearance (N, S) [m] per substep -> (N,) bool."""
    return np.any(np.asarray(clearance_m) < 0.0, axis=-1)


def period_outcome(states: np.ndarray, hit: np.ndarray, lo_m: np.ndarray, hi_m: np.ndarray,
                   goal_m: np.ndarray, goal_radius_m: np.ndarray | float) -> np.ndarray:
    """The outcome code (N,) of one control period for N vehicles (see the module table).

    Args:
        states: (N, S, nx) state after each substep (position first, world ENU [m]).
        hit: (N,) whether the vehicle collided during the period (`collided`); ignored where
            the state is non-finite.
        lo_m, hi_m: (N, 3) or (3,) flight-volume corners [m].
        goal_m: (N, 3) or (3,) goals [m]; goal_radius_m: (N,) or scalar [m].

    Returns:
        int codes: RUNNING, SUCCESS, COLLISION, OUT_OF_BOUNDS or NONFINITE (never TIMEOUT; see
        `timed_out`).
    """
    states = np.asarray(states)
    n = states.shape[0]
    if n == 1:
        return np.array([_period_outcome_one(states[0], hit, lo_m, hi_m, goal_m, goal_radius_m)], dtype=np.int64)
    finite = np.isfinite(states).all(axis=(1, 2))
    pos = states[:, :, 0:3]
    lo = np.asarray(lo_m, dtype=float).reshape(-1, 1, 3)
    hi = np.asarray(hi_m, dtype=float).reshape(-1, 1, 3)
    with np.errstate(invalid="ignore"):
        inside = ((pos >= lo) & (pos <= hi)).all(axis=(1, 2))
        g = pos[:, -1, :] - np.asarray(goal_m, dtype=float).reshape(-1, 3)
        arrived = np.sqrt(np.add.reduce(g * g, axis=1)) <= np.asarray(goal_radius_m, dtype=float)
    code = np.full(n, RUNNING, dtype=np.int64)
    code[arrived] = SUCCESS
    code[~inside] = OUT_OF_BOUNDS
    code[np.asarray(hit, dtype=bool)] = COLLISION
    code[~finite] = NONFINITE
    return code


def _period_outcome_one(states: np.ndarray, hit, lo_m, hi_m, goal_m, goal_radius_m) -> int:
    """`period_outcome` of one vehicle (states (S, nx)) in plain Python: a single vehicle's env calls
    it every control period, where NumPy's per-call overhead dominated. The same comparisons and the
    same arrival distance (sqrt((dx² + dy²) + dz²), correctly rounded either way), so the same code."""
    if not np.isfinite(states).all():
        return NONFINITE
    if bool(np.asarray(hit, dtype=bool).reshape(-1)[0]):
        return COLLISION
    lx, ly, lz = np.asarray(lo_m, dtype=float).reshape(3).tolist()
    hx, hy, hz = np.asarray(hi_m, dtype=float).reshape(3).tolist()
    pos = states[:, 0:3].tolist()
    for x, y, z in pos:
        if not (lx <= x <= hx and ly <= y <= hy and lz <= z <= hz):
            return OUT_OF_BOUNDS
    x, y, z = pos[-1]
    gx, gy, gz = np.asarray(goal_m, dtype=float).reshape(3).tolist()
    dx, dy, dz = x - gx, y - gy, z - gz
    if math.sqrt(dx * dx + dy * dy + dz * dz) <= float(np.asarray(goal_radius_m, dtype=float).reshape(-1)[0]):
        return SUCCESS
    return RUNNING


def timed_out(t_s: np.ndarray | float, timeout_s: np.ndarray | float) -> np.ndarray | bool:
    """Whether the clock t_s [s] (after a period) has reached the time limit timeout_s [s]."""
    return np.asarray(t_s) >= np.asarray(timeout_s) - TIME_EPS_S
