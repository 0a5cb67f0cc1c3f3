"""rl: the learned pilot (gymnasium environment, batched training env, SB3 PPO, shipped policy).

Importing the package registers the gymnasium environment `UAMNav-v0` (see `rl.env`).
"""
from rl.env import register as _register

_register()
