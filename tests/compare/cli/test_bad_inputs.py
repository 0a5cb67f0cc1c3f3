"""Catalogue of bad inputs: each is one clear error that writes nothing (an unreadable episode file is skipped
with a warning instead).

Every case goes through `compare.cli.main` (or the library where the command line has no path to
it) and checks the exit code, that the one error line names the file, key or option and the bad
value, that no traceback escaped, and that nothing under the test's folder was written or changed.
Inputs that used to hang are kept small here (a smaller alias bomb, a 600-vertex star); no test times
them: how quickly each is refused is measured by perf/responsiveness.py.
"""
from __future__ import annotations

import errno
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pypdf import PdfReader

import compare.cli.entry
import compare.cli.run
import compare.run.campaign
import compare.run.cells
import compare.scenarios.fingerprint
import uam_fdm.city.plot
import uam_fdm.vehicle.dynamics
from cli_checks import fails, snapshot
from compare.cli import main
from compare.results.episodes import open_episodes
from compare.scenarios.scenario import MAX_NAME_CHARS, MAX_SEED
from run_data import TINY
from scenario_box import BASE  # a 100 x 100 x 50 m box with one building in the middle
from slow_inputs import alias_bomb, geojson_scenario, star
from synthetic_run import write_run
from uam_fdm.city.geojson import MAX_FOOTPRINT_VERTICES, footprint_parts
from uam_fdm.errors import MAX_REASON_CHARS, ConfigError
from uam_fdm.files import atomic
from uam_fdm.files.yamlfile import MAX_YAML_VALUES
from uam_fdm.vehicle.params import PRESET_DIR, load_vehicle

QUAD_YAML = (PRESET_DIR / "small_quad.yaml").read_text()

# ---- helpers ---------------------------------------------------------------------------------------------



def _must_not_run(what: str):
    """A stand-in that fails the test if called: the input must be refused before `what`."""
    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"{what} before the input was refused")
    return refuse


def _scenario(tmp_path: Path, data: dict[str, Any], name: str = "scen.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _vehicle_file(tmp_path: Path, text: str, name: str = "vehicle.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path
def _area(v: np.ndarray) -> float:
    w = np.roll(v, -1, axis=0)
    return 0.5 * abs(float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1])))

@pytest.fixture
def no_flying(monkeypatch: pytest.MonkeyPatch) -> None:
    """`run` must stop before flying: fail loudly (and fast) if it ever gets to the runner."""
    def refuse(*_args: Any, **_kwargs: Any) -> Path:
        raise AssertionError("run_comparison was called: the bad input was not rejected")
    monkeypatch.setattr(compare.cli.run, "run_comparison", refuse)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bad_inputs") / "run"
    write_run(out, None)
    return out


# ---- limits that keep the tool responsive ------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["scenario", "vehicle"])
def test_yaml_alias_bomb_is_rejected_quickly(tmp_path: Path, capsys: pytest.CaptureFixture, kind: str) -> None:
    # 9**7 = 4.8 M strings from ~500 bytes (a reported 573-byte bomb has 9**9 and hung the loader
    # while printing the value in an error message; this smaller one keeps a regression bounded)
    if kind == "scenario":
        path = tmp_path / "bomb.yaml"
        path.write_text(yaml.safe_dump(BASE, sort_keys=False) + "description:\n" + alias_bomb(7))
        argv = ["validate", str(path)]
    else:
        path = _vehicle_file(tmp_path, QUAD_YAML + "\nextra:\n" + alias_bomb(7))
        argv = ["demo", str(path)]
    assert len(alias_bomb(7).encode()) < 600
    line = fails(argv, capsys, tmp_path, str(path), "<yaml>", f"more than {MAX_YAML_VALUES:,} values", "alias")
    assert len(line) < 300


def test_recursive_alias_and_deep_nesting_are_rejected(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "loop.yaml"
    path.write_text(yaml.safe_dump(BASE, sort_keys=False) + "description: &d [*d]\n")
    fails(["validate", str(path)], capsys, tmp_path, str(path), "<yaml>", "refers to itself")
    path.write_text(yaml.safe_dump(BASE, sort_keys=False) + "description: " + "[" * 300 + "]" * 300 + "\n")
    fails(["validate", str(path)], capsys, tmp_path, str(path), "<yaml>", "levels deep; at most 64")
    # far deeper: refused by the parser itself (libyaml's own depth limit) or by ours, whichever speaks first;
    # either way one line naming the file, exit 2
    path.write_text(yaml.safe_dump(BASE, sort_keys=False) + "description: " + "[" * 3000 + "]" * 3000 + "\n")
    fails(["validate", str(path)], capsys, tmp_path, str(path), "<yaml>")


def test_error_message_truncates_a_huge_value(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = _scenario(tmp_path, {**BASE, "description": list(range(20_000))})  # not a string
    line = fails(["validate", str(path)], capsys, tmp_path, str(path), "description: must be a string, got [0, 1,",
                  "more characters)")
    assert len(line) < MAX_REASON_CHARS + 200


@pytest.mark.parametrize("generator, key, reason", [
    # 6 km (a reported 100 km hung; 6 km is bounded for a regression), limit 5 km
    ({"extent_m": [6000, 6000]}, "map.generator.extent_m", "at most 5000 m per axis"),
    ({"lots_per_block": [11, 2]}, "map.generator.lots_per_block", "at most 10 per axis"),
    ({"extent_m": [5000, 5000], "block_size_m": [60, 60], "street_width_m": 10},
     "map.generator.extent_m", "lots; at most 20,000"),
    ({"extent_m": [200, 200], "block_size_m": [4, 4], "lots_per_block": [8, 8]}, "map.generator.block_size_m",
     "at least 1 m"),
])
def test_generator_parameters_are_bounded(tmp_path: Path, capsys: pytest.CaptureFixture, generator: dict,
                                          key: str, reason: str) -> None:
    data = {k: v for k, v in BASE.items() if k != "bounds"}  # a generated city brings its own
    path = _scenario(tmp_path, {**data, "map": {"generator": {"seed": 1, **generator}}})
    fails(["validate", str(path)], capsys, tmp_path, str(path), key, reason)


def test_a_geojson_star_validates_and_its_pieces_tile_it(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ring = star(600)  # took ~10 s before (a star of 800: 21 s); its time now: perf/responsiveness.py
    path = geojson_scenario(tmp_path, ring)
    assert main(["validate", str(path)]) == 0
    assert "ok" in capsys.readouterr().out
    # and the pieces of a larger one tile it exactly
    big = star(4000)
    parts = footprint_parts(big, 20.0, 0)
    assert math.isclose(sum(_area(p.footprint_xy_m()) for p in parts), _area(big), rel_tol=1e-9)


def test_geojson_vertex_limit_is_stated(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    n = MAX_FOOTPRINT_VERTICES + 1
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring = np.column_stack([150 + 60 * np.cos(ang), 150 + 60 * np.sin(ang)])
    ring[[1, 2]] = ring[[2, 1]]  # edges 0 and 2 cross: the old code stopped there, quickly, with another error
    path = geojson_scenario(tmp_path, ring)
    fails(["validate", str(path)], capsys, tmp_path, str(tmp_path / "fp.geojson"),
           "features[0].geometry.coordinates[0]", f"{n + 1:,} positions",
           f"at most {MAX_FOOTPRINT_VERTICES:,} vertices")


@pytest.mark.parametrize("rates, key, reason", [
    ({"physics_hz": 500, "control_hz": 1}, "control_hz", "500 physics steps per control period"),
    ({"physics_hz": 100, "control_hz": 50}, "physics_hz", "motor_time_constant_s 0.0125 s spans 1.25 physics steps"),
])
def test_rates_are_bounded_against_the_physics_rate(tmp_path: Path, capsys: pytest.CaptureFixture, rates: dict,
                                                    key: str, reason: str) -> None:
    path = _scenario(tmp_path, {**BASE, **rates})
    fails(["validate", str(path)], capsys, tmp_path, str(path), f": {key}: ", reason)


def test_a_control_rate_the_policy_was_not_trained_for_is_refused_before_writing(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Item 3: the shipped policy holds each decision for five 50 Hz periods; at 100 Hz it would decide at
    20 Hz, a rate it never saw. Refused before the run folder exists, naming the file, key and both rates."""
    path = _scenario(tmp_path, {**BASE, "physics_hz": 500, "control_hz": 100})
    fails(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"], capsys, tmp_path,
           str(path), "control_hz 100", "50 Hz controller", "--pilots rrt_mpc")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("shear, key, reason", [
    ({"law": "cubic"}, "atmosphere.wind_shear.law", "unknown shear law 'cubic'"),
    ({"law": "log", "roughness_m": 50}, "atmosphere.wind_shear.roughness_m", "roughness_m=50.0 is outside"),
])
def test_a_bad_wind_shear_is_refused_before_writing(tmp_path: Path, capsys: pytest.CaptureFixture, shear: dict,
                                                   key: str, reason: str) -> None:
    path = _scenario(tmp_path, {**BASE, "atmosphere": {"wind_mps": [3, 0, 0], "wind_shear": shear}})
    fails(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"], capsys, tmp_path,
           str(path), f": {key}: ", reason)
    assert not (tmp_path / "out").exists()


def test_motor_time_constant_too_short_for_the_demo(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    path = _vehicle_file(tmp_path, QUAD_YAML.replace("motor_time_constant_s: 0.0125", "motor_time_constant_s: 0.0005"))
    # refused before the model is built and compiled
    monkeypatch.setattr(uam_fdm.vehicle.dynamics, "build_model_functions", _must_not_run("the model was built"))
    fails(["demo", str(path)], capsys, tmp_path, str(path), "motor_time_constant_s: motor_time_constant_s 0.0005 s",
           "at least 2")


@pytest.mark.parametrize("speed", ["0.01", "1.0e+9"])
def test_max_speed_is_bounded(tmp_path: Path, capsys: pytest.CaptureFixture, speed: str) -> None:
    vehicle = _vehicle_file(tmp_path, QUAD_YAML.replace("max_speed_m_s: 12.0", f"max_speed_m_s: {speed}"))
    path = _scenario(tmp_path, {**BASE, "vehicle": "vehicle.yaml"})
    fails(["validate", str(path)], capsys, tmp_path, str(vehicle), "controller.max_speed_m_s",
           "must be in [0.5, 100] m/s", f"got {float(speed):g}")


def test_default_timeout_is_bounded(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    _vehicle_file(tmp_path, QUAD_YAML.replace("max_speed_m_s: 12.0", "max_speed_m_s: 1.0"))
    path = _scenario(tmp_path, {**BASE, "vehicle": "vehicle.yaml", "map": {"buildings": []},
                                "bounds": {"min": [0, 0, 0], "max": [3000, 100, 50]},
                                "episodes": [{"start": [10.0, 50.0, 10.0], "goal": [2500.0, 50.0, 10.0]}]})
    fails(["validate", str(path)], capsys, tmp_path, str(path), "episodes[0]", "= 6245 s, exceeds 3600 s",
           "set timeout_s")


def test_duplicate_key_in_a_vehicle_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    vehicle = _vehicle_file(tmp_path, QUAD_YAML + "\nmass_kg: 1.6\n")
    path = _scenario(tmp_path, {**BASE, "vehicle": "vehicle.yaml"})
    fails(["validate", str(path)], capsys, tmp_path, str(vehicle), "<yaml>", "duplicate key 'mass_kg'")
    with pytest.raises(ConfigError, match="duplicate key 'mass_kg'"):
        load_vehicle(vehicle)


def test_large_run_warns_with_time_and_disk(tmp_path: Path, capsys: pytest.CaptureFixture,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    def stop(*_args: Any, **_kwargs: Any) -> Path:
        raise ValueError("stopped before flying (test)")
    monkeypatch.setattr(compare.cli.run, "run_comparison", stop)
    out = tmp_path / "run"
    seeds = ",".join(str(s) for s in range(400))
    assert main(["run", str(TINY), "--seeds", seeds, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    warning = [ln for ln in err.splitlines() if ln.startswith("uam-compare: warning:")]
    assert len(warning) == 1 and "800 episodes" in warning[0] and " h with --jobs 1" in warning[0]
    assert " GB of episode files" in warning[0] and str(out) in warning[0]
    assert not out.exists()
    # a small run says nothing
    assert main(["run", str(TINY), "--out", str(out), "--no-progress"]) == 2
    assert "warning" not in capsys.readouterr().err


# ---- every remaining traceback is a clear error --------------------------------------------------------------
def test_run_out_is_a_file(tmp_path: Path, capsys: pytest.CaptureFixture, no_flying: None) -> None:
    out = tmp_path / "afile"
    out.write_text("keep me")
    fails(["run", str(TINY), "--out", str(out), "--no-progress"], capsys, tmp_path, f"--out {out}", "is a file")


def test_run_out_under_a_file(tmp_path: Path, capsys: pytest.CaptureFixture, no_flying: None) -> None:
    (tmp_path / "afile").write_text("keep me")
    out = tmp_path / "afile" / "run"
    fails(["run", str(TINY), "--out", str(out), "--no-progress"], capsys, tmp_path, f"--out {out}",
           f"{tmp_path / 'afile'} is a file")


def test_run_out_not_writable(tmp_path: Path, capsys: pytest.CaptureFixture, no_flying: None) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        parent = locked
        if os.access(locked, os.W_OK):  # root writes anywhere; /proc/1 it may not write in
            parent = Path("/proc/1")
            if os.access(parent, os.W_OK):
                pytest.skip("no folder here that this user cannot write in")
        out = parent / "run"
        fails(["run", str(TINY), "--out", str(out), "--no-progress"], capsys, tmp_path, f"--out {out}",
               f"cannot write in {parent}")
        assert not out.exists()
    finally:
        locked.chmod(0o700)


def test_disk_full_is_a_clear_error_and_leaves_no_partial_file(run_dir: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    real_open = open

    class FullDisk:
        """A file that takes the first 1000 bytes, then reports a full disk (as `write` does)."""

        def __init__(self, f: Any) -> None:
            self.f = f

        def write(self, data: Any) -> int:
            self.f.write(data[:1000])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __enter__(self) -> FullDisk:
            return self

        def __exit__(self, *exc: Any) -> None:
            self.f.close()

    monkeypatch.setattr(atomic, "open", lambda *a, **k: FullDisk(real_open(*a, **k)), raising=False)
    out = tmp_path / "viewer.html"
    run_before = snapshot(run_dir)
    fails(["view", str(run_dir), "--out", str(out)], capsys, tmp_path, str(out), "No space left on device",
           "disk is full")
    assert list(tmp_path.iterdir()) == [] and snapshot(run_dir) == run_before


def test_scenario_name_too_long_for_file_names(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = _scenario(tmp_path, {**BASE, "name": "n" * 300})
    fails(["validate", str(path)], capsys, tmp_path, str(path), ": name: 300 characters long",
           f"at most {MAX_NAME_CHARS}")


def test_demo_on_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = tmp_path / "vehicles"
    folder.mkdir()
    fails(["demo", str(folder)], capsys, tmp_path, str(folder), "is a folder")


def test_random_bytes_as_vehicle_yaml(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "noise.yaml"
    path.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 400, dtype=np.uint8)))
    fails(["demo", str(path)], capsys, tmp_path, str(path), "not a text file")
    scenario = _scenario(tmp_path, {**BASE, "vehicle": "noise.yaml"})
    fails(["validate", str(scenario)], capsys, tmp_path, str(scenario), "vehicle", str(path), "not a text file")


def test_random_bytes_as_geojson(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "noise.geojson").write_bytes(bytes(np.random.default_rng(1).integers(0, 256, 400, dtype=np.uint8)))
    path = _scenario(tmp_path, {**BASE, "map": {"geojson": "noise.geojson"}})
    fails(["validate", str(path)], capsys, tmp_path, str(tmp_path / "noise.geojson"), "not a text file")


@pytest.mark.parametrize("seeds, expected", [
    ("-1", "--seeds -1 (index 0): must be an integer in [0, 4294967295], got -1"),
    (str(MAX_SEED + 1), f"got {MAX_SEED + 1}"),
    ("3,4,3", "--seeds 3,4,3 (index 2): duplicate seed 3"),
])
def test_seeds_have_the_scenario_limits(tmp_path: Path, capsys: pytest.CaptureFixture, no_flying: None,
                                        seeds: str, expected: str) -> None:
    out = tmp_path / "run"
    fails(["run", str(TINY), "--seeds", seeds, "--out", str(out), "--no-progress"], capsys, tmp_path, expected)


def test_seeds_that_are_not_integers(tmp_path: Path, capsys: pytest.CaptureFixture, no_flying: None) -> None:
    with pytest.raises(SystemExit) as exc:  # argparse: usage and one error line, exit 2
        main(["run", str(TINY), "--seeds", "1,x", "--out", str(tmp_path / "run")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --seeds: expected comma-separated integers" in err and "'1,x'" in err
    assert list(tmp_path.iterdir()) == []


def test_jobs_below_one_rejected_and_above_cpus_warned(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                      no_flying: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(compare.cli.entry.LOG_DIR_ENV, str(tmp_path.parent / f"{tmp_path.name}-logs"))
    out = tmp_path / "run"
    fails(["run", str(TINY), "--jobs", "0", "--out", str(out)], capsys, tmp_path, "--jobs 0: must be >= 1")
    many = (os.cpu_count() or 1) + 1
    # a warning, not an error: the run goes on to fly (the fixture's refusal ends in the last-resort handler)
    assert main(["run", str(TINY), "--jobs", str(many), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "run_comparison was called" in err
    assert f"uam-compare: warning: --jobs {many} is more than the {os.cpu_count()} CPUs" in err


@pytest.mark.parametrize("options, expected", [
    ({"seeds": (3, 4, 3)}, "--seeds 3,4,3 (index 2): duplicate seed 3"),
    ({"jobs": 0}, "--jobs 0: must be >= 1"),
    ({"cell_timeout_s": 0.0}, "--cell-timeout 0: must be > 0 s"),
    ({"address": "10.0.0.5:6379"}, "--address 10.0.0.5:6379: a Ray cluster's address, only with --backend ray"),
    ({"videos": "some"}, "--videos 'some': choose from scenario, all, none"),
])
def test_a_library_run_checks_its_options_as_the_command_line_does(tmp_path: Path, options: dict,
                                                                   expected: str) -> None:
    """One check per option (`RunConfig.validate`): a library caller gets the CLI's message, before anything
    is read or written."""
    opts = compare.run.campaign.RunConfig(out_dir=tmp_path / "run", **options)
    with pytest.raises(ValueError) as exc:
        compare.run.campaign.run_comparison([], opts)
    assert str(exc.value).startswith(expected) and list(tmp_path.iterdir()) == []


def test_animate_duration_is_bounded(run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    before = snapshot(run_dir)
    fails(["animate", str(run_dir), "--duration", "1e9", "--out", str(tmp_path / "clip.gif")], capsys, tmp_path,
           "--duration 1e+09: must be at most 600 seconds")
    assert snapshot(run_dir) == before


def test_view_out_is_a_folder(run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = tmp_path / "site"
    folder.mkdir()
    (folder / "index.html").write_text("keep me")
    before = snapshot(run_dir)
    fails(["view", str(run_dir), "--out", str(folder)], capsys, tmp_path, f"--out {folder}", "is a folder")
    assert snapshot(run_dir) == before


@pytest.mark.parametrize("episodes", ["0", "-5"])
def test_evaluate_policy_episodes_must_be_positive(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                   episodes: str) -> None:
    # already a clear error before this catalogue; kept in it so that it stays one
    fails(["evaluate-policy", "--episodes", episodes], capsys, tmp_path, f"--episodes {episodes}: must be >= 1")


def test_maps_on_a_file(tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "maps.png"
    target.write_text("keep me")
    monkeypatch.setattr(uam_fdm.city.plot, "render_named_maps", _must_not_run("the maps were rendered"))
    fails(["maps", str(target)], capsys, tmp_path, f"OUT_DIR {target}", "is a file")


# ---- resume never mixes or destroys --------------------------------------------------------------------------


def _tiny_run(tmp_path: Path) -> tuple[Path, list[str]]:
    """A run of a copy of the tiny scenario (rrt_mpc, synthetic flights): the scenario file and the argv."""
    scen = tmp_path / "tiny.yaml"
    scen.write_text(TINY.read_text())
    argv = ["run", str(scen), "--pilots", "rrt_mpc", "--out", str(tmp_path / "run"), "--no-progress",
            "--videos", "none"]
    assert main(argv) == 0
    return scen, argv


@pytest.mark.parametrize(("old", "new", "part"), [
    ("height: 30.0", "height: 31.0", "map (buildings, bounds, no-fly zones)"),  # one building 1 m taller
    ("goal: [110.0, 45.0, 12.0]", "goal: [110.0, 45.0, 13.0]", "episodes (start, goal, radius, timeout)"),
    ("turbulence: light", "turbulence: moderate", "atmosphere, wind or rates"),
    ("turbulence: light", "turbulence: light, wind_shear: {law: power, exponent: 0.3}", "atmosphere, wind or rates"),
    ("vehicle: small_quad", "vehicle: VEHICLE", "vehicle parameters"),  # a copy of the preset, 0.1 kg heavier
])
def test_resume_refuses_a_changed_scenario(tmp_path: Path, capsys: pytest.CaptureFixture, synthetic_flying: None,
                                           old: str, new: str, part: str) -> None:
    scen, argv = _tiny_run(tmp_path)
    out = tmp_path / "run"
    saved = json.loads((out / "run.json").read_text())["fingerprints"]
    assert set(saved["scenarios"]["tiny"]) == {"map", "vehicle", "conditions", "episodes"} and "policies" not in saved
    assert main([*argv, "--resume"]) == 0  # the same inputs: resumes (nothing left to fly)
    capsys.readouterr()
    vehicle = _vehicle_file(tmp_path, QUAD_YAML.replace("mass_kg: 1.5", "mass_kg: 1.6"))
    scen.write_text(TINY.read_text().replace(old, new.replace("VEHICLE", str(vehicle))))
    fails([*argv, "--resume"], capsys, tmp_path, f"{out}: cannot resume: the inputs differ",
           f"scenario tiny: {part} changed", "nothing was written")


@pytest.mark.parametrize(("pilots", "seeds", "why"), [
    ("rrt_mpc", "0,1", "scenario tiny: seeds saved [0], now [0, 1] (--seeds)"),
    ("ppo,rrt_mpc", None, "scenario tiny: pilots saved rrt_mpc, now ppo, rrt_mpc (--pilots, --pilot)"),
])
def test_resume_refuses_other_seeds_or_pilots(tmp_path: Path, capsys: pytest.CaptureFixture, synthetic_flying: None,
                                              pilots: str, seeds: str | None, why: str) -> None:
    """run.json describes one command's cells: a resume that would mix in another's is refused, folder untouched."""
    _, argv = _tiny_run(tmp_path)
    argv = [pilots if a == "rrt_mpc" else a for a in argv] + (["--seeds", seeds] if seeds else [])
    fails([*argv, "--resume"], capsys, tmp_path, f"{tmp_path / 'run'}: cannot resume: the inputs differ", why,
           "nothing was written")


def test_resume_lists_every_difference(tmp_path: Path, capsys: pytest.CaptureFixture, synthetic_flying: None,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    scen, argv = _tiny_run(tmp_path)
    text = TINY.read_text().replace("height: 30.0", "height: 31.0")
    scen.write_text(text.replace("wind_mps: [1.0,", "wind_mps: [2.0,"))
    monkeypatch.setattr(compare.scenarios.fingerprint, "code_version",
                        lambda: {"uam-compare": "9.9", "commit": "f" * 40})
    fails([*argv, "--resume"], capsys, tmp_path,
           "scenario tiny: atmosphere, wind or rates, map (buildings, bounds, no-fly zones) changed",
           "code version: saved uam-compare", "now uam-compare 9.9 commit ffffffffffff")


def test_resume_keeps_the_policy_fingerprint_of_a_run_that_flew_ppo(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                    synthetic_flying: None) -> None:
    _, argv = _tiny_run(tmp_path)
    run_json = tmp_path / "run" / "run.json"
    info = json.loads(run_json.read_text())
    policies = {"small_quad": {"folder": "/somewhere/policy", "files": {"model.zip": "0" * 64}}}
    run_json.write_text(json.dumps({**info, "fingerprints": {**info["fingerprints"], "policies": policies}}))
    assert main([*argv, "--resume"]) == 0  # rrt_mpc only: the saved ppo episodes' policy stays on record
    assert json.loads(run_json.read_text())["fingerprints"]["policies"] == policies


def test_resume_refuses_a_foreign_folder_and_leaves_it_untouched(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                 synthetic_flying: None) -> None:
    out = tmp_path / "my-results"
    out.mkdir()
    (out / "metrics.csv").write_text("trial,score\n1,0.93\n2,0.88\n")  # the user's own file, same name as ours
    fails(["run", str(TINY), "--pilots", "rrt_mpc", "--out", str(out), "--resume", "--no-progress"], capsys,
           tmp_path, f"{out}: cannot resume: not a run folder of uam-compare (no run.json)", "nothing was written")
    assert (out / "metrics.csv").read_text() == "trial,score\n1,0.93\n2,0.88\n"


def test_resume_refuses_a_run_saved_before_fingerprints(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                        synthetic_flying: None) -> None:
    out = tmp_path / "old-run"
    write_run(out, None)  # a run.json as written before fingerprints were saved
    fails(["run", str(TINY), "--pilots", "rrt_mpc", "--out", str(out), "--resume", "--no-progress"], capsys,
           tmp_path, f"{out}: cannot resume: the run predates input fingerprints", "nothing was written")


# ---- one bad file does not block a report ------------------------------------------------------------------
@pytest.mark.parametrize("damage", ["truncated", "corrupt", "empty"])
def test_report_and_view_skip_an_unreadable_episode(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                    caplog: pytest.LogCaptureFixture, damage: str) -> None:
    run = tmp_path / "run"
    write_run(run, None)
    bad = run / "episodes" / "toy-quad__ep001__ppo__s0.npz"
    data = bad.read_bytes()
    data = {"truncated": data[:len(data) // 2], "corrupt": data[:200] + bytes(1000) + data[1200:],
            "empty": b""}[damage]
    bad.write_bytes(data)
    with caplog.at_level("WARNING"):
        assert main(["report", str(run)]) == 0
    assert "Traceback" not in capsys.readouterr().err
    warned = [r for r in caplog.records if r.levelname == "WARNING" and str(bad) in r.getMessage()]
    assert len(warned) == 1, caplog.text  # named once, not once per output
    rows = (run / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 and not any(",1,ppo," in r for r in rows)  # scored from the other three
    failures = [p.extract_text() for p in PdfReader(str(run / "report.pdf")).pages]
    failures = " ".join(t for t in failures if t.lstrip().startswith("Failures"))
    assert "Unreadable episode files skipped" in failures and bad.name in failures.replace("\n", "")
    assert (run / "viewer.html").is_file() and bad.read_bytes() == data  # the bad file is kept as it was
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main(["view", str(run), "--out", str(tmp_path / "v.html")]) == 0
    assert (tmp_path / "v.html").is_file() and str(bad) in caplog.text


def test_resume_flies_an_unreadable_episode_again(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                  caplog: pytest.LogCaptureFixture, synthetic_flying: None,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A truncated part is not a finished cell: `--resume` flies it again and replaces the file."""
    def interrupted(run_dir: Path, report: bool) -> Path:  # every cell flown, killed before the compaction
        raise KeyboardInterrupt

    finalize = compare.run.campaign._finalize
    monkeypatch.setattr(compare.run.campaign, "_finalize", interrupted)
    scen = tmp_path / "tiny.yaml"
    scen.write_text(TINY.read_text())
    argv = ["run", str(scen), "--pilots", "rrt_mpc", "--out", str(tmp_path / "run"), "--no-progress",
            "--videos", "none"]
    assert main(argv) == 130
    monkeypatch.setattr(compare.run.campaign, "_finalize", finalize)
    bad = tmp_path / "run" / "store" / "parts" / "tiny__ep000__rrt_mpc__s0.parquet"
    good = bad.read_bytes()
    bad.write_bytes(good[:len(good) // 2])
    with caplog.at_level("WARNING"):
        assert main([*argv, "--resume"]) == 0
    assert "Traceback" not in capsys.readouterr().err
    assert any(r.getMessage().startswith("flying again: ") and str(bad) in r.getMessage() for r in caplog.records)
    episodes = open_episodes(tmp_path / "run")  # flown again, then compacted: an episode that reads
    assert [e.key.stem for e in episodes.entries] == ["tiny__ep000__rrt_mpc__s0"] and not episodes.unreadable
    assert episodes.load(episodes.entries[0]).meta.outcome == "success" and not bad.exists()
