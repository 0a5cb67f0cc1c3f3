"""The minimum detectable paired difference of a benchmark run from its observed discordance: `paired_mdd` against
hand calculations of Connor's (1987) equation, its floor and monotony, and the per-level tables, their text and the
run's JSON carrying it."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from compare.cli.printout import print_headline_json
from compare.results.level_rates import (
    LevelMdd,
    LevelPair,
    level_json,
    level_mdd_json,
    level_mdds,
    level_pairs,
    level_rates,
    level_table_lines,
)
from compare.results.metrics import EpisodeMetrics, write_metrics_csv
from compare.results.run_info import PilotInfo, RunInfo, ScenarioInfo, TaskSetInfo, write_run_info
from compare.results.stats import PairedCounts, paired_mdd
from compare.results.summary import summarize_run, write_summary_json

Z_A = 1.959963984540054  # z_0.975
Z_B = 0.8416212335729143  # z_0.8


def _connor_fixed_psi(n: int, psi: float) -> float:
    """Connor's equation solved by hand for delta where psi does not depend on it: the larger root of
    (n + z_b^2) delta^2 - 2 sqrt(n) z_a sqrt(psi) delta + (z_a^2 - z_b^2) psi = 0 (sqrt(n) delta >= z_a sqrt(psi))."""
    a, b, c = n + Z_B**2, -2.0 * math.sqrt(n) * Z_A * math.sqrt(psi), (Z_A**2 - Z_B**2) * psi
    return (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


def _connor_floored(n: int) -> float:
    """Connor's equation with psi = delta: n delta = (z_a + z_b s)^2 with s = sqrt(1 - delta), a quadratic in s."""
    a, b, c = n + Z_B**2, 2.0 * Z_A * Z_B, Z_A**2 - n
    s = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return 1.0 - s * s


def test_paired_mdd_matches_connors_equation_by_hand() -> None:
    # 432 pairs, 20 discordant (12 + 8): psi = 20/432 is above the MDD, so it is the observed share
    got = paired_mdd(PairedCounts(400, 12, 8, 12))
    assert got == pytest.approx(_connor_fixed_psi(432, 20 / 432), abs=1e-9)
    assert got == pytest.approx(0.028923, abs=1e-6)
    assert 20 / 432 > got
    # no discordant pair: psi = delta, about (z_a + z_b)^2 / n, never 0
    none = paired_mdd(PairedCounts(420, 0, 0, 12))
    assert none == pytest.approx(_connor_floored(432), abs=1e-9)
    assert none == pytest.approx(0.018070, abs=1e-6)
    assert none == pytest.approx((Z_A + Z_B) ** 2 / 432, rel=0.01)
    # only the discordant counts matter, not how the agreeing pairs split or which pilot won
    assert paired_mdd(PairedCounts(0, 8, 12, 412)) == got


def test_the_discordance_is_floored_at_the_difference() -> None:
    floored = _connor_floored(432)
    for discordant in (1, 2, 7):  # all below the floored MDD (7/432 = 0.0162 < 0.0181)
        assert discordant / 432 < floored
        assert paired_mdd(PairedCounts(400, discordant, 0, 32 - discordant)) == pytest.approx(floored, abs=1e-9)
    # above it the observed share rules, and Connor's equation holds with psi = max(observed, delta)
    for discordant in (8, 20, 100):
        delta = paired_mdd(PairedCounts(300, discordant, 0, 132 - discordant))
        psi = max(discordant / 432, delta)
        assert 432 * delta**2 == pytest.approx((Z_A * math.sqrt(psi) + Z_B * math.sqrt(psi - delta**2)) ** 2,
                                               rel=1e-6)


def test_paired_mdd_falls_with_pairs_and_grows_with_discordance() -> None:
    by_n = [paired_mdd(PairedCounts(n - n // 20 - 1, n // 20, 1, 0)) for n in (10, 20, 50, 144, 432, 2000)]
    assert all(a > b for a, b in zip(by_n, by_n[1:]))
    assert by_n[3] == pytest.approx(_connor_fixed_psi(144, 8 / 144), abs=1e-9)
    by_discordance = [paired_mdd(PairedCounts(432 - d, d, 0, 0)) for d in range(0, 200, 5)]
    assert all(a <= b for a, b in zip(by_discordance, by_discordance[1:]))
    assert by_discordance[-1] > by_discordance[2] > by_discordance[0]  # 195 and 10 discordant above the floor
    # at alpha 0.01 or power 0.9 a larger difference is needed
    counts = PairedCounts(400, 12, 8, 12)
    assert paired_mdd(counts, alpha=0.01) > paired_mdd(counts) < paired_mdd(counts, power=0.9)


def test_paired_mdd_refuses_no_pairs_and_says_when_nothing_is_detectable() -> None:
    with pytest.raises(ValueError):
        paired_mdd(PairedCounts(0, 0, 0, 0))
    with pytest.raises(ValueError):
        paired_mdd(PairedCounts(5, 1, 1, 5), power=0.3)
    # n < z_a^2 = 3.84: not even a difference of 1 reaches the power
    assert paired_mdd(PairedCounts(0, 3, 0, 0)) == math.inf
    assert paired_mdd(PairedCounts(0, 4, 0, 0)) < 1.0


# ---- a benchmark run's levels ----------------------------------------------------------------------------
PILOTS = ("rrt_mpc", "ppo")
# (name, vehicle, sensing, map error, episodes, episodes ppo fails, episodes rrt_mpc fails)
SCENARIOS = (("a", "small_quad", "nominal", "exact", 100, range(0, 5), range(0)),
             ("b", "small_quad", "degraded", "exact", 100, range(0, 15), range(15, 20)),
             ("c", "small_quad", "perfect", "wrong", 5, range(0), range(0)),
             ("d", "uam_multicopter", "nominal", "exact", 12, range(0, 1), range(0)))


def _run() -> tuple[RunInfo, list[EpisodeMetrics]]:
    """A run of the scenarios above: ppo's failures are collisions, rrt_mpc's time-outs."""
    info = RunInfo(command="uam-compare run benchmark", task_set=TaskSetInfo("benchmark", "test"),
                   pilots={"rrt_mpc": PilotInfo("RRT* + MPC"), "ppo": PilotInfo("PPO policy")},
                   scenarios=tuple(ScenarioInfo(name=n, vehicle=v, sensing=s, map_error=m)
                                   for n, v, s, m, *_ in SCENARIOS))
    rows = []
    for name, vehicle, _, _, episodes, ppo_fails, rrt_fails in SCENARIOS:
        for ep in range(episodes):
            for pilot, fails in (("rrt_mpc", rrt_fails), ("ppo", ppo_fails)):
                bad = ep in fails
                outcome = ("collision" if pilot == "ppo" else "timeout") if bad else "success"
                rows.append(EpisodeMetrics(
                    scenario=name, episode=ep, method=pilot, seed=0, map="m", vehicle=vehicle, outcome=outcome,
                    success=not bad, collision=outcome == "collision", failure_reason="" if not bad else outcome,
                    min_clearance_m=2.0 + 0.01 * ep, time_below_2m_s=0.0, time_below_5m_s=1.0, time_s=20.0 + ep,
                    path_length_m=100.0, straight_line_m=90.0, spl=0.0 if bad else 0.9, energy_kj=5.0,
                    compute_ms_mean=1.0, compute_ms_max=2.0, plan_time_s=math.nan))
    return info, rows


# success: the degraded level has 20 discordant of 100, nominal 5 of 100, the quad's whole run 25 of 205
DEGRADED = _connor_fixed_psi(100, 0.20)
OVERALL = _connor_fixed_psi(205, 25 / 205)
NOMINAL = _connor_floored(100)  # 5 of 100 lies below its MDD


def test_level_pairs_carry_the_mdd() -> None:
    info, rows = _run()
    pairs = {(p.vehicle, p.axis, p.level): p for p in level_pairs(info, rows)}
    degraded = pairs["small_quad", "sensing", "degraded"]
    assert (degraded.first, degraded.second, degraded.pairs) == PILOTS + (100,)
    assert degraded.success_mdd == pytest.approx(DEGRADED, abs=1e-9)
    assert degraded.success_mdd == pytest.approx(0.123819, abs=1e-6)
    # collisions: ppo's 15 collisions are the only discordant pairs there
    assert degraded.collision_mdd == pytest.approx(_connor_fixed_psi(100, 0.15), abs=1e-9)
    assert degraded.collision_mdd < degraded.success_mdd
    assert pairs["small_quad", "sensing", "nominal"].success_mdd == pytest.approx(NOMINAL, abs=1e-9)
    assert pairs["small_quad", "all", "all"].success_mdd == pytest.approx(OVERALL, abs=1e-9)
    # five pairs: no MDD, as no difference is called there
    few = pairs["small_quad", "map_error", "wrong"]
    assert few.pairs == 5 and math.isnan(few.success_mdd) and math.isnan(few.collision_mdd)


def test_each_vehicles_mdd_summary_names_its_largest_level() -> None:
    info, rows = _run()
    quad, uam = level_mdds(level_pairs(info, rows))
    # the largest over the levels of one axis: sensing_map's perfect/wrong (5 pairs) is not counted as left out
    assert quad == LevelMdd("small_quad", "rrt_mpc", "ppo", pytest.approx(OVERALL, abs=1e-9),
                            pytest.approx(DEGRADED, abs=1e-9), "sensing", "degraded", 2)
    assert (uam.vehicle, uam.too_few) == ("uam_multicopter", 0)
    assert uam.overall == uam.max_per_level == pytest.approx(_connor_floored(12), abs=1e-9)


def test_the_sensing_map_pairs_are_not_levels_of_the_summary() -> None:
    def pair(axis: str, level: str, mdd: float) -> LevelPair:
        return LevelPair("small_quad", axis, level, "a", "b", 48, 0.0, (-0.1, 0.1), False, 0.0, (-0.1, 0.1), False,
                         mdd, mdd)

    (m,) = level_mdds([pair("all", "all", 0.02), pair("air", "sea-level", 0.04), pair("turbulence", "none", 0.05),
                       pair("sensing", "nominal", math.nan), pair("sensing_map", "nominal/exact", 0.16)])
    assert (m.overall, m.max_per_level, m.max_axis, m.max_level, m.too_few) == (0.02, 0.05, "turbulence", "none", 1)


def test_the_table_states_the_mdd_of_every_pair_and_each_vehicles_summary() -> None:
    info, rows = _run()
    lines = level_table_lines(level_rates(info, rows), level_pairs(info, rows))
    degraded = [line for line in lines if "100 pairs, success +10.0%" in line]  # sensing and sensing_map
    assert len(degraded) == 2
    for line in degraded:
        assert f"(MDD {100 * DEGRADED:.1f} points), collision -15.0%" in line
        assert line.endswith(f"(MDD {100 * _connor_fixed_psi(100, 0.15):.1f} points)")
    few = [line for line in lines if ": 5 pairs," in line]  # sensing perfect, map_error wrong, perfect/wrong
    assert len(few) == 3 and all("(MDD n/a)" in line and "too few to call" in line for line in few)
    summary = ("small_quad MDD of paired success differences (alpha 0.05, power 0.8, from the observed discordance): "
               f"rrt_mpc - ppo overall {100 * OVERALL:.1f} points, per level at most {100 * DEGRADED:.1f} points "
               "(sensing degraded), 2 levels with fewer than 10 pairs left out")
    assert (f"{100 * OVERALL:.1f}", f"{100 * DEGRADED:.1f}") == ("6.8", "12.4")
    # after the quad's rows, before the UAM's; the UAM's last
    assert lines.index(summary) + 1 == next(k for k, line in enumerate(lines) if line.startswith("uam_multicopter,"))
    assert lines[-1].startswith("uam_multicopter MDD of paired success differences") and "left out" not in lines[-1]


def test_the_json_carries_the_mdd_and_its_summary_beside_the_axes(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    info, rows = _run()
    pairs = level_pairs(info, rows)
    data = level_json(level_rates(info, rows), pairs)
    assert set(data["small_quad"]) == {"all", "air", "turbulence", "sensing", "map_error", "sensing_map"}
    entry = data["small_quad"]["sensing"]["degraded"]["paired"]["rrt_mpc - ppo"]
    assert entry["success"]["mdd"] == pytest.approx(DEGRADED, abs=1e-9)
    assert entry["collision"]["mdd"] == pytest.approx(_connor_fixed_psi(100, 0.15), abs=1e-9)
    assert level_mdd_json(level_mdds(pairs))["small_quad"] == {"rrt_mpc - ppo": {
        "overall": pytest.approx(OVERALL, abs=1e-9), "max_per_level": pytest.approx(DEGRADED, abs=1e-9),
        "max_level": "sensing degraded", "levels_too_few": 2, "alpha": 0.05, "power": 0.8}}
    # the run's last line of JSON: NaN (too few pairs) as null
    write_run_info(info, tmp_path)
    write_metrics_csv(rows, tmp_path / "metrics.csv")
    write_summary_json(summarize_run(rows, resamples=50), tmp_path / "summary.json")
    print_headline_json(tmp_path)
    last = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert last["by_level"]["small_quad"]["map_error"]["wrong"]["paired"]["rrt_mpc - ppo"]["success"]["mdd"] is None
    assert last["by_level"]["small_quad"]["all"]["all"]["paired"]["rrt_mpc - ppo"]["success"]["mdd"] == (
        pytest.approx(OVERALL, abs=1e-9))
    assert last["by_level_mdd"]["small_quad"]["rrt_mpc - ppo"]["max_level"] == "sensing degraded"
    assert set(last["by_level_mdd"]) == {"small_quad", "uam_multicopter"}
