"""The task a learned pilot is trained and evaluated on: `NavConfig`, per-vehicle tasks, the reward."""
