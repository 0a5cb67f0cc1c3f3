"""The classical pilot's promise (true clearance >= half the margin in force) measured by the scorer on the truth:
each physics step against the margin of the latest decision before it, never the pilot's own belief."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from compare.flying.promise import MARGIN_FLOOR_M, clearance_over_margin_min, scored_report
from planners.report import ClassicalReport
from uam_fdm.pilot import StatesMargins


def test_each_step_is_held_to_the_margin_of_the_decision_before_it() -> None:
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.04, 0.05])
    clearance = np.array([9.0, 4.0, 3.0, 2.0, 1.0, 2.5])
    decisions, margins = np.array([0.0, 0.02, 0.04]), np.array([8.0, 2.0, 5.0])
    # step 0 (t = 0, before any decision flew) is not counted; steps 1, 2 fly the first decision's 8 m, steps 3, 4
    # the second's 2 m, step 5 the third's 5 m: ratios 0.5, 0.375, 1.0, 0.5, 0.5
    assert clearance_over_margin_min(t, clearance, decisions, margins) == pytest.approx(0.375)
    assert clearance_over_margin_min(t, np.where(t == 0.02, np.nan, clearance), decisions, margins) == 0.5
    assert math.isnan(clearance_over_margin_min(t, clearance, np.array([]), np.array([])))
    # a zero margin counts as the floor: a finite ratio
    assert clearance_over_margin_min(t, clearance, decisions, np.zeros(3)) == pytest.approx(1.0 / MARGIN_FLOOR_M)


def _report(plan_time_s: float) -> ClassicalReport:
    nan = math.nan
    return ClassicalReport(plan_time_s, 0.0, 0, 0, 0, 0, nan, nan, {}, nan, nan, nan, nan, "")


class _Promising:
    """A pilot stating its margins, whose report is the classical pilot's."""

    name = "promising"

    def episode_report(self) -> ClassicalReport:
        return _report(0.1)

    def margins_in_force(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([0.0]), np.array([4.0])


@dataclasses.dataclass
class _Flight:
    t_s: np.ndarray
    clearance_m: np.ndarray


def test_the_report_gets_the_truths_ratio_and_other_pilots_keep_theirs() -> None:
    pilot = _Promising()
    assert isinstance(pilot, StatesMargins)
    flight = _Flight(np.array([0.0, 0.1, 0.2]), np.array([5.0, 3.0, 1.0]))
    report = scored_report(pilot, flight)  # type: ignore[arg-type]
    assert report.clearance_over_margin_min == pytest.approx(0.25) and report.plan_time_s == 0.1

    class Silent:
        name = "silent"

        def episode_report(self) -> ClassicalReport:
            return _report(0.2)

    assert math.isnan(scored_report(Silent(), flight).clearance_over_margin_min)  # type: ignore[arg-type]
