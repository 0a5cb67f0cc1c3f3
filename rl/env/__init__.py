"""The navigation environment: the batched engine (`world`), the gymnasium env, the SB3 VecEnv."""
