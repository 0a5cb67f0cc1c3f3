"""The command line's options: the old spellings of the pilot options still work, hidden and with a warning that
names the new one; every default comes from its typed config, and the help shows the config's."""
from __future__ import annotations

import re
import types
import warnings
from dataclasses import replace
from pathlib import Path

import pytest

from compare.cli import build_parser, main
from compare.run.campaign import RunConfig
from run_data import TINY

COMMANDS = ("demo", "maps", "run", "sweep", "report", "animate", "view", "view-training", "export", "validate",
            "list", "train", "evaluate-policy")


def _help(command: str, capsys: pytest.CaptureFixture) -> str:
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"])
    assert stop.value.code == 0
    return capsys.readouterr().out


def test_the_old_pilot_options_are_hidden_aliases_that_warn(capsys: pytest.CaptureFixture) -> None:
    args = build_parser().parse_args(["run", "--methods", "apf,ppo", "--method", "rrt_mpc", "--pilot", "apf"])
    assert args.pilots == ("apf", "ppo") and args.pilot == ["rrt_mpc", "apf"]
    assert capsys.readouterr().err.splitlines() == ["uam-compare: warning: --methods is deprecated; use --pilots",
                                                    "uam-compare: warning: --method is deprecated; use --pilot"]
    new = build_parser().parse_args(["sweep", "--pilots", "apf,ppo", "--pilot", "rrt_mpc"])
    assert (new.pilots, new.pilot) == (("apf", "ppo"), ["rrt_mpc"]) and capsys.readouterr().err == ""
    for command in ("run", "sweep"):
        text = _help(command, capsys)
        assert "--pilots" in text and "--pilot PILOT" in text and "--method" not in text


def test_an_old_option_is_checked_and_named_as_the_new_one(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert main(["run", str(TINY), "--method", "nowhere_module:Pilot", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "uam-compare: warning: --method is deprecated; use --pilot"
    assert err[1].startswith("uam-compare: error: --pilot: ") and not out.exists()
    with pytest.raises(SystemExit) as stop:  # a bad value is refused by argparse, naming the option as typed
        main(["run", str(TINY), "--methods", ","])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "--methods" in err and "expected a comma-separated list" in err


def test_an_old_key_in_a_scenario_file_is_one_warning_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Python hides DeprecationWarnings; ours reach the command's user as one line each, every time `main` runs,
    and the warnings state is the caller's again afterwards."""
    old = tmp_path / "old.yaml"
    old.write_text(TINY.read_text().replace("\nseeds: [0]\n", "\nseeds: [0]\nmethods: [rrt_mpc, ppo]\n"))
    before = (list(warnings.filters), warnings.showwarning)
    for _ in range(2):
        assert main(["validate", str(old)]) == 0
        out, err = capsys.readouterr()
        assert "pilots ppo, rrt_mpc" in out
        [line] = err.splitlines()
        assert line.startswith(f"uam-compare: warning: {old}: the key 'methods' is renamed 'pilots'")
    assert (list(warnings.filters), warnings.showwarning) == before


# A plug-in that imports an old name of ours (its warning names the plug-in's line) and deprecates something of
# its own: ours is shown, theirs is left to Python's filters (hidden by default).
OLD_NAME_PLUGIN = '''
import warnings

from rl.pilots.potential_field import PotentialFieldPilot
from uam_fdm.pilot import Agent

warnings.warn("their own deprecation", DeprecationWarning)


class Field(PotentialFieldPilot):
    """The potential field, in a plug-in that still uses an old name."""
'''


def test_an_old_name_a_plugin_imports_is_one_warning_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "old_name_plugin_i32.py").write_text(OLD_NAME_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    scenario = tmp_path / "plugin.yaml"
    pilots = "\nseeds: [0]\npilots: [old_name_plugin_i32:Field]\n"
    scenario.write_text(TINY.read_text().replace("\nseeds: [0]\n", pilots))
    assert main(["validate", str(scenario)]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "uam-compare: warning: uam_fdm.pilot.Agent is renamed uam_fdm.pilot.Pilot; the old name will be removed in "
        "the next release"]


def test_run_defaults_are_the_run_configs() -> None:
    args = build_parser().parse_args(["run"])
    fields = {"pilots": "pilots", "seeds": "seeds", "jobs": "jobs", "cell_timeout": "cell_timeout_s",
              "backend": "backend", "address": "address", "store": "store"}
    assert {option: getattr(args, option) for option in fields} == {o: getattr(RunConfig, f) for o, f in fields.items()}


def test_every_help_is_filled_in(capsys: pytest.CaptureFixture) -> None:
    """No `{name}` of a config default is left in any command's help (the defaults are read when it is printed)."""
    for command in COMMANDS:
        text = _help(command, capsys)
        assert re.search(r"\{\w+\}", text) is None, command  # (a choice list is {a,b})


def test_train_defaults_are_the_train_configs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture) -> None:
    import rl.training.loop
    from rl.training.config import TrainConfig

    seen: list[TrainConfig] = []

    def train(cfg: TrainConfig, out: Path, **_kwargs: object) -> types.SimpleNamespace:
        seen.append(cfg)
        return types.SimpleNamespace(success_rate=0.0, collision_rate=0.0, episodes=0)

    monkeypatch.setattr(rl.training.loop, "train", train)
    assert main(["train", "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    assert main(["train", "--out", str(tmp_path / "b"), "--no-progress", "--envs", "8", "--no-curriculum"]) == 0
    defaults = TrainConfig()
    assert seen == [defaults, replace(defaults, n_envs=8, curriculum=replace(defaults.curriculum, start=1.0))]
    text = " ".join(_help("train", capsys).split())
    assert f"(default {defaults.n_envs})" in text and f"(default {defaults.seed})" in text
    assert f"{defaults.nav.vehicle} (default)" in text and f"(default {defaults.preset};" in text


def test_an_unknown_preset_is_named_as_the_option(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["train", "--out", str(tmp_path / "p"), "--preset", "huge"]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("uam-compare: error: --preset huge: ") and "paper" in line
    assert not (tmp_path / "p").exists()
