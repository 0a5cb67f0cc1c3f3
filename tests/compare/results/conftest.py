"""Fixtures of the results tests: one real run folder, flown once per session and copied by the tests that change
it."""
from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path

import pytest

from compare.cli import main
from run_data import TINY

FLOWN_PILOTS = ("ppo", "rrt_mpc", "apf")


@pytest.fixture(scope="session")
def flown_tiny_run(tmp_path_factory: pytest.TempPathFactory,
                   scoring_only: Callable[[], AbstractContextManager[None]]) -> Path:
    """The tiny scenario flown by the learned pilot (velocity commands, observations), the classical pilot (rotor
    speeds) and the potential field (velocity commands, no observation): a run folder with its store, metrics.csv
    and summary.json, no report, viewer or videos (none of its tests reads them)."""
    out = tmp_path_factory.mktemp("flown") / "tiny"
    with scoring_only():
        assert main(["run", str(TINY), "--pilot", "apf", "--pilots", ",".join(FLOWN_PILOTS), "--videos", "none",
                     "--no-progress", "--out", str(out)]) == 0
    return out
