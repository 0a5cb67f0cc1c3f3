"""The module's old name: the classical pilot is `planners.classical_pilot.ClassicalPilot`.

Kept for one release, for code written against the old names: `planners.agent.ClassicalAgent` gives
`ClassicalPilot` with a `DeprecationWarning` (`uam_fdm.renamed`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from uam_fdm.renamed import renamed

if not TYPE_CHECKING:  # hidden from the type checker: our own code must use the new names
    def __getattr__(name: str) -> Any:
        """`ClassicalAgent`: `planners.classical_pilot.ClassicalPilot`, with a warning."""
        from planners import classical_pilot  # CasADi and OMPL: only when the old name is asked for

        return renamed(__name__, name, {"ClassicalAgent": "ClassicalPilot"}, classical_pilot)
