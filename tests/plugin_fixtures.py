"""Objects named as plug-in pilots by tests/compare/flying/test_plugin_pilots.py (`plugin_fixtures:...`)."""
from __future__ import annotations

from compare.flying.pilots import PILOTS, PilotEntry
from rl.pilots.potential_field import PotentialFieldPilot


class NoAct:
    """Has no `act`: not a pilot."""

    name = "no_act"

    def reset(self, world, task, seed):
        return None

    def episode_report(self):
        return None


class NamedWrong(PotentialFieldPilot):
    """The potential-field pilot under another class: its `name` attribute ("apf") is not the name it flies under."""


NOT_A_CLASS = 3
ENTRY: PilotEntry = PilotEntry(name="anything", label="Entered field", color="tab:olive", description="an entry",
                               given="It is given an entry.", build=PILOTS["apf"].build, default=True)
