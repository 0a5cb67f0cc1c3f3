"""Errors raised for bad user input: they name the file, the key and the reason."""
from __future__ import annotations


class ConfigError(ValueError):
    """Bad user input (a vehicle, map or scenario file): names the file, the key and the reason."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source, self.key, self.reason = source, key, reason
        super().__init__(f"{source}: {key}: {reason}")
