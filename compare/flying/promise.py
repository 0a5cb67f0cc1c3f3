"""Whether a pilot kept the clearance it promised, measured on the truth: the vehicle's true sphere clearance
(the episode's `clearance_m`, every physics step, to the true world) over the margin the pilot stated in force
at the time (`uam_fdm.pilot.StatesMargins`). The classical pilot promises at least half its margin; a pilot
flying on a wrong map and an estimate can believe it keeps it while the truth says otherwise, so the scorer,
not the pilot, measures it.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from compare.flying.episode_loop import Trajectory
from uam_fdm.pilot import Pilot, PilotReport, StatesMargins

MARGIN_FLOOR_M = 0.05
"""A stated margin below this counts as this [m], so that a zero margin gives a finite ratio."""


def clearance_over_margin_min(t_s: np.ndarray, clearance_m: np.ndarray, decision_t_s: np.ndarray,
                              margins_m: np.ndarray) -> float:
    """The least, over the physics steps after the first decision, of the true clearance over the margin in force
    (the one of the latest decision before the step) [-]; NaN without a decision or a finite step.

    Args:
        t_s: (M,) the steps' times [s]; clearance_m: (M,) the true sphere clearance there [m].
        decision_t_s: (D,) the decisions' times [s], ascending; margins_m: (D,) the margin in force from each [m].
    """
    t, c = np.asarray(t_s, float), np.asarray(clearance_m, float)
    d, m = np.asarray(decision_t_s, float), np.asarray(margins_m, float)
    if not len(d) or not len(t):
        return math.nan
    # a step ending after a decision flies under it: the step at the decision's own time ended before it
    k = np.searchsorted(d, t, side="left") - 1
    flown = (k >= 0) & np.isfinite(c)
    if not np.any(flown):
        return math.nan
    return float(np.min(c[flown] / np.maximum(m[k[flown]], MARGIN_FLOOR_M)))


def scored_report(pilot: Pilot, traj: Trajectory) -> PilotReport | None:
    """The pilot's episode report, with its `clearance_over_margin_min` measured on the truth where the pilot states
    its margins (`StatesMargins`) and its report has that field; else the report as the pilot gives it."""
    report = pilot.episode_report()
    if report is None or not isinstance(pilot, StatesMargins) or not hasattr(report, "clearance_over_margin_min"):
        return report
    times, margins = pilot.margins_in_force()
    ratio = clearance_over_margin_min(traj.t_s, traj.clearance_m, times, margins)
    return dataclasses.replace(report, clearance_over_margin_min=ratio)  # type: ignore[type-var]
