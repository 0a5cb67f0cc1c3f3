"""The benchmark sets, both families (the tiered benchmark and benchmark-perfect, today's set before the tiers):
generated the same every time, versioned by what they hold, held out from the learned pilot's cities and from each
other, per vehicle, quick a subset of full, every scenario through the strict loader, axes that vary; the tiers'
sensing and map-error levels balanced against the air and turbulence; benchmark-perfect's versions unchanged."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
import yaml

import compare.scenarios.benchmark as bench
from compare.cli import main
from compare.results.difficulty import building_coverage
from compare.results.run_info import read_run_info
from compare.run.campaign import RunConfig, plan_cells, write_run_files
from compare.scenarios.benchmark import (
    AIR_LEVELS,
    DENSITY_LEVELS,
    DESIGN,
    FULL,
    PERFECT_DESIGN,
    QUICK,
    TURBULENCE_LEVELS,
    VALIDATION,
    VALIDATION_SEED_OFFSET,
    BenchmarkDesign,
    TaskSet,
    VehicleBenchmark,
    build_task_set,
    levels,
    task_set_version,
)
from compare.scenarios.fingerprint import scenario_fingerprint
from compare.scenarios.scenario import load_scenario, scenario_from_dict
from compare.scenarios.sets import builtin_sets, resolve_scenarios
from rl.task.cities import EVAL_SEEDS, TRAIN_SEEDS
from rl.task.vehicles import task_for
from rl.training.evaluation import VALIDATION_OFFSET
from uam_fdm.air.atmosphere import density_altitude_m
from uam_fdm.city import generator as citygen

VEHICLES = ("small_quad", "uam_multicopter")
ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module", params=[DESIGN, PERFECT_DESIGN], ids=["tiered", "perfect"])
def family(request: pytest.FixtureRequest) -> BenchmarkDesign:
    return request.param


@pytest.fixture(scope="module")
def full(family: BenchmarkDesign) -> TaskSet:
    return build_task_set(family.sets[0])


@pytest.fixture(scope="module")
def quick(family: BenchmarkDesign) -> TaskSet:
    return build_task_set(family.sets[1])


def _bins(vb: VehicleBenchmark, index: int) -> tuple[tuple[float, float], ...]:
    """The leg bins of scenario `index` of a vehicle (its city component's, when its cities are a mixture)."""
    return vb.component_leg_bins_m[index % len(vb.component_leg_bins_m)] if vb.component_leg_bins_m else vb.leg_bins_m


def _seed(sc) -> int:
    return sc.raw["map"]["generator"]["seed"]


def _by_vehicle(task_set: TaskSet) -> dict[str, list]:
    out: dict[str, list] = {v: [] for v in VEHICLES}
    for sc in task_set.scenarios:
        out[sc.vehicle_name].append(sc)
    return out


# ---- determinism and version ---------------------------------------------------------------------------
def test_same_tasks_and_version_twice(family: BenchmarkDesign, full: TaskSet, quick: TaskSet) -> None:
    again = build_task_set(family.sets[1])
    assert again.info == quick.info and [s.raw for s in again.scenarios] == [s.raw for s in quick.scenarios]
    assert [scenario_fingerprint(s) for s in again.scenarios] == [scenario_fingerprint(s) for s in quick.scenarios]
    assert task_set_version(full.scenarios, family.generator_version) == full.info.version != quick.info.version
    assert full.info.version.startswith(f"{family.generator_version}+") and len(full.info.version) == 12
    assert {sc.task_set for sc in full.scenarios} == {full.info} and full.info.name == family.sets[0]


def test_same_in_a_fresh_process(family: BenchmarkDesign, quick: TaskSet) -> None:
    code = ("import json; from compare.scenarios.benchmark import build_task_set; "
            f"s = build_task_set('{family.sets[1]}'); "
            "print(json.dumps([s.info.version, [sc.raw for sc in s.scenarios]]))")
    env = {**os.environ, "PYTHONHASHSEED": "12345", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    version, raws = json.loads(out.stdout)
    assert version == quick.info.version and raws == json.loads(json.dumps([sc.raw for sc in quick.scenarios]))


def test_version_changes_with_the_output(family: BenchmarkDesign, quick: TaskSet,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    name = family.sets[1]
    fewer = build_task_set(name, dataclasses.replace(family, quick_legs=2))
    assert fewer.info.version != quick.info.version
    bins = dataclasses.replace(family.vehicles[0], leg_bins_m=((50.0, 110.0), (110.0, 180.0), (180.0, 240.0)))
    other = build_task_set(name, dataclasses.replace(family, vehicles=(bins, family.vehicles[1])))
    assert other.info.version != quick.info.version

    # the city generator changes (the loader's cities lose their last building) while the mappings, which
    # name a city by its generator parameters and seed, stay the same: the version still changes
    original = citygen.generate_city

    def fewer_buildings(params, seed, name=""):
        city = original(params, seed, name)
        return type(city)(city.buildings[:-1], city.bounds_min_m, city.bounds_max_m, city.no_fly, name=city.name)

    monkeypatch.setattr(citygen, "generate_city", fewer_buildings)
    changed = build_task_set(name)
    assert [s.raw for s in changed.scenarios] == [s.raw for s in quick.scenarios]
    assert changed.info.version != quick.info.version


# ---- held out, per vehicle, subsets --------------------------------------------------------------------
def test_city_seeds_are_held_out(family: BenchmarkDesign, full: TaskSet) -> None:
    seeds = [_seed(sc) for sc in full.scenarios]
    assert len(set(seeds)) == len(seeds)
    test_pool = range(EVAL_SEEDS.start, EVAL_SEEDS.start + VALIDATION_OFFSET)
    validation_pool = range(EVAL_SEEDS.start + VALIDATION_OFFSET, EVAL_SEEDS.stop)
    for pool in (TRAIN_SEEDS, test_pool, validation_pool, EVAL_SEEDS):
        assert not any(s in pool for s in seeds)
    assert all(s >= 3_000_000 for s in seeds)
    for v, seed_range in bench.city_seed_ranges(family).items():
        assert sorted(_seed(sc) for sc in full.scenarios if sc.vehicle_name == v) == list(seed_range)
    # and from the other family's sets and twins
    others = set()
    for other in (DESIGN, PERFECT_DESIGN):
        if other is not family:
            for twin in (other, bench.validation_design(other)):
                others |= {s for r in bench.city_seed_ranges(twin).values() for s in r}
    assert not others & set(seeds) and not others & {s + VALIDATION_SEED_OFFSET for s in seeds}
    # the cities are the learned pilot's distribution (its generator parameters) at the levels' density
    sc = full.scenarios[0]
    drawn = task_for(sc.vehicle_name, envelope=family.vehicles[0].envelope).cities.params(_seed(sc))
    made = citygen.params_from_config(sc.raw["map"]["generator"], "x", "map.generator")[0]
    assert dataclasses.replace(made, density=drawn.density, fill_range=drawn.fill_range) == drawn
    assert sc.city.name == f"gen-{_seed(sc)}"


def test_per_vehicle_sets_at_the_vehicles_scale(family: BenchmarkDesign, full: TaskSet) -> None:
    per = _by_vehicle(full)
    for vb in family.vehicles:
        scenarios = per[vb.vehicle]
        assert len(scenarios) == family.scenarios_per_vehicle
        assert sum(len(s.episodes) for s in scenarios) == family.scenarios_per_vehicle * family.legs_per_scenario
        nav = task_for(vb.vehicle, envelope=vb.envelope)
        for i, sc in enumerate(scenarios):
            assert sc.name.startswith(f"{family.prefix}-{vb.tag}-") and sc.pilots == ("ppo", "rrt_mpc", "apf")
            assert sc.seeds == family.seeds
            for ep in sc.episodes:
                task = ep.task
                a, b = task.start_m, task.goal_m
                lo, hi = _bins(vb, i)[ep.index % 3]
                assert lo <= math.dist(a, b) <= hi
                assert all(vb.altitude_m[0] <= z <= vb.altitude_m[1] for z in (a[2], b[2]))
                assert task.goal_radius_m == nav.tasks.goal_radius_m
                expected = nav.tasks.timeout_s(math.dist(a, b), b[2] - a[2], sc.vehicle.controller.max_speed_m_s,
                                               sc.vehicle.controller.max_vertical_speed_m_s)
                assert task.timeout_s == pytest.approx(expected, abs=0.05)
                clear = sc.city.clearance([a, b], sc.vehicle.collision_radius_m).distance_m
                assert (clear >= nav.tasks.min_clearance_m).all()
    assert {s.goal_radius_m for s in (e.task for e in per["uam_multicopter"][0].episodes)} == {10.0}


def test_quick_is_a_subset_of_full(family: BenchmarkDesign, full: TaskSet, quick: TaskSet) -> None:
    named = {sc.name: sc for sc in full.scenarios}
    per = _by_vehicle(quick)
    assert all(len(per[v]) == family.quick_scenarios for v in VEHICLES)
    for sc in quick.scenarios:
        big = named[sc.name]
        assert len(sc.episodes) == family.quick_legs < len(big.episodes)
        assert sc.episodes == big.episodes[:len(sc.episodes)]  # same indices, same tasks: the same cells
        assert {k: v for k, v in sc.raw.items() if k != "episodes"} == \
               {k: v for k, v in big.raw.items() if k != "episodes"}
        assert scenario_fingerprint(sc)["map"] == scenario_fingerprint(big)["map"]
        assert scenario_fingerprint(sc)["conditions"] == scenario_fingerprint(big)["conditions"]
    assert quick.info.description.startswith(f"Held-out generated tasks per vehicle (the first of {family.sets[0]}'s)")


def test_the_validation_twin_is_the_same_design_on_other_cities(family: BenchmarkDesign, full: TaskSet) -> None:
    """The validation twin: where a pilot's choices are tuned. Scenario i has the test set's levels, leg bins and
    time-limit rule in city seed + 200,000: disjoint from the test set and every learned pilot's pool."""
    name, _, validation, validation_quick = family.sets
    twin = build_task_set(validation)
    assert twin.info.name == validation and twin.info.version != full.info.version
    assert f"validation twin of {name} (city seeds +200,000)" in twin.info.description
    assert len(twin.scenarios) == len(full.scenarios)
    test_seeds = {_seed(sc) for sc in full.scenarios}
    for mine, theirs in zip(twin.scenarios, full.scenarios, strict=True):
        assert mine.name == theirs.name.replace(f"{family.prefix}-", f"{family.prefix}-validation-", 1)
        assert _seed(mine) == _seed(theirs) + VALIDATION_SEED_OFFSET and _seed(mine) not in test_seeds
        assert not any(_seed(mine) in pool for pool in (TRAIN_SEEDS, EVAL_SEEDS))
        assert mine.wind.turbulence == theirs.wind.turbulence and len(mine.episodes) == len(theirs.episodes)
        assert (mine.sensing.label, mine.map_error.label) == (theirs.sensing.label, theirs.map_error.label)
        assert mine.city.buildings != theirs.city.buildings
        i = int(mine.name.rsplit("-", 1)[1])
        for a, b in zip(mine.episodes, theirs.episodes, strict=True):  # the same leg-length bin
            vb = next(v for v in family.vehicles if v.vehicle == mine.vehicle_name)
            lo, hi = _bins(vb, i)[a.index % 3]
            assert lo <= math.dist(a.task.start_m, a.task.goal_m) <= hi and a.index == b.index
    # its quick subset: the twin's first scenarios with their first legs, the same names and tasks
    quick = build_task_set(validation_quick)
    assert quick.info.name == validation_quick and f"the first of {validation}'s" in quick.info.description
    by_name = {sc.name: sc for sc in twin.scenarios}
    assert len(quick.scenarios) == len(family.vehicles) * family.quick_scenarios
    for sc in quick.scenarios:
        whole = by_name[sc.name]
        assert len(sc.episodes) == family.quick_legs
        assert [e.task for e in sc.episodes] == [e.task for e in whole.episodes[:family.quick_legs]]
    # the twin's seeds may not land on another vehicle's test cities
    first = family.vehicles[0].first_seed + VALIDATION_SEED_OFFSET
    crowded = dataclasses.replace(family.vehicles[1], first_seed=family.vehicles[0].first_seed + VALIDATION_SEED_OFFSET)
    with pytest.raises(ValueError, match=f"small_quad: city seeds {first}-{first + 35} overlap the uam_multicopter "
                                         f"{name} cities"):
        build_task_set(validation, dataclasses.replace(family, vehicles=(family.vehicles[0], crowded)))


# ---- strict checks and the CLI -------------------------------------------------------------------------
def test_every_scenario_passes_the_strict_checks_as_a_file(full: TaskSet, tmp_path: Path) -> None:
    for sc in full.scenarios:  # built by the loader: again from its mapping, and the first few from a file
        assert scenario_fingerprint(scenario_from_dict(sc.raw, "again", Path("."))) == scenario_fingerprint(sc)
    for sc in full.scenarios[::27]:
        path = tmp_path / f"{sc.name}.yaml"
        path.write_text(yaml.safe_dump(sc.raw, sort_keys=False))
        assert scenario_fingerprint(load_scenario(path)) == scenario_fingerprint(sc)
    bad = json.loads(json.dumps(full.scenarios[0].raw))
    bad["episodes"][0]["start"][2] = -1.0
    with pytest.raises(ValueError, match=r"benchmark:benchmark-quad-000: episodes\[0\].start"):
        scenario_from_dict(bad, "benchmark:benchmark-quad-000", Path("."))


def test_sets_resolve_and_validate(family: BenchmarkDesign, quick: TaskSet,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    name = family.sets[1]
    assert set(family.sets) <= set(builtin_sets()) and {FULL, QUICK, VALIDATION} <= set(builtin_sets())
    resolved = resolve_scenarios(name)
    assert [s.name for s in resolved] == [s.name for s in quick.scenarios] and resolved[0].task_set == quick.info
    assert resolved[0].source == f"{name}:{resolved[0].name}"
    assert main(["validate", name]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(quick.scenarios) and all(f": ok ({family.prefix}-" in line for line in lines)
    with pytest.raises(ValueError, match="unknown benchmark set"):
        build_task_set("benchmark-huge")
    with pytest.raises(ValueError, match="is not one of the design's"):
        build_task_set(name, PERFECT_DESIGN if family is DESIGN else DESIGN)
    leaky = dataclasses.replace(family.vehicles[0], first_seed=1_049_990)
    with pytest.raises(ValueError, match="small_quad: city seeds 1049990-1050025 overlap the test and validation"):
        build_task_set(name, dataclasses.replace(family, vehicles=(leaky, family.vehicles[1])))
    onto = dataclasses.replace(family.vehicles[0], first_seed=(PERFECT_DESIGN if family is DESIGN else DESIGN
                                                               ).vehicles[0].first_seed)
    with pytest.raises(ValueError, match="small_quad: city seeds .* overlap the small_quad benchmark"):
        build_task_set(name, dataclasses.replace(family, vehicles=(onto, family.vehicles[1])))
    with pytest.raises(ValueError, match="must be a non-empty subset"):
        build_task_set(name, dataclasses.replace(family, quick_legs=13))


def test_run_json_records_the_task_set(family: BenchmarkDesign, quick: TaskSet, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    from compare.cli.printout import print_task_set

    scenarios = list(quick.scenarios)
    opts = RunConfig(out_dir=tmp_path, pilots=("apf",), progress=False)
    cells, notes = plan_cells(scenarios, opts, None)
    write_run_files(scenarios, opts, cells, notes, {})
    info = read_run_info(tmp_path)
    name = family.sets[1]
    assert info.task_set == quick.info and info.scenarios[0].source == f"{name}:{family.prefix}-quad-000"
    print_task_set(tmp_path)
    assert capsys.readouterr().out == f"task set {name}, version {quick.info.version}: {quick.info.description}\n"
    mixed = [*scenarios[:1], dataclasses.replace(scenarios[1], task_set=None)]
    write_run_files(mixed, RunConfig(out_dir=tmp_path / "mixed"), plan_cells(mixed, opts, None)[0], [], {})
    assert read_run_info(tmp_path / "mixed").task_set is None


def test_the_report_names_the_task_set_on_its_title_page(family: BenchmarkDesign, quick: TaskSet,
                                                         tmp_path: Path) -> None:
    from pypdf import PdfReader

    from compare.report.report import build_report
    from synthetic_run import write_run

    write_run(tmp_path, None)
    data = json.loads((tmp_path / "run.json").read_text())
    name = family.sets[1]
    data["suite"] = {"name": name, "version": quick.info.version, "description": quick.info.description}
    (tmp_path / "run.json").write_text(json.dumps(data))
    title = PdfReader(build_report(tmp_path)).pages[0].extract_text()
    assert f"Task set {name}, version {quick.info.version}: Held-out" in " ".join(title.split())


# ---- the difficulty axes -------------------------------------------------------------------------------
def test_the_difficulty_axes_vary(full: TaskSet) -> None:
    for vehicle, scenarios in _by_vehicle(full).items():
        n = len(scenarios)
        turbulence = Counter(sc.wind.turbulence.value for sc in scenarios)
        assert turbulence == {t: n // 3 for t in TURBULENCE_LEVELS}
        cover: dict[int, list[float]] = {}
        altitude: dict[int, list[float]] = {}
        for i, sc in enumerate(scenarios):
            lv = levels(i)
            assert sc.wind.turbulence.value == TURBULENCE_LEVELS[lv.turbulence]
            cover.setdefault(lv.density, []).append(building_coverage(sc.city))
            altitude.setdefault(lv.air, []).append(density_altitude_m(sc.air.density_kg_m3(0.0)))
            assert DENSITY_LEVELS[lv.density] in sc.description and AIR_LEVELS[lv.air].name in sc.description
        means = [sum(cover[k]) / len(cover[k]) for k in range(3)]
        assert means[0] < means[1] < means[2] and means[2] > 2 * means[0], (vehicle, means)
        assert max(abs(a) for a in altitude[0]) < 50.0            # sea level, standard day
        assert 900.0 < min(altitude[1]) and max(altitude[1]) < 2300.0  # DA grows ~36 m per K of offset
        assert 2300.0 < min(altitude[2]) and max(altitude[2]) < 4500.0
        lengths = [math.dist(e.task.start_m, e.task.goal_m) for sc in scenarios for e in sc.episodes]
        assert max(lengths) > 3.0 * min(lengths)
        blocked = [not sc.city.segment_free(e.task.start_m, e.task.goal_m, sc.vehicle.collision_radius_m)
                   for sc in scenarios for e in sc.episodes]
        assert sum(blocked) >= 0.9 * len(blocked), (vehicle, sum(blocked), len(blocked))


def test_the_levels_are_an_orthogonal_array() -> None:
    first9 = [levels(i) for i in range(9)]
    for a, b in (("turbulence", "density"), ("turbulence", "air"), ("density", "air")):
        assert len({(getattr(x, a), getattr(x, b)) for x in first9}) == 9
    assert len({(x.turbulence, x.density, x.air) for x in map(levels, range(27))}) == 27
    # the tiers: every pair of levels of any two axes equally often in 27 scenarios; balanced against the air and
    # the turbulence in every block of 9 too (sensing moves with density there), each level 12 times in 36
    axes = ("turbulence", "density", "air", "sensing", "map_error")
    block = [levels(i) for i in range(27)]
    for k, a in enumerate(axes):
        for b in axes[k + 1:]:
            assert set(Counter((getattr(x, a), getattr(x, b)) for x in block).values()) == {3}, (a, b)
    for tier in ("sensing", "map_error"):
        for other in ("turbulence", "air"):
            assert len({(getattr(x, tier), getattr(x, other)) for x in first9}) == 9, (tier, other)
        assert Counter(getattr(levels(i), tier) for i in range(36)) == {0: 12, 1: 12, 2: 12}
        assert {getattr(levels(i), tier) for i in range(6)} == {0, 1, 2} or tier == "map_error"
    assert {levels(i).map_error for i in range(6)} == {0, 2}  # the quick subset: exact and wrong maps
    assert density_altitude_m(1.225) == pytest.approx(0.0, abs=1e-9)
    assert density_altitude_m(0.9091) == pytest.approx(3000.0, abs=5.0)  # ISA density at 3 km


def test_a_benchmark_run_animates_nothing_unless_asked(quick: TaskSet) -> None:
    from compare.cli.run import resolve_videos

    tiny = load_scenario(Path(__file__).resolve().parents[2] / "data" / "tiny_scenario.yaml")
    assert resolve_videos(None, list(quick.scenarios)) == "none"
    assert resolve_videos(None, [tiny]) == "scenario"
    assert resolve_videos("all", list(quick.scenarios)) == "all"


def test_the_quick_set_stays_the_version_reported() -> None:
    """The sets are made from fixed settings (not the learned pilots' current training tasks): retraining a pilot
    in other air or cities leaves the benchmark, and before-and-after figures, comparable; benchmark-perfect is
    the headline set before the tiers, task for task (its version then was benchmark-quick's)."""
    assert build_task_set("benchmark-perfect-quick").info.version == "1+b27f29cc25"  # docs/benchmark.md
    assert build_task_set("benchmark-quick").info.version == "2+8e99cc8cc4"


def test_the_tiers_at_their_levels_and_the_uam_in_both_kinds_of_city(full: TaskSet, family: BenchmarkDesign) -> None:
    """The tiered benchmark: each scenario at its sensing and map-error level (the map error drawn from its city's
    seed), each level on 144 tasks per vehicle; winds to the envelopes'; the UAM's cities alternating between its
    districts and the shipped maps' scale. benchmark-perfect: perfect sensing over exact maps, no such keys."""
    for vb in family.vehicles:
        mine = _by_vehicle(full)[vb.vehicle]
        speeds = [math.hypot(*sc.wind.steady_enu_m_s[:2]) for sc in mine]
        assert max(speeds) <= vb.steady_wind_max_m_s + 0.1
        if not family.tiers:
            assert all("sensing" not in sc.raw and "map_error" not in sc.raw for sc in mine)
            assert {(sc.sensing.label, sc.map_error.label) for sc in mine} == {("perfect", "exact")}
            continue
        assert max(speeds) > 0.7 * vb.steady_wind_max_m_s
        for i, sc in enumerate(mine):
            lv = levels(i)
            assert sc.sensing.label == ("perfect", "nominal", "degraded")[lv.sensing]
            assert sc.map_error.label == ("exact", "outdated", "wrong")[lv.map_error]
            if sc.map_error.label != "exact":
                points = [p for e in sc.episodes for p in (list(e.task.start_m), list(e.task.goal_m))]
                assert sc.raw["map_error"] == {"preset": sc.map_error.label, "seed": _seed(sc), "keep_clear": points}
                assert sc.prior_map is not sc.city
        for tier in ("sensing", "map_error"):
            tasks = Counter()
            for sc in mine:
                tasks[getattr(sc, tier).label] += len(sc.episodes)
            assert set(tasks.values()) == {144}, (vb.vehicle, tier, tasks)
        if vb.component_leg_bins_m:  # every other city at the shipped maps' scale: smaller, narrower streets
            extents = [sc.city.bounds_max_m[0] - sc.city.bounds_min_m[0] for sc in mine]
            assert max(extents[1::2]) <= 1100.0 + 1e-6 and min(extents[0::2]) >= 1000.0 - 1e-6


# ---- the rates per level ---------------------------------------------------------------------------------
def test_a_benchmark_runs_rates_per_air_and_turbulence_level(quick: TaskSet, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Every scenario's levels are read from the air it flew; each level pools its scenarios' episodes, counted
    by outcome, with Wilson intervals; a benchmark run prints the table and its JSON carries it."""
    from compare.cli.printout import print_task_set
    from compare.results.level_rates import level_json, level_pairs, level_rates
    from compare.results.metrics import EpisodeMetrics, write_metrics_csv
    from compare.scenarios.levels import with_levels
    from uam_fdm.stats import wilson_interval

    # every other scenario flown at nominal sensing, every third over an outdated map: the levels cross
    scenarios = [with_levels(sc, "nominal" if k % 2 else None, "outdated" if k % 3 == 0 else None)
                 for k, sc in enumerate(quick.scenarios)]
    flown = {sc.name: sc for sc in scenarios}
    opts = RunConfig(out_dir=tmp_path, pilots=("apf", "ppo"), progress=False)
    cells, notes = plan_cells(scenarios, opts, None)
    write_run_files(scenarios, opts, cells, notes, {})
    outcomes = ("success", "collision", "timeout", "out_of_bounds")
    rows = [EpisodeMetrics(sc.name, e, m, 0, "city", sc.vehicle_name, outcomes[(k + e + j) % 4],
                           outcomes[(k + e + j) % 4] == "success", outcomes[(k + e + j) % 4] == "collision",
                           "" if (k + e + j) % 4 == 0 else outcomes[(k + e + j) % 4], *([1.0] * 12))
            for k, sc in enumerate(scenarios) for e in range(3) for j, m in enumerate(("apf", "ppo"))]
    write_metrics_csv(rows, tmp_path / "metrics.csv")
    info = read_run_info(tmp_path)
    rates = level_rates(info, rows)
    for vehicle, mine in _by_vehicle(quick).items():
        index = {sc.name: int(sc.name.rsplit("-", 1)[1]) for sc in mine}
        for axis, names, key in (("air", list(bench.LEVELS_OF_AIR), lambda i: levels(i).air),
                                 ("turbulence", list(TURBULENCE_LEVELS), lambda i: levels(i).turbulence)):
            got = [r for r in rates if r.vehicle == vehicle and r.axis == axis]
            assert [r.level for r in got if r.pilot == "apf"] == [n for n in names if any(
                key(i) == names.index(n) for i in index.values())]
            for r in got:
                mine_rows = [x for x in rows if x.method == r.pilot and x.vehicle == vehicle
                             and key(index[x.scenario]) == names.index(r.level)]
                assert r.episodes == len(mine_rows)
                assert r.successes == sum(x.success for x in mine_rows)
                assert r.collisions == sum(x.collision for x in mine_rows)
                assert r.timeouts == sum(x.outcome == "timeout" for x in mine_rows)
                assert dict(r.other) == dict(Counter(x.outcome for x in mine_rows if x.outcome == "out_of_bounds"))
                assert r.success_ci95 == wilson_interval(r.successes, r.episodes)
        (whole,) = [r for r in rates if r.vehicle == vehicle and r.axis == "all" and r.pilot == "ppo"]
        assert whole.episodes == 3 * len(mine) and whole.level == "all"
        for axis in ("sensing", "map_error", "sensing_map"):
            got = [r for r in rates if r.vehicle == vehicle and r.axis == axis and r.pilot == "ppo"]
            assert sorted(r.level for r in got) == sorted({_flown_level(flown, axis, n) for n in index})
            for r in got:
                assert r.episodes == 3 * sum(_flown_level(flown, axis, n) == r.level for n in index)
    pairs = level_pairs(info, rows)
    for p in pairs:  # the two pilots, in run order, on the same cells of the level
        assert {p.first, p.second} == {"apf", "ppo"}
        (a,) = [r for r in rates if (r.vehicle, r.axis, r.level, r.pilot) == (p.vehicle, p.axis, p.level, p.first)]
        (b,) = [r for r in rates if (r.vehicle, r.axis, r.level, r.pilot) == (p.vehicle, p.axis, p.level, p.second)]
        assert p.pairs == a.episodes == b.episodes
        assert p.success_diff == pytest.approx(a.success - b.success)
        assert p.collision_diff == pytest.approx(a.collision - b.collision)
        assert p.success_ci95[0] <= p.success_diff <= p.success_ci95[1]
        assert (p.success_excludes_zero is None) == (p.pairs < 10)
    assert {(p.axis, p.level) for p in pairs if p.vehicle == "small_quad"} == {
        (r.axis, r.level) for r in rates if r.vehicle == "small_quad"}
    data = level_json(rates, pairs)
    assert set(data) == set(VEHICLES) and set(data["small_quad"]) == {"all", "air", "turbulence", "sensing",
                                                                      "map_error", "sensing_map"}
    assert set(data["small_quad"]["sensing"]) == {_flown_level(flown, "sensing", sc.name) for sc in scenarios
                                                  if sc.vehicle_name == "small_quad"}
    assert f"{pairs[0].first} - {pairs[0].second}" in data["small_quad"]["all"]["all"]["paired"]
    print_task_set(tmp_path)
    out = capsys.readouterr().out
    assert "small_quad, per air, turbulence, sensing and map-error level (Wilson 95 % intervals; paired" in out
    assert "air hot-and-high" in out and "turbulence moderate" in out and "sensing_map nominal/outdated" in out
    assert f"{pairs[0].first} - {pairs[0].second}: " in out


def _flown_level(flown: dict, axis: str, name: str) -> str:
    """Scenario `name`'s sensing, map-error or sensing/map level as flown."""
    sc = flown[name]
    return {"sensing": sc.sensing.label, "map_error": sc.map_error.label,
            "sensing_map": f"{sc.sensing.label}/{sc.map_error.label}"}[axis]


def test_a_field_outside_every_air_level_is_other() -> None:
    from compare.results.level_rates import OTHER, air_level
    from compare.results.run_info import AtmosphereInfo, ScenarioInfo

    def at(elevation: float | None, offset: float | None) -> str:
        return air_level(ScenarioInfo("s", atmosphere=AtmosphereInfo(elevation, offset, 1.0)))

    assert at(0.0, 0.0) == "sea-level" and at(1200.0, 10.0) == "warm-and-raised" and at(2600.0, 30.0) == "hot-and-high"
    assert at(0.0, -10.0) == OTHER and at(1500.0, 15.0) == OTHER and at(None, 0.0) == OTHER


def test_a_map_error_keeps_clear_of_the_points_it_is_given(tmp_path: Path) -> None:
    """`map_error.keep_clear`: the errors keep clear of the points as of a leg's ends; bad points are named."""
    from uam_fdm.city.map_error import map_error_from_config
    from uam_fdm.errors import ConfigError

    cfg = map_error_from_config({"preset": "wrong", "seed": 3, "keep_clear": [[1, 2, 3], [4.5, 5, 6]]}, "f.yaml")
    assert cfg.keep_clear == ((1.0, 2.0, 3.0), (4.5, 5.0, 6.0)) and cfg.label == "wrong"  # not an override
    for bad, key in (([[1, 2]], "map_error.keep_clear[0]"), ([[1, 2, float("nan")]], "map_error.keep_clear[0]"),
                     ("here", "map_error.keep_clear")):
        with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
            map_error_from_config({"preset": "wrong", "keep_clear": bad}, "f.yaml")
