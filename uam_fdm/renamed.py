"""Old names kept for one release after a rename, for code written against them (plug-in pilots, scripts).

A module that renamed a public name answers the old one from a module-level `__getattr__` (PEP 562) that calls
`renamed`: the caller gets the new object and a `RenamedWarning` (a DeprecationWarning) naming the new spelling.
The `__getattr__` stands under ``if not TYPE_CHECKING:`` so that the type checker still refuses a misspelt or old
name in our own code (a module-level `__getattr__` would make every attribute of the module look defined).
"""
from __future__ import annotations

import sys
import warnings
from collections.abc import Mapping
from types import ModuleType
from typing import Any


class RenamedWarning(DeprecationWarning):
    """A name or key of ours is used under its old spelling (a Python name, a scenario key): the user who wrote it
    must act, so the command line shows these (`compare.cli.entry`) where Python hides other DeprecationWarnings."""


def renamed(module: str, name: str, renames: Mapping[str, str], home: ModuleType | None = None) -> Any:
    """The object the old name `name` of `module` now goes by, with a `DeprecationWarning` naming the new spelling.

    Args:
        module: the module asked for `name` (its `__name__`).
        name: the attribute asked for.
        renames: old name -> new name.
        home: the module the new names live in (default: `module` itself).

    Raises:
        AttributeError: `name` is not an old name of `module` (what Python raises for a missing attribute).
    """
    new = renames.get(name)
    if new is None:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    home = sys.modules[module] if home is None else home
    warnings.warn(f"{module}.{name} is renamed {home.__name__}.{new}; the old name will be removed in the next "
                  f"release", RenamedWarning, stacklevel=3)  # 3: the code that asked, past `__getattr__`
    return getattr(home, new)
