"""rl: the learned pilot (gymnasium environment, batched training env, SB3 PPO, shipped policy)."""
