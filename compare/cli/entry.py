"""The `uam-compare` entry point: the parser of every command, `main`, its exit codes, and how an error becomes
one line on stderr (the traceback of an unexpected one in a log file), as does a deprecation of our own.

The command modules import the packages their commands use (PyTorch, CasADi, matplotlib, OMPL, ...), so `main`
imports only the one module of the command it runs: `COMMANDS` names each command's module and one-line help, and
`uam-compare --help` or `--version` imports none of them.
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import signal
import sys
import tempfile
import threading
import traceback
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, TextIO

from compare.cli.common import CommandInterrupted, CommandParser
from uam_fdm.files.atomic import TEMP_MARK
from uam_fdm.files.version import code_version
from uam_fdm.renamed import RenamedWarning

DESCRIPTION = "The `uam-compare` command line."


@dataclass(frozen=True)
class Command:
    """One command of the command line: the module that adds it (`add_parser`) and runs it, and its one-line help
    (the module's own, checked by tests/compare/cli/test_entry.py)."""

    module: str
    help: str


COMMANDS: dict[str, Command] = {name: Command(f"compare.cli.{module}", text) for name, module, text in (
    ("demo", "demo", "fly the vehicle presets through a demo pattern and report what happened"),
    ("maps", "demo", "render the shipped maps (top-down and 3D) to PNG"),
    ("run", "run", "fly both pilots through scenarios and write metrics and the PDF report"),
    ("sweep", "run", "fly the robustness sweep (success and collision against density altitude and steady wind, "
                     "every pilot on the same tasks): `run sweep` with a per-step table; the report draws it"),
    ("report", "report", "rescore a run folder's saved episodes, rebuild its report and viewer (no simulation)"),
    ("animate", "playback", "render both pilots flying one cell of a run to MP4 (GIF without ffmpeg)"),
    ("view", "playback", "write a run folder's interactive 3D viewer (one self-contained HTML file)"),
    ("view-training", "playback", "write one offline HTML page of a policy's training: the curves, and the "
                                  "recorded flights of every checkpoint in 3D, scrubbable"),
    ("export", "playback", "write a run's flights, or a policy's recorded training flights, as a Rerun recording "
                           "(.rrd; needs the rerun extra)"),
    ("validate", "validate", "check scenario files strictly without flying anything"),
    ("list", "catalog", "list the scenario sets, shipped maps, vehicles, pilots (plug-ins too) and shipped policies, "
                        "one line each (--json for scripts)"),
    ("train", "train", "train the learned pilot with PPO from scratch on the batched environment"),
    ("evaluate-policy", "evaluate", "fly a policy and the potential-field pilot (apf) on the same held-out cities; "
                                    "last line is JSON"),
)}
"""Every command, in the order `--help` lists them; a module's commands stand together."""

BAD_INPUT_EXIT = 2  # bad input (a file, a key, an option): the one error line says which and why
INTERNAL_ERROR_EXIT = 1  # anything else: a bug or a broken installation; the traceback is in a log file
INTERRUPTED_EXIT = 130  # the shell's code for a command stopped by Ctrl-C (128 + SIGINT)
LOG_DIR_ENV = "UAM_COMPARE_LOG_DIR"
"""Where the last-resort handler writes tracebacks (default: <temporary folder>/uam-compare-logs)."""
MAX_MESSAGE_CHARS = 300


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line: the global options and every command of `COMMANDS`.

    Args:
        commands: the commands whose options are wanted (their modules are imported); the others are there by
            name and one-line help only. None: every command in full.

    Raises:
        ValueError: a name in `commands` is not a command.
    """
    wanted = set(COMMANDS) if commands is None else set(commands)
    unknown = sorted(wanted - set(COMMANDS))
    if unknown:
        raise ValueError(f"not commands: {', '.join(unknown)} (the commands: {', '.join(COMMANDS)})")
    full = {COMMANDS[w].module for w in wanted}
    parser = argparse.ArgumentParser(prog="uam-compare", description=DESCRIPTION)
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO)")
    parser.add_argument("--version", action=_VersionAction, help="print the version (and commit) and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CommandParser)
    added: set[str] = set()
    for name, command in COMMANDS.items():
        if command.module not in full:
            sub.add_parser(name, help=command.help)
        elif command.module not in added:  # adds every command of its module, which stand together
            importlib.import_module(command.module).add_parser(sub)
            added.add(command.module)
    return parser


def command_of(argv: Sequence[str]) -> str | None:
    """The command `argv` runs: its first word that is not a global option (None: no command, or not one of ours,
    which argparse then refuses naming the commands)."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def version_text() -> str:
    """"uam-compare <package version> (commit <12 hex digits>)": the commit where the package runs from a git
    checkout (`uam_fdm.files.version`, which runs git; no path of this machine is printed)."""
    code = code_version()
    text = f"uam-compare {code['uam-compare'] or 'unknown version (not installed)'}"
    return text + (f" (commit {code['commit'][:12]})" if code["commit"] else "")


class _VersionAction(argparse.Action):
    """`--version`: the version line on stdout, then exit 0 (read only when asked: it may run git)."""

    def __init__(self, option_strings: Sequence[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(version_text())
        parser.exit()


class _CliFormatter(logging.Formatter):
    """Log records as the CLI's own lines: "uam-compare: warning: <message>"."""

    def format(self, record: logging.LogRecord) -> str:
        return f"uam-compare: {record.levelname.lower()}: {record.getMessage()}"


def main(argv: list[str] | None = None) -> int:
    """Run one command line (default: this process's); returns its exit code, and every error is one line on
    stderr: 2 for bad input, 130 when interrupted, 1 for anything else (its traceback in a log file)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = command_of(argv)
    parser = build_parser([] if command is None else [command])
    args = parser.parse_args(argv)
    args.argv = argv
    handler = logging.StreamHandler()  # a no-op where the caller configured logging already (basicConfig)
    # without -v a user sees the same "uam-compare: warning: ..." lines as the CLI's own warnings
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s") if args.verbose else _CliFormatter())
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, handlers=[handler])
    if args.command is None:
        parser.print_help()
        return 0
    # SIGTERM stops a command the way Ctrl-C does (a run keeps its finished episodes and says how to resume);
    # only the main thread may set handlers, and the previous one comes back for library callers.
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler) if in_main else None
    try:
        with own_deprecations_on_stderr():
            return _run_command(args)
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)


def _run_command(args: argparse.Namespace) -> int:
    """The command's exit code; an exception said in one line on stderr."""
    try:
        return args.func(args)
    except CommandInterrupted as stop:  # the command kept its work and says how to go on
        print(f"uam-compare: interrupted: {stop}", file=sys.stderr)
        return INTERRUPTED_EXIT
    except KeyboardInterrupt:
        print(f"uam-compare: interrupted ({args.command}); its outputs are written whole or not at all",
              file=sys.stderr)
        return INTERRUPTED_EXIT
    except ValueError as exc:   # bad user input (ConfigError is a ValueError): one clear line, non-zero exit
        print(f"uam-compare: error: {exc}", file=sys.stderr)
        return BAD_INPUT_EXIT
    except OSError as exc:      # the file system said no (disk full, permissions): which file, and why
        print(f"uam-compare: error: {os_error_message(exc)}", file=sys.stderr)
        return BAD_INPUT_EXIT
    except (Exception, SystemExit) as exc:  # the last resort: one line, the traceback in a file
        if isinstance(exc, SystemExit) and exc.code in (None, 0):
            return 0
        print(f"uam-compare: error: {args.command}: internal error {last_resort(exc, args.command)}",
              file=sys.stderr)
        return INTERNAL_ERROR_EXIT


@contextlib.contextmanager
def own_deprecations_on_stderr() -> Iterator[None]:
    """While a command runs, each of our `RenamedWarning`s (an old key in a scenario file, an old name a plug-in
    imports) is one line on stderr, "uam-compare: warning: <message>", once per place: Python hides
    DeprecationWarnings outside `__main__`, yet the one who must act on ours (change the file, update the
    plug-in) is the command's user. Every other warning is left to Python's filters (-W, PYTHONWARNINGS), which
    then decide for ours too. The warnings filters and `warnings.showwarning` are restored on exit."""
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
            if issubclass(category, RenamedWarning):
                print(f"uam-compare: warning: {' '.join(str(message).split())}", file=sys.stderr)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        if not sys.warnoptions:
            warnings.simplefilter("default", RenamedWarning)
        yield


def last_resort(exc: BaseException, command: str) -> str:
    """Log `exc`'s full traceback to a new file in the log folder; returns the rest of the one error line: the
    exception, and where its traceback is (or why it could not be written)."""
    what = f"({type(exc).__name__}: {one_line(str(exc))})"
    folder = Path(os.environ.get(LOG_DIR_ENV) or Path(tempfile.gettempdir()) / "uam-compare-logs")
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f"{datetime.now().strftime('%Y%m%d-%H%M%S')}-{command}-",
                                    suffix=".log", dir=folder)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(f"uam-compare {' '.join(sys.argv[1:])}\n{text}")
    except OSError as log_exc:
        return f"{what}; the traceback could not be logged in {folder} ({log_exc.strerror or log_exc})"
    return f"{what}; full traceback in {name}"


def one_line(text: str) -> str:
    """`text` on one line, at most `MAX_MESSAGE_CHARS` characters."""
    flat = " ".join(text.split())
    return flat if len(flat) <= MAX_MESSAGE_CHARS else flat[:MAX_MESSAGE_CHARS] + "..."


def os_error_message(exc: OSError) -> str:
    """One line for a failed read or write: the file, the system's reason, and for a full disk what was kept.

    A temporary of an atomic write (".<name>.partial-...") is named by the file it was to become: the user never
    made it and will not find it.
    """
    filename = exc.filename
    if filename is not None and TEMP_MARK in Path(str(filename)).name:
        temp = Path(str(filename))
        filename = temp.with_name(temp.name[1:].split(TEMP_MARK)[0])
    text = f"{filename}: {exc.strerror or exc}" if filename is not None else str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        text += ": the disk is full; the file was not written (no partial file is left)"
    return text
