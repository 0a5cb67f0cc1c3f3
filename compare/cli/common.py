"""What the commands share: the parser class of every command, old option spellings kept as hidden aliases, option
checks that name the option, and the one-thread PyTorch setting of the commands that fly."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar


class CommandInterrupted(Exception):
    """A command stopped by the user (Ctrl-C, SIGTERM) that kept what it finished; the message says what and how
    to go on. `compare.cli.entry.main` prints it and exits with the shell's code for an interrupted command."""


class CommandParser(argparse.ArgumentParser):
    """A command's parser. Its options' help may show a typed config's defaults: each `{name}` in a help text is
    `help_values()[name]`, read only when the help is printed, as the config's module may import PyTorch or
    matplotlib, which a command line that asks for no help must not wait for.

    Args:
        help_values: the texts of the `{name}` fields of this command's help (None: none).
    """

    def __init__(self, *args: Any, help_values: Callable[[], Mapping[str, str]] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.help_values = help_values

    def format_help(self) -> str:
        if self.help_values is not None:
            values = {k: v.replace("%", "%%") for k, v in self.help_values().items()}  # help is %-formatted next
            for action in self._actions:
                if action.help and "{" in action.help:
                    action.help = action.help.format_map(values)
            self.help_values = None  # filled in once
        return super().format_help()


class _DeprecatedAlias(argparse.Action):
    """An option's old spelling, hidden from the help: one warning line on stderr naming the new spelling, then
    the new option's own action."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: argparse.Action) -> None:
        super().__init__(option_strings, dest, nargs=new.nargs, default=argparse.SUPPRESS, metavar=new.metavar,
                         help=argparse.SUPPRESS)
        self.type = new.type  # the value is converted as the new option's, before `__call__`
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        new = self.new.option_strings[0]
        print(f"uam-compare: warning: {option_string} is deprecated; use {new}", file=sys.stderr)
        self.new(parser, namespace, values, new)


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: argparse.Action) -> None:
    """Accept `old` as a hidden spelling of the option `new` (the action `add_argument` returned), with a warning."""
    parser.add_argument(old, action=_DeprecatedAlias, new=new)


def csv_list(text: str, kind: Callable[[str], Any] = str) -> tuple:
    """A comma-separated option value as a tuple of `kind` (blank items dropped); none at all is an error."""
    items = tuple(kind(v.strip()) for v in text.split(",") if v.strip())
    if not items:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    return items


def check_ranges(values: dict[str, tuple[int, int, int]]) -> None:
    """Raise ValueError naming the first option whose value is outside [low, high] (option -> value, low, high)."""
    for option, (value, low, high) in values.items():
        if not low <= value <= high:
            raise ValueError(f"{option} {value}: must be between {low} and {high}")


T = TypeVar("T")


def option(name: str, check: Callable[[str], T], value: str) -> T:
    """`check(value)`, its ValueError said as the option's: "--option value: reason"."""
    try:
        return check(value)
    except ValueError as exc:
        raise ValueError(f"{name} {value}: {exc}") from None


def turbulence_levels(text: str) -> tuple[str, ...]:
    """--turbulence's levels ("moderate", or "none,light,moderate").

    Raises:
        ValueError: an unknown or repeated level, naming the option.
    """
    from rl.task.air import AirDistribution  # the learned pilot's package: not for a command line that needs none

    levels = tuple(t.strip() for t in text.split(","))
    try:
        AirDistribution(turbulence=levels)
    except ValueError as exc:
        raise ValueError(f"--turbulence {text}: {str(exc).removeprefix('air.turbulence ')}") from None
    return levels


def one_torch_thread() -> None:
    """This process flies small networks one observation at a time: one torch thread is fastest."""
    import torch  # PyTorch: seconds to import, only for the commands that fly

    torch.set_num_threads(1)
