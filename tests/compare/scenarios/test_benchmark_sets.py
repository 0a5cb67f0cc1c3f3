"""The benchmark sets: generated the same every time, versioned by what they hold, held out from the learned
pilot's cities, per vehicle, quick a subset of full, every scenario through the strict loader, axes that vary."""
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
    QUICK,
    TURBULENCE_LEVELS,
    VALIDATION,
    VALIDATION_QUICK,
    VALIDATION_SEED_OFFSET,
    TaskSet,
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


@pytest.fixture(scope="module")
def full() -> TaskSet:
    return build_task_set(FULL)


@pytest.fixture(scope="module")
def quick() -> TaskSet:
    return build_task_set(QUICK)


def _seed(sc) -> int:
    return sc.raw["map"]["generator"]["seed"]


def _by_vehicle(task_set: TaskSet) -> dict[str, list]:
    out: dict[str, list] = {v: [] for v in VEHICLES}
    for sc in task_set.scenarios:
        out[sc.vehicle_name].append(sc)
    return out


# ---- determinism and version ---------------------------------------------------------------------------
def test_same_tasks_and_version_twice(full: TaskSet, quick: TaskSet) -> None:
    again = build_task_set(QUICK)
    assert again.info == quick.info and [s.raw for s in again.scenarios] == [s.raw for s in quick.scenarios]
    assert [scenario_fingerprint(s) for s in again.scenarios] == [scenario_fingerprint(s) for s in quick.scenarios]
    assert task_set_version(full.scenarios) == full.info.version != quick.info.version
    assert full.info.version.startswith(f"{bench.GENERATOR_VERSION}+") and len(full.info.version) == 12
    assert {sc.task_set for sc in full.scenarios} == {full.info} and full.info.name == FULL


def test_same_in_a_fresh_process(quick: TaskSet) -> None:
    code = ("import json; from compare.scenarios.benchmark import build_task_set; "
            "s = build_task_set('benchmark-quick'); "
            "print(json.dumps([s.info.version, [sc.raw for sc in s.scenarios]]))")
    env = {**os.environ, "PYTHONHASHSEED": "12345", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    version, raws = json.loads(out.stdout)
    assert version == quick.info.version and raws == json.loads(json.dumps([sc.raw for sc in quick.scenarios]))


def test_version_changes_with_the_output(quick: TaskSet, monkeypatch: pytest.MonkeyPatch) -> None:
    fewer = build_task_set(QUICK, dataclasses.replace(DESIGN, quick_legs=2))
    assert fewer.info.version != quick.info.version
    bins = dataclasses.replace(DESIGN.vehicles[0], leg_bins_m=((50.0, 110.0), (110.0, 180.0), (180.0, 240.0)))
    other = build_task_set(QUICK, dataclasses.replace(DESIGN, vehicles=(bins, DESIGN.vehicles[1])))
    assert other.info.version != quick.info.version

    # the city generator changes (the loader's cities lose their last building) while the mappings, which
    # name a city by its generator parameters and seed, stay the same: the version still changes
    original = citygen.generate_city

    def fewer_buildings(params, seed, name=""):
        city = original(params, seed, name)
        return type(city)(city.buildings[:-1], city.bounds_min_m, city.bounds_max_m, city.no_fly, name=city.name)

    monkeypatch.setattr(citygen, "generate_city", fewer_buildings)
    changed = build_task_set(QUICK)
    assert [s.raw for s in changed.scenarios] == [s.raw for s in quick.scenarios]
    assert changed.info.version != quick.info.version


# ---- held out, per vehicle, subsets --------------------------------------------------------------------
def test_city_seeds_are_held_out(full: TaskSet) -> None:
    seeds = [_seed(sc) for sc in full.scenarios]
    assert len(set(seeds)) == len(seeds)
    test_pool = range(EVAL_SEEDS.start, EVAL_SEEDS.start + VALIDATION_OFFSET)
    validation_pool = range(EVAL_SEEDS.start + VALIDATION_OFFSET, EVAL_SEEDS.stop)
    for pool in (TRAIN_SEEDS, test_pool, validation_pool, EVAL_SEEDS):
        assert not any(s in pool for s in seeds)
    assert all(s >= 3_000_000 for s in seeds)
    for v, seed_range in bench.city_seed_ranges().items():
        assert sorted(_seed(sc) for sc in full.scenarios if sc.vehicle_name == v) == list(seed_range)
    # the cities are the learned pilot's distribution (its generator parameters) at the levels' density
    sc = full.scenarios[0]
    drawn = task_for(sc.vehicle_name).cities.params(_seed(sc))
    made = citygen.params_from_config(sc.raw["map"]["generator"], "x", "map.generator")[0]
    assert dataclasses.replace(made, density=drawn.density, fill_range=drawn.fill_range) == drawn
    assert sc.city.name == f"gen-{_seed(sc)}"


def test_per_vehicle_sets_at_the_vehicles_scale(full: TaskSet) -> None:
    per = _by_vehicle(full)
    for vb in DESIGN.vehicles:
        scenarios = per[vb.vehicle]
        assert len(scenarios) == DESIGN.scenarios_per_vehicle
        assert sum(len(s.episodes) for s in scenarios) == DESIGN.scenarios_per_vehicle * DESIGN.legs_per_scenario
        nav = task_for(vb.vehicle)
        for sc in scenarios:
            assert sc.name.startswith(f"benchmark-{vb.tag}-") and sc.pilots == ("ppo", "rrt_mpc", "apf")
            assert sc.seeds == DESIGN.seeds
            for ep in sc.episodes:
                task = ep.task
                a, b = task.start_m, task.goal_m
                lo, hi = vb.leg_bins_m[ep.index % 3]
                assert lo <= math.dist(a, b) <= hi
                assert all(vb.altitude_m[0] <= z <= vb.altitude_m[1] for z in (a[2], b[2]))
                assert task.goal_radius_m == nav.tasks.goal_radius_m
                expected = nav.tasks.timeout_s(math.dist(a, b), b[2] - a[2], sc.vehicle.controller.max_speed_m_s,
                                               sc.vehicle.controller.max_vertical_speed_m_s)
                assert task.timeout_s == pytest.approx(expected, abs=0.05)
                clear = sc.city.clearance([a, b], sc.vehicle.collision_radius_m).distance_m
                assert (clear >= nav.tasks.min_clearance_m).all()
    assert {s.goal_radius_m for s in (e.task for e in per["uam_multicopter"][0].episodes)} == {10.0}


def test_quick_is_a_subset_of_full(full: TaskSet, quick: TaskSet) -> None:
    named = {sc.name: sc for sc in full.scenarios}
    per = _by_vehicle(quick)
    assert all(len(per[v]) == DESIGN.quick_scenarios for v in VEHICLES)
    for sc in quick.scenarios:
        big = named[sc.name]
        assert len(sc.episodes) == DESIGN.quick_legs < len(big.episodes)
        assert sc.episodes == big.episodes[:len(sc.episodes)]  # same indices, same tasks: the same cells
        assert {k: v for k, v in sc.raw.items() if k != "episodes"} == \
               {k: v for k, v in big.raw.items() if k != "episodes"}
        assert scenario_fingerprint(sc)["map"] == scenario_fingerprint(big)["map"]
        assert scenario_fingerprint(sc)["conditions"] == scenario_fingerprint(big)["conditions"]
    assert quick.info.description.startswith("Held-out generated tasks per vehicle (the first of benchmark's)")


def test_the_validation_twin_is_the_same_design_on_other_cities(full: TaskSet) -> None:
    """`benchmark-validation`: where a pilot's choices are tuned. Scenario i has the test set's levels, leg bins and
    time-limit rule in city seed + 200,000: disjoint from the test set and every learned pilot's pool."""
    twin = build_task_set(VALIDATION)
    assert twin.info.name == VALIDATION and twin.info.version != full.info.version
    assert "validation twin of benchmark (city seeds +200,000)" in twin.info.description
    assert len(twin.scenarios) == len(full.scenarios)
    test_seeds = {_seed(sc) for sc in full.scenarios}
    for mine, theirs in zip(twin.scenarios, full.scenarios, strict=True):
        assert mine.name == theirs.name.replace("benchmark-", "benchmark-validation-", 1)
        assert _seed(mine) == _seed(theirs) + VALIDATION_SEED_OFFSET and _seed(mine) not in test_seeds
        assert not any(_seed(mine) in pool for pool in (TRAIN_SEEDS, EVAL_SEEDS))
        assert mine.wind.turbulence == theirs.wind.turbulence and len(mine.episodes) == len(theirs.episodes)
        assert mine.city.buildings != theirs.city.buildings
        for a, b in zip(mine.episodes, theirs.episodes, strict=True):  # the same leg-length bin
            vb = next(v for v in DESIGN.vehicles if v.vehicle == mine.vehicle_name)
            lo, hi = vb.leg_bins_m[a.index % 3]
            assert lo <= math.dist(a.task.start_m, a.task.goal_m) <= hi and a.index == b.index
    # its quick subset: the twin's first scenarios with their first legs, the same names and tasks
    quick = build_task_set(VALIDATION_QUICK)
    assert quick.info.name == VALIDATION_QUICK and "the first of benchmark-validation's" in quick.info.description
    by_name = {sc.name: sc for sc in twin.scenarios}
    assert len(quick.scenarios) == len(DESIGN.vehicles) * DESIGN.quick_scenarios
    for sc in quick.scenarios:
        whole = by_name[sc.name]
        assert len(sc.episodes) == DESIGN.quick_legs
        assert [e.task for e in sc.episodes] == [e.task for e in whole.episodes[:DESIGN.quick_legs]]
    # the twin's seeds may not land on another vehicle's test cities
    crowded = dataclasses.replace(DESIGN.vehicles[1], first_seed=DESIGN.vehicles[0].first_seed + VALIDATION_SEED_OFFSET)
    with pytest.raises(ValueError, match="small_quad: city seeds 3200000-3200035 overlap the uam_multicopter bench"):
        build_task_set(VALIDATION, dataclasses.replace(DESIGN, vehicles=(DESIGN.vehicles[0], crowded)))


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


def test_sets_resolve_and_validate(quick: TaskSet, capsys: pytest.CaptureFixture[str]) -> None:
    assert {FULL, QUICK, VALIDATION} <= set(builtin_sets())
    resolved = resolve_scenarios(QUICK)
    assert [s.name for s in resolved] == [s.name for s in quick.scenarios] and resolved[0].task_set == quick.info
    assert resolved[0].source == f"{QUICK}:{resolved[0].name}"
    assert main(["validate", QUICK]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(quick.scenarios) and all(": ok (benchmark-" in line for line in lines)
    with pytest.raises(ValueError, match="unknown benchmark set"):
        build_task_set("benchmark-huge")
    leaky = dataclasses.replace(DESIGN.vehicles[0], first_seed=1_049_990)
    with pytest.raises(ValueError, match="small_quad: city seeds 1049990-1050025 overlap the test and validation"):
        build_task_set(QUICK, dataclasses.replace(DESIGN, vehicles=(leaky, DESIGN.vehicles[1])))
    with pytest.raises(ValueError, match="must be a non-empty subset"):
        build_task_set(QUICK, dataclasses.replace(DESIGN, quick_legs=13))


def test_run_json_records_the_task_set(quick: TaskSet, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from compare.cli.printout import print_task_set

    scenarios = list(quick.scenarios)
    opts = RunConfig(out_dir=tmp_path, pilots=("apf",), progress=False)
    cells, notes = plan_cells(scenarios, opts, None)
    write_run_files(scenarios, opts, cells, notes, {})
    info = read_run_info(tmp_path)
    assert info.task_set == quick.info and info.scenarios[0].source == f"{QUICK}:benchmark-quad-000"
    print_task_set(tmp_path)
    assert capsys.readouterr().out == f"task set {QUICK}, version {quick.info.version}: {quick.info.description}\n"
    mixed = [*scenarios[:1], dataclasses.replace(scenarios[1], task_set=None)]
    write_run_files(mixed, RunConfig(out_dir=tmp_path / "mixed"), plan_cells(mixed, opts, None)[0], [], {})
    assert read_run_info(tmp_path / "mixed").task_set is None


def test_the_report_names_the_task_set_on_its_title_page(quick: TaskSet, tmp_path: Path) -> None:
    from pypdf import PdfReader

    from compare.report.report import build_report
    from synthetic_run import write_run

    write_run(tmp_path, None)
    data = json.loads((tmp_path / "run.json").read_text())
    data["suite"] = {"name": QUICK, "version": quick.info.version, "description": quick.info.description}
    (tmp_path / "run.json").write_text(json.dumps(data))
    title = PdfReader(build_report(tmp_path)).pages[0].extract_text()
    assert f"Task set {QUICK}, version {quick.info.version}: Held-out" in " ".join(title.split())


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
    in other air or cities leaves the benchmark, and before-and-after figures, comparable."""
    assert build_task_set("benchmark-quick").info.version == "1+b27f29cc25"  # docs/benchmark.md


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
    assert set(data["small_quad"]["sensing"]) == {"perfect", "nominal"}
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
