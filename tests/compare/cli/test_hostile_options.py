"""Hostile inputs, round four: plug-in pilots and options. A plug-in that cannot fly (no `name`, a wall time that is
not a number, a name too long for its episode files) is refused when it is named, and a `reset` that returns no
`ResetInfo` fails its cell naming it; an option out of its physical range, a scenario rate that cannot be flown, a
`--resume` onto a folder that is not a run, and a set name that is also a local folder are one error line naming
the option, key or folder and the value, before anything flies or is written.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

import compare.cli.run
from cli_checks import fails
from compare.cli import main
from compare.flying import pilots
from compare.results.trajectory import MAX_STEM_BYTES
from compare.scenarios.scenario import MAX_NAME_CHARS, MAX_SEED
from run_data import TINY

LONG_CLASS = "L" * 131  # "hostile_p_plugins:" + this = 149 characters
PLUGINS = f'''
from rl.pilots.potential_field import PotentialFieldPilot
from uam_fdm.pilot import ResetInfo


class NoneReset(PotentialFieldPilot):
    """Returns None from reset."""

    name = "none_reset"

    def reset(self, world, task, seed):
        super().reset(world, task, seed)


class NoName:
    """Has the methods of a pilot but no name."""

    def reset(self, world, task, seed):
        return ResetInfo(True)

    def act(self, obs):
        raise AssertionError("never flown")

    def episode_report(self):
        return None


class Fast(PotentialFieldPilot):
    """States its speed as a word."""

    wall_s_per_flight_s = "fast"


class NoWall(PotentialFieldPilot):
    """States no speed at all."""

    wall_s_per_flight_s = None


class {LONG_CLASS}(PotentialFieldPilot):
    """A class name long enough to make the episode file names too long."""

    label = "Long"
'''
MODULE = "hostile_p_plugins"


@pytest.fixture
def plugins(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> str:
    """The module of hostile plug-ins, importable (outside the test's own folder: importing writes __pycache__)."""
    folder = tmp_path_factory.mktemp("plugins")
    (folder / f"{MODULE}.py").write_text(PLUGINS)
    monkeypatch.syspath_prepend(str(folder))
    return MODULE


def _fly(reference: str, out: Path) -> list[str]:
    """`run` of the tiny scenario by the plug-in `reference` alone."""
    return ["run", str(TINY), "--pilot", reference, "--pilots", reference, "--videos", "none", "--no-progress",
            "--out", str(out)]


# ---- 1: plug-in pilots -------------------------------------------------------------------------------------
def test_a_reset_without_reset_info_fails_its_cell_naming_the_pilot(plugins: str, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert main(_fly(f"{plugins}:NoneReset", out)) == 2  # its only cell failed: nothing to report
    err = capsys.readouterr().err
    assert "Traceback" not in err and "AttributeError" not in err
    [record] = [json.loads(p.read_text()) for p in (out / "failed").glob("*.json")]
    assert record["kind"] == "pilot error"
    assert record["reason"] == (f"pilot '{plugins}:NoneReset': reset returned None, not a ResetInfo "
                                f"(uam_fdm.pilot.ResetInfo)")


@pytest.mark.parametrize(("attr", "expected"), [
    ("NoName", "NoName has no `name`"),
    ("Fast", "wall_s_per_flight_s = 'fast' is not a wall time per simulated second"),
    ("NoWall", "wall_s_per_flight_s = None is not a wall time per simulated second"),
])
def test_a_plugin_that_cannot_fly_is_refused_before_flying(plugins: str, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture, attr: str,
                                                           expected: str) -> None:
    work = tmp_path / "work"
    work.mkdir()
    fails(_fly(f"{plugins}:{attr}", work / "run"), capsys, work, f"--pilot: pilot '{plugins}:{attr}'", expected)


def test_a_plugin_name_too_long_for_its_episode_files_is_refused_before_flying(
        plugins: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    reference = f"{plugins}:{LONG_CLASS}"
    assert len(reference) == 149
    work = tmp_path / "work"
    work.mkdir()
    fails(_fly(reference, work / "run"), capsys, work, "--pilot: pilot", "its name is 149 bytes long; at most 78")


def test_the_plugin_name_limit_leaves_room_for_any_scenario_and_seed() -> None:
    """The longest scenario name, a 3-digit episode and the largest seed beside the longest plug-in name make the
    longest episode stem `EpisodeKey` accepts."""
    assert pilots.MAX_PLUGIN_NAME_BYTES == MAX_STEM_BYTES - MAX_NAME_CHARS - len("__ep000__") - len(f"__s{MAX_SEED}")


# ---- 2: options --------------------------------------------------------------------------------------------
@pytest.fixture
def no_evaluation(monkeypatch: pytest.MonkeyPatch) -> None:
    """An evaluation that gets as far as loading the policy fails the test at once: the options are checked before
    (unchecked, --episodes 50001 would build 50,001 cities, and --wind-max 1e9 fly)."""
    import rl.pilots.learned

    def loaded(*args: object, **kwargs: object) -> None:
        raise AssertionError("evaluate-policy went on to load the policy")

    monkeypatch.setattr(rl.pilots.learned, "load_policy", loaded)


@pytest.mark.parametrize(("argv", "expected"), [
    (["--wind-max", "1e9", "--episodes", "2"], ("--wind-max 1e+09", "[0, 60] m/s")),
    (["--wind-max", "nan", "--episodes", "2"], ("--wind-max nan", "[0, 60] m/s")),
    (["--episodes", str(10**12)], ("--episodes 1000000000000", "between 1 and 50000")),
    (["--episodes", "50001"], ("--episodes 50001", "between 1 and 50000")),  # the test pool's cities end there
    (["--episodes", "50001", "--pool", "validation"], ("--episodes 50001", "between 1 and 50000")),
])
def test_evaluate_policy_refuses_an_option_out_of_range(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                        no_evaluation: None, argv: list[str],
                                                        expected: tuple[str, ...]) -> None:
    fails(["evaluate-policy", *argv, "--no-baseline"], capsys, tmp_path, *expected)


@pytest.mark.parametrize(("option", "value"), [("--sensing", "perfectt"), ("--map-error", "none")])
@pytest.mark.parametrize("command", ["run", "sweep"])
def test_a_bad_sensing_level_is_one_line_naming_the_option(capsys: pytest.CaptureFixture, command: str, option: str,
                                                           value: str) -> None:
    with pytest.raises(SystemExit) as stop:
        main([command, option, value])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err
    [line] = [ln for ln in err.splitlines() if "error:" in ln]
    assert f"argument {option}: invalid choice: '{value}'" in line


# ---- 3: a scenario's rates ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("rates", "key", "value"), [
    ({"control_hz": 0}, "control_hz", "0"),
    ({"control_hz": -50}, "control_hz", "-50"),
    ({"control_hz": 1e-9}, "control_hz", "1e-09"),
    ({"control_hz": 1e-300}, "control_hz", "1e-300"),
    ({"control_hz": 1e-310}, "control_hz", "1e-310"),  # 500 Hz / 1e-310 Hz overflows a float
    ({"control_hz": 5e-324}, "control_hz", "4.94066e-324"),
    ({"physics_hz": 0}, "physics_hz", "0"),
    ({"physics_hz": -50}, "physics_hz", "-50"),
    ({"physics_hz": 1e-9}, "physics_hz", "1e-09"),
    ({"physics_hz": 1e-9, "control_hz": 1e-9}, "physics_hz", "1e-09"),
])
def test_a_rate_that_cannot_be_flown_is_refused_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                          rates: dict[str, float], key: str, value: str) -> None:
    path = tmp_path / "rates.yaml"
    path.write_text(yaml.safe_dump({**yaml.safe_load(TINY.read_text()), **rates}))
    line = fails(["validate", str(path)], capsys, tmp_path, f"{path}: {key}: ", value)
    assert not re.search(r"\d{20}", line), line  # a reason, not a 300-digit count of physics steps


# ---- 4: --resume and set names -----------------------------------------------------------------------------
@pytest.fixture
def no_flying(monkeypatch: pytest.MonkeyPatch) -> None:
    """A run that starts flying fails the test at once (the code before the checks would fly a new run)."""
    def flew(*args: object, **kwargs: object) -> None:
        raise AssertionError("the run flew")

    monkeypatch.setattr(compare.cli.run, "run_comparison", flew)


def test_sweep_resume_onto_a_folder_that_does_not_exist_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                  no_flying: None) -> None:
    typo = tmp_path / "typo"
    fails(["sweep", "--quick", "--resume", "--out", str(typo), "--no-progress"], capsys, tmp_path,
          f"{typo}: cannot resume: not a run folder of uam-compare (no such folder)", "leave out --resume")
    assert not typo.exists()


def test_resume_onto_an_empty_folder_or_without_out_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                               no_flying: None, monkeypatch: pytest.MonkeyPatch
                                                               ) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    fails(["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--resume", "--out", str(empty), "--no-progress"],
          capsys, tmp_path, f"{empty}: cannot resume: not a run folder of uam-compare (no run.json)")
    monkeypatch.chdir(tmp_path)  # the default --out would be runs/<time>-tiny here
    fails(["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--resume", "--no-progress"], capsys, tmp_path,
          "--resume: give --out")


def test_a_set_name_that_is_also_a_local_folder_is_refused_naming_both(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                      monkeypatch: pytest.MonkeyPatch,
                                                                      no_flying: None) -> None:
    (tmp_path / "default").mkdir()
    (tmp_path / "default" / "mine.yaml").write_text(TINY.read_text())
    monkeypatch.chdir(tmp_path)
    for argv in (["validate", "default"], ["run", "default", "--out", str(tmp_path / "run"), "--no-progress"]):
        fails(argv, capsys, tmp_path, "'default' names both a built-in scenario set and the folder ./default here",
              "write ./default for the folder")
    assert main(["validate", "./default"]) == 0  # the local folder, as written
    assert "tiny" in capsys.readouterr().out


def test_the_sweep_of_stale_temporaries_never_follows_a_link(tmp_path):
    """A link planted in a run folder (to a user's folder) never leads the sweep of stale temporaries there, and a
    link named like a temporary is left alone: only the run's own killed writes are removed."""
    from uam_fdm.files.atomic import TEMP_MARK, remove_stale_temporaries

    run, home = tmp_path / "run", tmp_path / "home"
    run.mkdir()
    home.mkdir()
    theirs = home / f".notes.txt{TEMP_MARK}draft.tmp"  # a user's file that happens to look like a temporary
    theirs.write_text("mine")
    (run / "maps").symlink_to(home, target_is_directory=True)
    (run / f".x{TEMP_MARK}link.tmp").symlink_to(theirs)
    ours = run / f".metrics.csv{TEMP_MARK}k3j2.tmp"
    ours.write_text("half")
    assert remove_stale_temporaries(run) == [ours]
    assert theirs.read_text() == "mine" and (run / f".x{TEMP_MARK}link.tmp").is_symlink()


@pytest.mark.parametrize("target", ["loop", "gone"])
def test_an_output_that_is_a_dead_link_is_named_as_one(tmp_path, capsys, target):
    """`--out` at a link to itself (a loop) or to a missing target: one line saying so, exit 2, nothing written
    (before: "File exists")."""
    out = tmp_path / "loop"
    out.symlink_to(out if target == "loop" else tmp_path / "gone")
    assert main(["run", str(TINY), "--pilots", "apf", "--pilot", "apf", "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "link that leads nowhere" in err[0] and str(out) in err[0]
    assert out.is_symlink() and not (tmp_path / "gone").exists()


# ---- 5: the JSON line is strict JSON ------------------------------------------------------------------------
def _strict(text: str) -> object:
    """`json.loads` refusing NaN and Infinity, as strict JSON readers do."""
    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_evaluate_policy_prints_null_for_a_kind_of_city_without_episodes(monkeypatch: pytest.MonkeyPatch,
                                                                         capsys: pytest.CaptureFixture) -> None:
    """Two episodes, both in the first kind of city of a mixed task: the second kind's rates are NaN, and the last
    line says null for them (before: NaN, which strict JSON readers refuse)."""
    import rl.env.world
    import rl.training.evaluation as evaluation

    class World:  # stands in for the task's world: nothing is built or flown here
        atmospheres = (None,)

        def __init__(self, nav: object) -> None:
            pass

    result = evaluation.EvalResult(2, 0.5, 0.0, (0.09, 0.91), (0.0, 0.66), {"success": 1, "timeout": 1}, 1.0, 20.0,
                                   ("success", "timeout"), "test", 0)
    nan = float("nan")
    monkeypatch.setattr(rl.env.world, "NavWorld", World)
    monkeypatch.setattr(evaluation, "evaluate", lambda *args, **kwargs: result)
    monkeypatch.setattr(evaluation, "rates_by_city_component", lambda res, nav: (
        evaluation.GroupRates("dense", 2, 0.5, (0.09, 0.91), 0.0, (0.0, 0.66), {"success": 1, "timeout": 1}),
        evaluation.GroupRates("sparse", 0, nan, (0.0, 1.0), nan, (0.0, 1.0), {})))
    assert main(["evaluate-policy", "--episodes", "2", "--no-baseline"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    data = _strict(last)
    assert isinstance(data, dict)
    sparse = data["by_city_kind"]["ppo"][1]
    assert sparse["episodes"] == 0 and sparse["success_rate"] is None and sparse["collision_rate"] is None
    assert data["success_rate"] == 0.5


def test_a_printed_json_line_holds_no_number_json_lacks() -> None:
    from compare.cli.printout import json_line

    line = json_line({"a": float("inf"), "b": [1.0, float("-inf"), (float("nan"), 2)], "c": {"d": float("nan")}})
    assert _strict(line) == {"a": None, "b": [1.0, None, [None, 2]], "c": {"d": None}}
