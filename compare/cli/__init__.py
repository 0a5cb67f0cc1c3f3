"""The `uam-compare` command line, one module per family of commands, each adding its commands (`add_parser`)
beside the functions that run them: `demo` (demo, maps), `run` (run, sweep), `report`, `playback` (animate,
view, view-training, export), `validate`, `train`, `evaluate` (evaluate-policy). `entry` holds `main`, the exit
codes and the one-line errors; `printout` what a finished run prints; `common` what the commands share."""
from compare.cli.entry import BAD_INPUT_EXIT, INTERNAL_ERROR_EXIT, INTERRUPTED_EXIT, build_parser, main

__all__ = ["BAD_INPUT_EXIT", "INTERNAL_ERROR_EXIT", "INTERRUPTED_EXIT", "build_parser", "main"]
