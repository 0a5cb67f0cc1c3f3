"""Flights played back: a run's flights grouped per cell (`flights`), animations (`animate`) and Rerun
recordings (`rerun_export`). Reads saved results only."""
