"""The `uam-compare` command line (placeholder until the flight-dynamics demo lands)."""
from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    return 0
