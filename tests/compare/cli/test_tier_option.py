"""`run --tier SENSING/MAP_ERROR` flies only the scenarios at those levels (a benchmark set's cells): a value that is
not two known levels, or that no scenario is at, is one error line naming the option and the value, before anything
is written."""
from __future__ import annotations

from pathlib import Path

import pytest

from cli_checks import fails
from compare.cli import main
from compare.cli.run import only_tiers
from compare.scenarios.levels import with_levels
from compare.scenarios.sets import resolve_scenarios
from run_data import TINY


def test_only_the_scenarios_at_a_tier_are_kept() -> None:
    [tiny] = resolve_scenarios(TINY)
    both = [tiny, with_levels(tiny, "nominal", "wrong")]
    assert only_tiers(both, [], "x") == both
    assert only_tiers(both, [("nominal", "wrong")], "x") == [both[1]]
    assert only_tiers(both, [("perfect", "exact"), ("nominal", "wrong")], "x") == both
    with pytest.raises(ValueError, match=r"--tier degraded/wrong: no scenario of x .*nominal/wrong, perfect/exact"):
        only_tiers(both, [("degraded", "wrong")], "x")


def test_a_tier_no_scenario_is_at_is_refused_before_anything_is_written(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    fails(["run", str(TINY), "--tier", "nominal/wrong", "--out", str(tmp_path / "run"), "--no-progress"], capsys,
          tmp_path, "--tier nominal/wrong", "perfect/exact")


@pytest.mark.parametrize("value", ["nominal", "nominal/", "/wrong", "nominal/wrongg", "best/exact", "nominal/wrong/x"])
def test_a_malformed_tier_is_one_line_naming_the_option_and_value(capsys: pytest.CaptureFixture, value: str) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["run", "--tier", value])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err
    [line] = [ln for ln in err.splitlines() if "error:" in ln]
    assert "argument --tier" in line and repr(value) in line
