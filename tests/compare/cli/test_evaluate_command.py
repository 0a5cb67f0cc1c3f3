"""`uam-compare evaluate-policy` as a user meets it: progress on stderr while it flies, a default of a few hundred
episodes whose interval the help states, and the potential-field pilot called `apf` (its old JSON keys kept)."""
from __future__ import annotations

import json
from typing import Any

import pytest

import rl.env.world
import rl.training.evaluation as evaluation
from compare.cli import main
from compare.cli.entry import build_parser
from compare.cli.evaluate import DEFAULT_EPISODES, OLD_JSON_KEYS, interval_half_width


@pytest.fixture
def instant_evaluation(monkeypatch: pytest.MonkeyPatch) -> None:
    """Nothing built or flown: each pilot's episodes end one by one, said to `progress` as the real loop says them."""
    class World:
        atmospheres = (None,)

        def __init__(self, nav: object) -> None:
            pass

    def flown(episodes: int, seed: int, pool: str, progress: Any, successes: int) -> evaluation.EvalResult:
        for ended in range(1, episodes + 1):
            progress(ended, episodes)
        outcomes = ("success",) * successes + ("timeout",) * (episodes - successes)
        return evaluation.EvalResult(episodes, successes / episodes, 0.0, (0.0, 1.0), (0.0, 1.0),
                                     {"success": successes, "timeout": episodes - successes}, 0.0, 10.0, outcomes,
                                     pool, seed)

    monkeypatch.setattr(rl.env.world, "NavWorld", World)
    monkeypatch.setattr(evaluation, "evaluate", lambda pilot, nav, episodes, seed=0, pool="test", world=None,
                        progress=None: flown(episodes, seed, pool, progress, episodes))
    monkeypatch.setattr(evaluation, "evaluate_potential_field", lambda nav, episodes, seed=0, pool="test",
                        world=None, progress=None: flown(episodes, seed, pool, progress, episodes // 2))
    monkeypatch.setattr(evaluation, "rates_by_city_component", lambda res, nav: ())


def test_progress_goes_to_stderr_once_a_tenth(capsys: pytest.CaptureFixture, instant_evaluation: None) -> None:
    assert main(["evaluate-policy", "--episodes", "40"]) == 0
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert all(ln.startswith("evaluate-policy: ") for ln in lines)
    for pilot in ("ppo", "apf"):
        ended = [ln for ln in lines if ln.startswith(f"evaluate-policy: {pilot}: ")]
        assert [ln.split()[2] for ln in ended] == [f"{4 * k}/40" for k in range(1, 11)]
    assert "evaluate-policy" not in out  # stdout keeps the results alone, the JSON line last
    last = json.loads(out.splitlines()[-1])
    assert last["apf_success_rate"] == 0.5 and last["success_rate"] == 1.0
    assert all(last[old] == last[new] for old, new in OLD_JSON_KEYS.items())
    assert [ln.split()[0] for ln in out.splitlines()[1:3]] == ["ppo", "apf"]
    assert main(["evaluate-policy", "--episodes", "40", "--no-progress"]) == 0
    assert capsys.readouterr().err == ""


def test_the_default_is_a_few_hundred_episodes_and_the_help_says_what_it_buys(capsys: pytest.CaptureFixture) -> None:
    assert build_parser(["evaluate-policy"]).parse_args(["evaluate-policy"]).episodes == DEFAULT_EPISODES
    assert 100 <= DEFAULT_EPISODES <= 500
    half = interval_half_width(DEFAULT_EPISODES, 0.5)
    assert 5.0 < half < 6.0 and interval_half_width(1000, 0.5) < half  # 1.96 sqrt(0.25 / n), about
    with pytest.raises(SystemExit):
        main(["evaluate-policy", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"default {DEFAULT_EPISODES}" in text and f"+/-{half:.1f} points at 50 % success" in text
    assert "apf" in text and "expert_*" in text


def test_episodes_at_several_levels_are_counted_per_level(capsys: pytest.CaptureFixture, instant_evaluation: None,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A policy trained across sensing and map-error levels flies its episodes at each: the rates per level and pair
    are printed and in the JSON line; an evaluation at one level of each has none."""
    levels = (("nominal", "exact"), ("degraded", "wrong")) * 5

    def at_levels(pilot, nav, episodes, seed=0, pool="test", world=None, progress=None) -> evaluation.EvalResult:
        outcomes = ("success", "collision") * 5
        return evaluation.EvalResult(10, 0.5, 0.5, (0.0, 1.0), (0.0, 1.0), {"collision": 5, "success": 5}, 0.0, 10.0,
                                     outcomes, pool, seed, levels)

    monkeypatch.setattr(evaluation, "evaluate", at_levels)
    assert main(["evaluate-policy", "--episodes", "10", "--no-progress", "--no-baseline"]) == 0
    out = capsys.readouterr().out
    assert "by sensing and map-error level:" in out
    line = next(ln for ln in out.splitlines() if ln.split()[:3] == ["ppo", "sensing", "degraded"])
    assert "5 episodes, success   0.0% [0.0%, 43.4%], collisions 100.0%" in line
    rows = {g["label"]: g for g in json.loads(out.splitlines()[-1])["by_level"]["ppo"]}
    assert list(rows) == ["sensing nominal", "sensing degraded", "map exact", "map wrong", "nominal / exact",
                          "degraded / wrong"]
    assert rows["map exact"]["success_rate"] == 1.0 and rows["degraded / wrong"]["collision_rate"] == 1.0
