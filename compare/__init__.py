"""compare: scenarios, the one episode runner, metrics, reports and the `uam-compare` CLI."""
