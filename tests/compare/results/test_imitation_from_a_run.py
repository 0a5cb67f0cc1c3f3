"""A run's store is enough to train an imitation baseline: the decisions table pairs what each pilot was given
(the learned pilot's observation vector, or the state) with the command it gave, and a least-squares fit on half
of a tiny run's decisions reproduces the commands of the other half far better than the best constant."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pytest

from compare.results.run_tables import load_run
from compare.results.store_schema import STATE_COLUMNS


def _held_out_rms(x: np.ndarray, y: np.ndarray, ridge: float = 1e-3) -> tuple[float, float]:
    """RMS error on the odd decisions of a ridge fit on the even ones, and of the even ones' mean command."""
    fit, test = slice(0, None, 2), slice(1, None, 2)
    mean, spread = x[fit].mean(axis=0), x[fit].std(axis=0) + 1e-6
    a = np.hstack([(x - mean) / spread, np.ones((len(x), 1))]).astype(np.float64)
    w = np.linalg.solve(a[fit].T @ a[fit] + ridge * np.eye(a.shape[1]), a[fit].T @ y[fit])
    return (float(np.sqrt(np.mean((a[test] @ w - y[test]) ** 2))),
            float(np.sqrt(np.mean((y[fit].mean(axis=0) - y[test]) ** 2))))


@pytest.mark.parametrize(("pilot", "features", "command_size"), [
    ("ppo", ("observation",), 4),   # its policy's input -> velocity [m/s] ENU and heading [rad]
    ("rrt_mpc", STATE_COLUMNS, 4),  # the state -> four rotor speeds [rad/s]
    ("apf", STATE_COLUMNS, 4),      # the state -> velocity and heading
])
def test_a_least_squares_pilot_fitted_on_the_store_reproduces_the_stored_commands(
        flown_tiny_run: Path, pilot: str, features: tuple[str, ...], command_size: int) -> None:
    x, y = load_run(flown_tiny_run).imitation_pairs(pilot, features)
    assert x.dtype == y.dtype == np.float32 and y.shape == (len(x), command_size) and len(x) > 50
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.ptp(y, axis=0).max() > 0.5
    fitted, constant = _held_out_rms(x, y)
    assert fitted < 0.25 * constant, (fitted, constant)


def test_the_stored_commands_are_the_ones_flown(flown_tiny_run: Path) -> None:
    run = load_run(flown_tiny_run)
    samples = run.samples.filter(pc.equal(run.samples.column("method"), "rrt_mpc"))
    flown = samples.column("rotor_command_rad_s").to_pylist()  # applied during the steps ending at each row
    actions = samples.column("action").to_pylist()
    decided = [i for i, a in enumerate(actions) if a is not None]
    assert len(decided) == samples.column("decision_t_s").drop_null().length() > 50
    # a rotor-speed command is flown as given until the next row (every row a decision: the MPC's 50 Hz)
    same = [i for i in decided[:-1] if actions[i] == flown[i + 1]]
    assert len(same) >= len(decided) - 3  # all but the rows around the physics step of least clearance
    ppo = run.decisions.filter(pc.equal(run.decisions.column("method"), "ppo"))
    assert set(ppo.column("action_hold_periods").to_pylist()) == {5}  # its policy decides at 10 Hz
    np.testing.assert_allclose(np.diff(ppo.column("decision_t_s").to_numpy()), 0.1, atol=1e-9)
