"""rl: the learned pilot, in rooms by role.

- `rl.task`: what a policy is trained and evaluated on (`NavConfig`, the per-vehicle tasks, city and
  leg distributions, the reward);
- `rl.sensing`: what the pilot senses (observation, perception, clearance sensor, route potential),
  shared by the environment and the flying pilot;
- `rl.env`: the batched engine (`NavWorld`, `NavBatch`), the gymnasium env and the SB3 VecEnv;
- `rl.policies`: the policy-folder format, its safe reader, the network, and the shipped folders;
- `rl.training`: PPO presets and settings, the training loop, resuming, held-out evaluation;
- `rl.pilots`: the learned pilot and the potential-field pilot as `uam_fdm.pilot.Pilot`s.

Importing the package registers the gymnasium environment `UAMNav-v0` by its entry point's name
(`rl.env.gym_env:UAMNavEnv`, imported by `gymnasium.make` only), so importing any part of `rl`
stays light.
"""
from gymnasium.envs.registration import register, registry

if "UAMNav-v0" not in registry:
    register(id="UAMNav-v0", entry_point="rl.env.gym_env:UAMNavEnv")
