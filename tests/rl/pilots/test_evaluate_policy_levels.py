"""`evaluate-policy --sensing/--map-error`: the policy flies the held-out episodes at the scenario presets' levels,
its JSON line states them, and a bad level is refused naming the option and the value before anything is built."""
from __future__ import annotations

import json

import pytest

from compare.cli import main
from rl.task.config import NavConfig
from rl.training.evaluation import eval_config


@pytest.mark.parametrize(("option", "value"), [("--sensing", "perfectt"), ("--sensing", "Nominal"),
                                               ("--map-error", "none")])
def test_a_bad_level_is_refused_naming_the_option_and_value(capsys, monkeypatch, option, value):
    import rl.env.world

    def built(*_args, **_kwargs):  # pragma: no cover (reached only if the option were let through)
        raise AssertionError("a world was built for a refused option")

    monkeypatch.setattr(rl.env.world, "NavWorld", built)
    with pytest.raises(SystemExit) as stop:
        main(["evaluate-policy", "--episodes", "2", option, value])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err
    [line] = [ln for ln in err.splitlines() if "error:" in ln]
    assert f"argument {option}: invalid choice: '{value}'" in line


def test_perfect_sensing_over_a_wrong_map_is_sent_to_the_runner(capsys, monkeypatch):
    import rl.env.world

    def built(*_args, **_kwargs):  # pragma: no cover (reached only if the combination were let through)
        raise AssertionError("a world was built for a refused combination")

    monkeypatch.setattr(rl.env.world, "NavWorld", built)
    assert main(["evaluate-policy", "--episodes", "2", "--sensing", "perfect", "--map-error", "wrong"]) == 2
    err = capsys.readouterr().err
    assert "--sensing perfect --map-error wrong" in err and "uam-compare run" in err and "Traceback" not in err


def test_eval_config_replaces_the_tasks_levels_or_keeps_them():
    nav = NavConfig(sensing=("perfect", "nominal"), map_error=("exact", "wrong"))
    kept = eval_config(nav, 2)
    assert (kept.sensing, kept.map_error) == (("perfect", "nominal"), ("exact", "wrong"))
    flown = eval_config(nav, 2, sensing="degraded", map_error="outdated")
    assert (flown.sensing, flown.map_error) == (("degraded",), ("outdated",))
    with pytest.raises(ValueError, match="bogus"):
        eval_config(nav, 2, sensing="bogus")


def test_the_json_line_states_the_levels_flown(capsys):
    assert main(["evaluate-policy", "--episodes", "2", "--pool", "validation", "--no-baseline", "--no-progress",
                 "--sensing", "nominal", "--map-error", "outdated"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    last = json.loads(out[-1])
    assert last["sensing"] == "nominal" and last["map_error"] == "outdated" and last["episodes"] == 2
    assert sum(last["outcomes"].values()) == 2
    assert "nominal sensing, outdated map" in out[0]
