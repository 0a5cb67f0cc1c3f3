"""Flying a learned pilot imports no training code: the shipped pilots are built in a fresh interpreter and
neither `rl.training` nor Stable-Baselines3 (whose package imports its PPO) is loaded; `import rl` stays light."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from rl.policies.folder import SHIPPED_POLICIES

_BUILD = """
import json, sys
from rl.pilots.learned import PolicyPilot, load_policy
from rl.policies.folder import SHIPPED_POLICIES
from uam_fdm.vehicle.params import load_vehicle
pilot = PolicyPilot(load_policy(SHIPPED_POLICIES[sys.argv[1]], load_vehicle(sys.argv[1])))
print(json.dumps(sorted(sys.modules)))
"""


def _modules(code: str, *args: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True)
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize("vehicle", sorted(SHIPPED_POLICIES))
def test_building_a_shipped_pilot_imports_no_training_code(vehicle: str) -> None:
    loaded = _modules(_BUILD, vehicle)
    assert "rl.pilots.learned" in loaded and "torch" in loaded  # the probe did build the pilot
    assert not {m for m in loaded if m.startswith(("rl.training", "stable_baselines3"))}
    assert "stable_baselines3.ppo" not in loaded


def test_importing_rl_loads_neither_the_env_nor_torch() -> None:
    loaded = _modules("import json, sys, rl, rl.policies.folder; print(json.dumps(sorted(sys.modules)))")
    assert not {m for m in loaded if m.startswith(("rl.env", "rl.training", "torch", "stable_baselines3"))}
    import gymnasium

    assert "UAMNav-v0" in gymnasium.registry  # registered by name on `import rl`
    assert gymnasium.registry["UAMNav-v0"].entry_point == "rl.env.gym_env:UAMNavEnv"
