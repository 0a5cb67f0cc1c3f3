"""Training the learned pilot with PPO: presets, run settings, the loop, resuming, evaluation."""
