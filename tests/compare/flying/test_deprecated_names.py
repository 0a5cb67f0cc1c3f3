"""The names before the pilot vocabulary (`Agent`, `PilotSpec`, `METHODS`, ...) still work for one release: each
gives the new object with a DeprecationWarning naming the new spelling, and a plug-in written against them still
flies through the registry, warning as it is loaded."""
from __future__ import annotations

import importlib
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from compare.flying import pilots
from compare.results.trajectory import SavedEpisode
from compare.run.cells import Cell, CellRunner
from compare.scenarios.scenario import load_scenario
from run_data import TINY

OLD_NAMES = [  # (module, old name, new spelling)
    ("uam_fdm.pilot", "Agent", "uam_fdm.pilot.Pilot"),
    ("compare.flying.pilots", "PilotSpec", "compare.flying.pilots.PilotEntry"),
    ("compare.flying.pilots", "METHODS", "compare.flying.pilots.PILOT_NAMES"),
    ("compare.flying.pilots", "DEFAULT_METHODS", "compare.flying.pilots.DEFAULT_PILOTS"),
    ("planners.agent", "ClassicalAgent", "planners.classical_pilot.ClassicalPilot"),
    ("rl.pilots.learned", "PolicyAgent", "rl.pilots.learned.PolicyPilot"),
    ("rl.pilots.potential_field", "PotentialFieldAgent", "rl.pilots.potential_field.PotentialFieldPilot"),
]

# A plug-in module written against the old names: a Pilot class (a subclass of the old potential-field pilot,
# checked against the old protocol) and a registry entry made with the old PilotSpec from the old METHODS.
OLD_PLUGIN = '''
from compare.flying.pilots import DEFAULT_METHODS, METHODS, PILOTS, PilotSpec
from rl.pilots.potential_field import PotentialFieldAgent
from uam_fdm.pilot import Agent


class OldField(PotentialFieldAgent):
    """The potential field, written against the old names."""

    label = "Old field"


assert isinstance(OldField(), Agent)
OLD_ENTRY = PilotSpec(name="old", label="Old entry", color="tab:olive", description="an entry of the old kind",
                      given="It is given what apf is.", build=PILOTS[METHODS[-1]].build)
assert "apf" in METHODS and "apf" not in DEFAULT_METHODS
'''


def _new(spelling: str) -> object:
    module, _, name = spelling.rpartition(".")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize(("module", "old", "new"), OLD_NAMES, ids=[o for _, o, _ in OLD_NAMES])
def test_each_old_name_warns_naming_the_new_one_and_is_the_new_object(module: str, old: str, new: str) -> None:
    with pytest.warns(DeprecationWarning, match=re.escape(f"{module}.{old} is renamed {new}")) as caught:
        got = getattr(importlib.import_module(module), old)
    assert got is _new(new)
    assert [w.filename for w in caught] == [__file__]  # the warning points at the code that used the old name
    with pytest.warns(DeprecationWarning, match=re.escape(new)):
        exec(f"from {module} import {old}", {})  # noqa: S102 - the import statement a plug-in author writes


@pytest.mark.parametrize("module", sorted({m for m, _, _ in OLD_NAMES}))
def test_other_missing_names_are_still_missing_without_a_warning(module: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(AttributeError, match=f"module '{re.escape(module)}' has no attribute 'Nope'"):
            importlib.import_module(module).Nope  # noqa: B018 - the lookup is the test
        assert not hasattr(importlib.import_module(module), "Agentish")


def test_a_plugin_written_against_the_old_names_flies_through_the_registry(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "old_names_plugin.py").write_text(OLD_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.warns(DeprecationWarning) as caught:
        field = pilots.pilot("old_names_plugin:OldField")
    warned = " ".join(str(w.message) for w in caught)
    for old in ("Agent", "PotentialFieldAgent", "PilotSpec", "METHODS", "DEFAULT_METHODS"):
        assert f".{old} is renamed" in warned
    assert field.label == "Old field" and field.description.endswith("(plug-in old_names_plugin:OldField)")
    entry = pilots.pilot("old_names_plugin:OLD_ENTRY")
    assert isinstance(entry, pilots.PilotEntry) and entry.label == "Old entry"
    sc = load_scenario(TINY)
    flown = {}
    for name in ("apf", "old_names_plugin:OldField", "old_names_plugin:OLD_ENTRY"):
        flown[name] = SavedEpisode(*CellRunner([sc], tmp_path / "run", {}).fly(Cell(0, 0, 0, name)))
    apf = flown.pop("apf")
    for name, saved in flown.items():  # the potential field under its old names flies exactly as apf
        assert saved.meta.key.method == name and saved.meta.outcome is apf.meta.outcome
        np.testing.assert_array_equal(saved.trajectory.states, apf.trajectory.states, err_msg=name)
