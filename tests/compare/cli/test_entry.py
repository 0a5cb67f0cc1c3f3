"""The entry point: `--help` and `--version` import no command module (so none of PyTorch, CasADi, matplotlib, OMPL,
...), a command imports only its own module, and the table of commands `--help` lists says what the modules do."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

from compare.cli import main
from compare.cli.entry import COMMANDS, build_parser, command_of, version_text
from run_data import TINY

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("torch", "casadi", "matplotlib", "ompl", "stable_baselines3", "plotly", "ray", "pyarrow", "jsbsim", "rl",
         "planners")
"""Packages a command line that only prints must not wait for (any of their modules counts)."""


def _imported_after(argv: list[str]) -> tuple[int, set[str], str]:
    """Run `main(argv)` in a fresh interpreter: its exit code, the modules it imported, and its stdout."""
    code = (f"import json, sys\nfrom compare.cli import main\ntry:\n    rc = main({argv!r})\n"
            f"except SystemExit as stop:\n    rc = stop.code\nprint(json.dumps([rc, sorted(sys.modules)]))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    *printed, last = done.stdout.strip().splitlines()
    rc, modules = json.loads(last)
    return rc, set(modules), "\n".join(printed)


def _heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in HEAVY)


@pytest.mark.parametrize("argv", [["--help"], ["--version"], [], ["no-such-command"]])
def test_help_and_version_import_no_command_module(argv: list[str]) -> None:
    rc, modules, out = _imported_after(argv)
    assert rc == (2 if argv == ["no-such-command"] else 0)
    assert _heavy(modules) == []
    assert not any(m.startswith("compare.cli.") and m not in ("compare.cli.entry", "compare.cli.common")
                   for m in modules), sorted(m for m in modules if m.startswith("compare.cli."))
    if argv in (["--help"], []):
        assert all(name in out for name in COMMANDS)


def test_a_command_imports_only_its_own_module() -> None:
    rc, modules, out = _imported_after(["validate", str(TINY)])
    assert rc == 0 and "ok" in out
    ours = {m for m in modules if m.startswith("compare.cli.")}
    assert ours == {"compare.cli.entry", "compare.cli.common", "compare.cli.validate"}


def test_version_names_the_package_version_and_commit(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    line = capsys.readouterr().out.strip()
    assert line == version_text()
    assert re.fullmatch(r"uam-compare \S+( \(commit [0-9a-f]{12}\))?", line), line
    assert line.split()[1] == metadata.version("uam-compare")
    assert "/" not in line  # no path of this machine


def test_the_table_of_commands_is_what_the_modules_add() -> None:
    """`--help` lists the commands from `COMMANDS` without importing their modules: the names, their order and
    their one-line help are the modules' own."""
    full = build_parser()
    sub = next(a for a in full._actions if a.dest == "command")
    assert list(sub.choices) == list(COMMANDS)
    assert {a.dest: a.help for a in sub._choices_actions} == {name: c.help for name, c in COMMANDS.items()}
    light = build_parser([])
    light_sub = next(a for a in light._actions if a.dest == "command")
    assert list(light_sub.choices) == list(COMMANDS)


def test_only_the_named_command_is_built_in_full() -> None:
    parser = build_parser(["train"])
    sub = next(a for a in parser._actions if a.dest == "command")
    assert any("--timesteps" in a.option_strings for a in sub.choices["train"]._actions)
    assert not any("--episodes" in a.option_strings for a in sub.choices["evaluate-policy"]._actions)
    assert parser.parse_args(["train", "--timesteps", "5"]).timesteps == 5
    with pytest.raises(ValueError, match="not commands: trian"):
        build_parser(["trian"])


@pytest.mark.parametrize(("argv", "command"), [
    (["train", "--envs", "8"], "train"), (["-v", "evaluate-policy"], "evaluate-policy"), (["--help"], None),
    ([], None), (["trian"], None), (["-v", "--version"], None)])
def test_the_command_is_the_first_word_that_is_not_an_option(argv: list[str], command: str | None) -> None:
    assert command_of(argv) == command
