"""Producing and keeping results: episode files (`trajectory`), per-episode metrics and metrics.csv (`metrics`),
the run's summary.json (`summary`) and run.json (`run_info`), output folders (`outputs`). Each file has one
writer and one reader here. Nothing here draws; the report, playback and pages read results through these types only."""
