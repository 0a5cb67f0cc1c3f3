"""Producing and keeping results: episode files, per-episode metrics, run summaries, output folders.
Nothing here draws; `compare.viz` reads results through these types only."""
