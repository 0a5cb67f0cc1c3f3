"""The learned pilot's policy per vehicle: the run picks the shipped policy of each scenario's vehicle,
`--policy` replaces it for the vehicle it was trained for, and the default set flies both pilots on
both vehicles (planned here, not flown: `tests/compare/cli/test_run_command.py` flies a run)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from compare.run.campaign import RunConfig, plan_cells, select_policies
from compare.scenarios.sets import resolve_scenarios
from rl.policies.folder import SHIPPED_POLICIES


@pytest.mark.parametrize("name", ["default", "full"])
def test_shipped_sets_fly_both_pilots_on_both_vehicles(tmp_path: Path, name: str) -> None:
    scenarios = resolve_scenarios(name)
    opts = RunConfig(out_dir=tmp_path)
    policies = select_policies(scenarios, opts)
    assert {p.vehicle for p in policies.values()} == {"small_quad", "uam_multicopter"}
    for p in policies.values():
        assert p.folder == SHIPPED_POLICIES[p.vehicle].resolve()
    cells, notes = plan_cells(scenarios, opts, policies)
    assert notes == []
    flown = {(scenarios[c.scenario].vehicle.name, c.pilot) for c in cells}
    names = ("ppo", "rrt_mpc") + (("apf",) if name == "full" else ())  # the full set adds the potential field
    assert flown == {(v, m) for v in ("small_quad", "uam_multicopter") for m in names}


def test_a_given_policy_replaces_the_shipped_one_for_its_vehicle_only(tmp_path: Path) -> None:
    mine = tmp_path / "my-quad-policy"
    shutil.copytree(SHIPPED_POLICIES["small_quad"], mine)
    scenarios = resolve_scenarios("default")
    policies = select_policies(scenarios, RunConfig(out_dir=tmp_path, policies=(mine,)))
    by_vehicle = {p.vehicle: p.folder for p in policies.values()}
    assert by_vehicle == {"small_quad": mine.resolve(),
                          "uam_multicopter": SHIPPED_POLICIES["uam_multicopter"].resolve()}


def test_two_policies_for_one_vehicle_are_refused(tmp_path: Path) -> None:
    mine = tmp_path / "copy"
    shutil.copytree(SHIPPED_POLICIES["small_quad"], mine)
    with pytest.raises(ValueError, match=r"--policy .*copy: a second policy for vehicle 'small_quad'"):
        select_policies(resolve_scenarios("default"),
                        RunConfig(out_dir=tmp_path, policies=(SHIPPED_POLICIES["small_quad"], mine)))


def test_a_vehicle_without_a_policy_flies_only_the_classical_pilot(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import rl.policies.folder

    monkeypatch.setitem(rl.policies.folder.SHIPPED_POLICIES, "uam_multicopter", tmp_path / "none-shipped")
    scenarios = resolve_scenarios("default")
    opts = RunConfig(out_dir=tmp_path)
    cells, notes = plan_cells(scenarios, opts, select_policies(scenarios, opts))
    flown = {(scenarios[c.scenario].vehicle.name, c.pilot) for c in cells if c.pilot == "ppo"}
    assert flown == {("small_quad", "ppo")}
    assert len(notes) == 1 and "no learned policy for vehicle 'uam_multicopter'" in notes[0]
