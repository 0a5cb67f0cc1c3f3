"""Objects named as plug-in pilots by tests/compare/flying/test_plugin_pilots.py (`plugin_fixtures:...`)."""
from __future__ import annotations

from compare.flying.pilots import PILOTS, PilotSpec
from rl.pilots.potential_field import PotentialFieldAgent


class NoAct:
    """Has no `act`: not a pilot."""

    name = "no_act"

    def reset(self, world, task, seed):
        return None

    def episode_report(self):
        return None


class NamedWrong(PotentialFieldAgent):
    """The potential-field pilot under another class: its `name` attribute ("apf") is not the method's."""


NOT_A_CLASS = 3
SPEC: PilotSpec = PilotSpec(name="anything", label="Spec'd field", color="tab:olive", description="a spec",
                            given="It is given a spec.", build=PILOTS["apf"].build, default=True)
