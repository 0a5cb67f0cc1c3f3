"""Honest small samples, on 1, 2, 5 and 30 episodes per pilot: below MIN_INTERVAL_N no bootstrap interval (the mean
and its n), a rate keeps its Wilson interval, no difference is called, no MDD from the spread; and the command line,
the report's pages and summary.json say the same."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from compare.cli.printout import print_headline_json, print_summary
from compare.report.metrics_pages import PilotStyle, format_ci, vehicle_pages
from compare.report.title_page import TitleFacts, headline_pages
from compare.results.difficulty import ScenarioConditions
from compare.results.metrics import EpisodeMetrics
from compare.results.run_info import RunInfo, write_run_info
from compare.results.stats import MIN_INTERVAL_N, Bootstrap, PairedCounts, newcombe_paired_interval
from compare.results.summary import (
    NO_INTERVAL_NOTE,
    format_stat,
    mdd_gap,
    read_summary_json,
    summarize,
    summarize_run,
    write_summary_json,
)
from uam_fdm.stats import wilson_interval

SIZES = (1, 2, 5, 30)
STYLE = PilotStyle(("ppo", "rrt_mpc"), {"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC"},
                   {"ppo": "tab:orange", "rrt_mpc": "tab:blue"})


def rows(n: int) -> list[EpisodeMetrics]:
    """Two pilots on n episodes: PPO always succeeds, RRT* + MPC one episode in five; clearances spread out."""
    out = []
    for ep in range(n):
        for pilot in ("ppo", "rrt_mpc"):
            ok = pilot == "ppo" or ep % 5 == 4
            out.append(EpisodeMetrics(
                scenario="town", episode=ep, method=pilot, seed=0, map="m", vehicle="small_quad",
                outcome="success" if ok else "collision", success=ok, collision=not ok,
                failure_reason="" if ok else "collision",
                min_clearance_m=(2.0 + 0.37 * ep if pilot == "ppo" else 1.0 + 0.21 * math.sin(ep)) + 19.83 * (n == 1),
                time_below_2m_s=0.0, time_below_5m_s=1.0, time_s=20.0 + ep, path_length_m=100.0 + ep,
                straight_line_m=90.0, spl=0.9 if ok else 0.0, energy_kj=5.0 + 0.1 * ep, compute_ms_mean=1.0 + 0.01 * ep,
                compute_ms_max=2.0, plan_time_s=math.nan))
    return out


def _texts(figs: list[Figure]) -> str:
    """Every text of the pages (figure texts, axes texts and annotations, table cells), one per line."""
    out = []
    for fig in figs:
        out += [t.get_text() for t in fig.texts] + [fig.get_suptitle()]
        for ax in fig.axes:
            out += [t.get_text() for t in ax.texts]
            for table in ax.tables:
                out += [c.get_text().get_text() for c in table.get_celld().values()]
    return "\n".join(" ".join(t.split()) for t in out)


def _report_pages(n: int) -> str:
    s = summarize_run(rows(n), resamples=300)
    part = s.by_vehicle["small_quad"]
    pages = vehicle_pages("small_quad", part, s.by_scenario, rows(n),
                          {"town": ScenarioConditions("town", "small_quad", 0.2, "light", 1.2)}, STYLE, "test.")
    facts = TitleFacts(Path("run"), RunInfo(command="uam-compare run"), STYLE.label, 2 * n,
                       2 * n, s.by_vehicle, STYLE, "numbers from summary.json.")
    return _texts([f for _, figs in pages for f in figs] + headline_pages(facts))


@pytest.mark.parametrize("n", SIZES)
def test_below_the_minimum_no_bootstrap_interval_but_rates_keep_wilson(n, tmp_path):
    s = summarize(rows(n), resamples=300)
    ppo, mpc = s.pilots["ppo"].stats, s.pilots["rrt_mpc"].stats
    few = n < MIN_INTERVAL_N
    for st in (ppo["min_clearance_m"], mpc["min_clearance_m"], ppo["energy_kj"], ppo["compute_ms_mean"]):
        assert st.n == n and st.mean is not None
        if few:
            assert (st.ci_low, st.ci_high) == (None, None)
        else:
            assert st.ci_low < st.mean < st.ci_high  # a real interval: width, around the mean
    successes = sum(r.success for r in rows(n) if r.method == "rrt_mpc")
    assert (mpc["success"].ci_low, mpc["success"].ci_high) == wilson_interval(successes, n)  # at every n
    assert (ppo["success"].ci_low, ppo["success"].ci_high) == wilson_interval(n, n)
    # summary.json: null where there is no interval, and the minimum it used
    data = json.loads(write_summary_json(s, tmp_path / "summary.json").read_text())
    assert data["bootstrap"]["min_n"] == MIN_INTERVAL_N
    clear = data["methods"]["ppo"]["min_clearance_m"]
    assert (clear["ci_low"] is None) is few and (clear["ci_high"] is None) is few and clear["n"] == n
    assert data["methods"]["ppo"]["success"]["ci_low"] is not None
    assert read_summary_json(tmp_path / "summary.json") == s


@pytest.mark.parametrize("n", SIZES)
def test_no_difference_is_called_below_the_minimum(n):
    (pair,) = summarize(rows(n), resamples=300).paired
    succ, clear = pair.stats["success"], pair.stats["min_clearance_m"]
    counts = PairedCounts.of([True] * n, [ep % 5 == 4 for ep in range(n)])
    low, high = newcombe_paired_interval(counts)
    assert (succ.ci_low, succ.ci_high) == (low, high)  # the paired rate keeps its score interval
    if n < MIN_INTERVAL_N:
        assert succ.excludes_zero is None and clear.excludes_zero is None
        assert clear.ci_low is None and clear.mdd is None and succ.mdd is None
        if n == 5:
            assert low > 0.0  # the interval itself clears zero, yet five pairs are not enough to call it
        assert mdd_gap(clear) in ("fewer than 10 pairs", "every pair agreed") or n < 2
    else:
        assert succ.excludes_zero is True and clear.excludes_zero is True
        assert clear.mdd is not None and clear.mdd > 0 and mdd_gap(clear) == ""


def test_one_value_has_no_zero_width_interval():
    mean, low, high = Bootstrap(500, 0.95, 0).mean_ci(np.array([21.83]))
    assert (mean, low, high) == (21.83, None, None)
    assert Bootstrap(500, 0.95, 0).mean_ci(np.arange(float(MIN_INTERVAL_N - 1)))[1] is None
    assert Bootstrap(500, 0.95, 0).mean_ci(np.arange(float(MIN_INTERVAL_N)))[1] is not None


@pytest.mark.parametrize("n", SIZES)
def test_command_line_report_and_summary_json_agree(n, tmp_path, capsys):
    rs = rows(n)
    summary = summarize_run(rs, resamples=300)
    write_summary_json(summary, tmp_path / "summary.json")
    write_run_info(RunInfo(command="uam-compare run"), tmp_path)
    print_summary(tmp_path)
    print_headline_json(tmp_path)
    printed = capsys.readouterr().out
    cli = printed.splitlines()
    report = _report_pages(n)
    st = summary.by_vehicle["small_quad"].pilots["ppo"].stats["min_clearance_m"]
    cell = format_stat(st, lambda v: f"{v:.2f}")
    assert cell == format_ci(st, 1.0, 2)  # one formatting for both
    assert any(cell in line for line in cli) and cell in report
    few = n < MIN_INTERVAL_N
    assert (f"(n={n}, no CI)" in cell) is few
    assert ("[" not in cell) is few and "21.83 [21.83, 21.83]" not in report
    # what "no CI" means is said wherever a cell says it (at 30 episodes too: RRT* + MPC's 6 successful flights)
    assert (NO_INTERVAL_NOTE in printed) is any("no CI)" in line for line in cli[:-1]) is True
    assert NO_INTERVAL_NOTE in report
    # success with its Wilson interval, the same in both
    rate = format_ci(summary.by_vehicle["small_quad"].pilots["rrt_mpc"].stats["success"], 100.0, 0)
    assert "[" in rate and rate in report
    # the paired difference: never called below the minimum, in words in both
    pair = summary.by_vehicle["small_quad"].paired[0]
    gap = mdd_gap(pair.stats["min_clearance_m"])
    if few:
        assert "too few pairs to call" in printed and "n/a (n < 10)" in report
        assert f"n/a ({gap})" in report and "0 (no spread)" not in report
        assert not any(line.endswith(" *") for line in report.splitlines())  # no forest row starred
        assert f"n/a ({mdd_gap(pair.stats['success'])})" in printed
    else:
        assert "the interval excludes 0" in printed and "yes" in report
    headline = json.loads(cli[-1])
    diff = headline["paired"]["small_quad"]["ppo - rrt_mpc"]["success"]
    assert diff["pairs"] == n and diff["excludes_zero"] is (None if few else True)
    assert diff["ci95"] == [pair.stats["success"].ci_low, pair.stats["success"].ci_high]
    assert headline["vehicles"]["small_quad"]["ppo"]["success"]["ci95"][0] == wilson_interval(n, n)[0]
