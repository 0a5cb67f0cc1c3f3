"""Statistics that never pool vehicles: Wilson and Newcombe intervals and MDDs against published and hand-computed
numbers, summary.json per vehicle (no pooled statistic anywhere), older files still read, task difficulty bins, and
the CLI's end-of-run summary per vehicle."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from compare.cli.printout import print_summary
from compare.results.difficulty import (
    ScenarioConditions,
    building_coverage,
    success_by_difficulty,
)
from compare.results.metrics import EpisodeMetrics
from compare.results.stats import MIN_INTERVAL_N, PairedCounts, design_mdd_rate, mdd, newcombe_paired_interval
from compare.results.summary import (
    IntervalMethods,
    PairedStat,
    PowerConfig,
    mdd_gap,
    read_summary_json,
    summarize,
    summarize_run,
    summary_to_json,
    write_summary_json,
)
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.city.buildings import Building, BuildingMap
from uam_fdm.stats import wilson_interval

Z_SUM = 1.959963984540054 + 0.8416212335729143  # z_0.975 + z_0.8


def row(pilot: str, episode: int, *, vehicle: str = "small_quad", scenario: str = "town", seed: int = 0,
        success: bool = True, **values) -> EpisodeMetrics:
    base = {"scenario": scenario, "episode": episode, "method": pilot, "seed": seed, "map": "m", "vehicle": vehicle,
            "outcome": "success" if success else "collision", "success": success, "collision": not success,
            "failure_reason": "" if success else "collision", "min_clearance_m": 3.0, "time_below_2m_s": 0.0,
            "time_below_5m_s": 1.0, "time_s": 20.0, "path_length_m": 100.0, "straight_line_m": 90.0,
            "spl": 0.9 if success else 0.0, "energy_kj": 50.0, "compute_ms_mean": 1.0, "compute_ms_max": 2.0,
            "plan_time_s": math.nan}
    base.update(values)
    return EpisodeMetrics(**base)


# ---- intervals and MDD ----------------------------------------------------------------------------------
def test_wilson_interval_matches_published_values():
    # Newcombe (1998), "Two-sided confidence intervals for the single proportion", example 81/263
    low, high = wilson_interval(81, 263)
    assert (round(low, 4), round(high, 4)) == (0.2553, 0.3662)
    assert wilson_interval(0, 10) == (0.0, pytest.approx(0.2775, abs=1e-4))
    assert wilson_interval(10, 10) == (pytest.approx(0.7225, abs=1e-4), 1.0)  # the bootstrap would give [1, 1]
    with pytest.raises(ValueError):
        wilson_interval(3, 0)


def test_newcombe_paired_interval_matches_the_published_example():
    # Fagerland, Lydersen & Laake (2017), ch. 8: Cavo et al. (2012), 59 / 6 / 16 / 80 -> -0.0621 (-0.1186 to -0.0046)
    counts = PairedCounts(both=59, first_only=6, second_only=16, neither=80)
    low, high = newcombe_paired_interval(counts)
    assert (round(low, 4), round(high, 4)) == (-0.1186, -0.0046)
    # every pair agrees (both always succeed): not the bootstrap's [0, 0] but a real interval about 0
    low, high = newcombe_paired_interval(PairedCounts(10, 0, 0, 0))
    assert low == pytest.approx(-high) and high == pytest.approx(1.0 - wilson_interval(10, 10)[0])
    assert PairedCounts.of(np.array([1, 1, 0, 0, 1]), np.array([1, 0, 1, 0, 1])) == PairedCounts(2, 1, 1, 1)


def test_minimum_detectable_difference_by_hand():
    assert mdd(1.0, 4) == pytest.approx(Z_SUM / 2.0)
    assert mdd(2.0, 100, alpha=0.05, power=0.8) == pytest.approx(Z_SUM * 0.2)
    assert design_mdd_rate(100) == pytest.approx(Z_SUM * math.sqrt(0.5) / 10.0)  # 0.198: 20 points at 100 pairs
    assert design_mdd_rate(400) == pytest.approx(design_mdd_rate(100) / 2.0)


# ---- summary per vehicle --------------------------------------------------------------------------------
def hand_rows(vehicle: str = "small_quad", scenario: str = "town") -> list[EpisodeMetrics]:
    """ppo and rrt_mpc on five episodes: clearance differences 1..5 m, successes ppo 1,1,1,0,1 vs rrt 1,0,0,0,1."""
    ppo_ok, rrt_ok = [1, 1, 1, 0, 1], [1, 0, 0, 0, 1]
    rows = []
    for ep in range(5):
        rows.append(row("ppo", ep, vehicle=vehicle, scenario=scenario, success=bool(ppo_ok[ep]),
                        min_clearance_m=10.0 + ep + 1.0, time_s=20.0 + ep))
        rows.append(row("rrt_mpc", ep, vehicle=vehicle, scenario=scenario, success=bool(rrt_ok[ep]),
                        min_clearance_m=10.0, time_s=25.0 + 2 * ep))
    return rows


def test_paired_differences_and_mdd_on_hand_made_numbers():
    s = summarize(hand_rows(), resamples=400)
    assert s.vehicles == ("small_quad",) and s.vehicle == "small_quad"
    assert s.intervals == IntervalMethods("wilson", "newcombe-hybrid-score", ("success", "collision"))
    assert s.power == PowerConfig(0.05, 0.8, 0.5)
    ppo = s.pilots["ppo"].stats["success"]
    assert (ppo.mean, ppo.n) == (0.8, 5) and (ppo.ci_low, ppo.ci_high) == wilson_interval(4, 5)
    (p,) = s.paired
    clear = p.stats["min_clearance_m"]
    assert isinstance(clear, PairedStat) and clear.mean == pytest.approx(3.0) and clear.n == 5
    assert clear.sd == pytest.approx(math.sqrt(2.5))                       # differences 1, 2, 3, 4, 5
    # five pairs: below MIN_INTERVAL_N, so no bootstrap interval, no MDD from the spread, no call on zero
    assert (clear.ci_low, clear.ci_high, clear.mdd, clear.excludes_zero) == (None, None, None, None)
    assert mdd_gap(clear) == "fewer than 10 pairs" and clear.mdd_design is None
    succ = p.stats["success"]
    assert succ.mean == pytest.approx(0.4) and succ.n == 5                # differences 0, 1, 1, 0, 0
    assert (succ.ci_low, succ.ci_high) == newcombe_paired_interval(PairedCounts(2, 2, 0, 1))  # a rate's: kept
    assert succ.sd == pytest.approx(math.sqrt(0.3)) and succ.mdd is None
    assert succ.mdd_design == pytest.approx(Z_SUM * math.sqrt(0.5 / 5))   # a design value needs no spread
    assert succ.excludes_zero is None
    time = p.stats["time_s"]                                               # only where both succeeded: 0 and 4
    assert time.n == 2 and time.mean == pytest.approx(((20 - 25) + (24 - 33)) / 2)
    assert time.sd == pytest.approx(np.std([-5.0, -9.0], ddof=1))
    one = summarize([row("ppo", 0), row("rrt_mpc", 0, min_clearance_m=2.0)]).paired[0].stats["min_clearance_m"]
    assert one.n == 1 and one.sd is None and one.mdd is None and one.excludes_zero is None
    # the same five twice: ten pairs, at MIN_INTERVAL_N, so the MDD and the call by hand
    (p10,) = summarize(hand_rows(scenario="a") + hand_rows(scenario="b"), resamples=400).paired
    clear, succ = p10.stats["min_clearance_m"], p10.stats["success"]
    assert clear.n == MIN_INTERVAL_N == 10 and clear.sd == pytest.approx(math.sqrt(20.0 / 9.0))
    assert clear.mdd == pytest.approx(Z_SUM * math.sqrt(20.0 / 9.0) / math.sqrt(10))  # 1.32 m
    assert clear.ci_low is not None and clear.ci_low > 0.0 and clear.excludes_zero is True
    assert succ.sd == pytest.approx(math.sqrt(2.4 / 9.0))
    assert succ.mdd == pytest.approx(Z_SUM * math.sqrt(2.4 / 9.0) / math.sqrt(10))
    low, high = newcombe_paired_interval(PairedCounts(4, 4, 0, 2))
    assert (succ.ci_low, succ.ci_high) == (low, high) and succ.excludes_zero is (low > 0.0)


def two_vehicle_rows() -> list[EpisodeMetrics]:
    uam = [row(r.method, r.episode, vehicle="uam_multicopter", scenario="city-uam", success=r.success,
               min_clearance_m=r.min_clearance_m + 20.0, energy_kj=2000.0) for r in hand_rows()]
    return hand_rows(scenario="town-quad") + hand_rows(scenario="park-quad") + uam


def _blocks_with_statistics(data: dict, where: str = "") -> list[tuple[str, list]]:
    """Every (key path, vehicles) of a summary.json block that holds per-pilot statistics."""
    found = [(where or "<root>", data.get("vehicles"))] if data.get("methods") else []
    for key in ("by_vehicle", "by_scenario"):
        for name, part in (data.get(key) or {}).items():
            found += _blocks_with_statistics(part, f"{where}{key}.{name}.")
    return found


def test_summary_json_never_pools_vehicles(tmp_path):
    rows = two_vehicle_rows()
    with pytest.raises(ValueError, match=r"2 vehicles \(small_quad, uam_multicopter\).*never pools"):
        summarize(rows)
    s = summarize_run(rows, resamples=200)
    assert s.vehicles == ("small_quad", "uam_multicopter") and s.pilots == {} and s.paired == ()
    assert list(s.by_vehicle) == ["small_quad", "uam_multicopter"]
    assert s.by_vehicle["uam_multicopter"] == summarize([r for r in rows if r.vehicle == "uam_multicopter"],
                                                        resamples=200)
    assert s.by_vehicle["small_quad"].pilots["ppo"].episodes == 10  # its two scenarios, and only its own
    assert s.by_scenario["city-uam"].vehicle == "uam_multicopter"
    data = json.loads(write_summary_json(s, tmp_path / "summary.json").read_text())
    assert "methods" not in data and "paired" not in data
    blocks = _blocks_with_statistics(data)
    assert len(blocks) == 2 + 3 and all(len(v) == 1 for _, v in blocks), blocks
    # nested blocks leave out the settings they share with the file's top
    assert set(data["by_vehicle"]["small_quad"]) == {"vehicles", "methods", "paired"}
    pair = data["by_vehicle"]["small_quad"]["paired"]["ppo - rrt_mpc"]
    assert set(pair["success"]) == {"mean_diff", "ci_low", "ci_high", "n", "over", "sd", "mdd", "mdd_design"}
    assert "mdd_design" not in pair["min_clearance_m"]
    back = read_summary_json(tmp_path / "summary.json")
    assert back == s and back.per_vehicle() == s.by_vehicle
    assert write_summary_json(back, tmp_path / "again.json").read_bytes() == (tmp_path / "summary.json").read_bytes()
    # one vehicle: the run-wide block is that vehicle's (files read by older tools keep their top-level "methods")
    one = summarize_run(hand_rows(), resamples=200)
    assert one.pilots == one.by_vehicle["small_quad"].pilots and one.per_vehicle() == one.by_vehicle
    assert "methods" in summary_to_json(one)


def test_a_summary_json_written_before_per_vehicle_summaries_still_reads(tmp_path):
    stat = {"mean": 0.5, "ci_low": 0.0, "ci_high": 1.0, "n": 2, "over": "all"}
    old = {"bootstrap": {"resamples": 2000, "confidence": 0.95, "seed": 0, "method": "percentile"},
           "metrics": ["success", "energy_kj"],
           "methods": {"ppo": {"episodes": 2, "failure_reasons": {}, "success": stat,
                               "energy_kj": {**stat, "mean": 336}}},
           "paired": {"ppo - rrt_mpc": {"episodes": 2, "success": {"mean_diff": 0.5, "ci_low": 0.0, "ci_high": 1.0,
                                                                   "n": 2}}},
           "by_scenario": {"a": {"bootstrap": {"resamples": 2000}, "metrics": ["success"], "methods": {
               "ppo": {"episodes": 2, "success": stat}}, "paired": {}}}}
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(old))
    s = read_summary_json(path)
    assert s.vehicles == () and s.by_vehicle is None and s.per_vehicle() is None  # may pool: the report recomputes
    assert s.intervals == IntervalMethods() and s.power == PowerConfig()
    p = s.paired[0].stats["success"]
    assert isinstance(p, PairedStat) and (p.mean, p.sd, p.mdd, p.mdd_design) == (0.5, None, None, None)
    assert s.by_scenario["a"].bootstrap.resamples == 2000 and s.by_scenario["a"].metrics == ("success",)
    assert read_summary_json(write_summary_json(s, tmp_path / "again.json")) == s


def test_cli_summary_is_per_vehicle(tmp_path, capsys):
    write_summary_json(summarize_run(two_vehicle_rows(), resamples=100), tmp_path / "summary.json")
    print_summary(tmp_path)
    out = capsys.readouterr().out
    assert "small_quad: 2 scenarios" in out and "small_quad / park-quad" in out and "small_quad / town-quad" in out
    assert "uam_multicopter: scenario city-uam" in out and "uam_multicopter / city-uam" not in out
    assert out.count("ppo - rrt_mpc: success difference +40% [") == 2
    assert "over 5 paired episodes" in out and "over 10 paired episodes" in out
    # ten pairs (small_quad): an MDD; five (uam_multicopter): too few, said in words
    assert f"detectable (alpha 0.05, power 0.8): {100 * Z_SUM * math.sqrt(2.4 / 9.0 / 10):.0f}%" in out
    assert "detectable (alpha 0.05, power 0.8): n/a (fewer than 10 pairs)" in out
    assert "too few pairs to call (fewer than 10)" in out
    first = out.splitlines()[0]
    assert first.startswith("small_quad: 2 scenarios") and not any(line.startswith("all") for line in out.splitlines())


# ---- task difficulty ------------------------------------------------------------------------------------
def test_building_coverage_and_density_altitude():
    squares = [Building(0, (20.0, 20.0), (10.0, 10.0), 10.0), Building(1, (25.0, 20.0), (10.0, 10.0), 30.0),
               Building(2, (90.0, 50.0), (4.0, 4.0), 10.0)]  # 0 and 1 overlap by half: counted once
    bmap = BuildingMap(squares, (0.0, 0.0, 0.0), (100.0, 100.0, 50.0), name="squares")
    assert building_coverage(bmap) == pytest.approx((150.0 + 16.0) / 100.0 ** 2)
    assert density_altitude_m(1.225) == pytest.approx(0.0, abs=1e-6)
    assert density_altitude_m(1.0066) == pytest.approx(2000.0, abs=5.0)   # ISA density at 2000 m


def test_success_by_difficulty_bins_on_hand_made_rows():
    rows = []
    for ep in range(8):  # legs 100..800 m; ppo fails the four longest, rrt_mpc only the longest
        for m, ok in (("ppo", ep < 4), ("rrt_mpc", ep < 7)):
            rows.append(row(m, ep, scenario=("a" if ep % 2 else "b"), success=ok, straight_line_m=100.0 * (ep + 1)))
    conditions = {"a": ScenarioConditions("a", "small_quad", 0.30, "moderate", 1.0),
                  "b": ScenarioConditions("b", "small_quad", 0.10, "none", 1.2)}
    leg, cover, turb, dens = success_by_difficulty(rows, conditions, ["ppo", "rrt_mpc"])
    assert leg.bins == ("100–275", "275–450", "450–625", "625–800") and leg.left_out == 0
    assert [b.n for b in leg.rates["ppo"]] == [2, 2, 2, 2]
    assert [b.rate for b in leg.rates["ppo"]] == [1.0, 1.0, 0.0, 0.0]
    assert [b.rate for b in leg.rates["rrt_mpc"]] == [1.0, 1.0, 1.0, 0.5]
    last = leg.rates["rrt_mpc"][3]
    assert (last.low, last.high) == wilson_interval(1, 2)              # a bin of two shows as wide as it is
    assert cover.bins == ("10", "30") and turb.bins == ("none", "moderate")
    assert dens.bins[0].startswith("1.200") and dens.bins[1].startswith("1.000")  # thinner air is harder: right
    assert [b.n for b in turb.rates["ppo"]] == [4, 4]
    # a scenario run.json does not describe: its episodes are left out of its axes, not guessed
    part = success_by_difficulty(rows, {"a": conditions["a"]}, ["ppo"])
    assert part[1].left_out == 4 and sum(b.n for b in part[1].rates["ppo"]) == 4 and part[0].left_out == 0
