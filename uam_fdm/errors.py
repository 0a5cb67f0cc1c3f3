"""Errors raised for bad user input: they name the file, the key and the reason."""
from __future__ import annotations

# A bad value is quoted in its error message; a huge one (a 10 MB string, a list of a million numbers)
# would bury the message, so key and reason are cut to these lengths with a note of what was cut.
MAX_KEY_CHARS = 200
MAX_REASON_CHARS = 600


def shorten(text: str, limit: int) -> str:
    """`text` cut to about `limit` characters, saying how many were left out."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text) - limit:,} more characters)"


class ConfigError(ValueError):
    """Bad user input (a vehicle, map or scenario file): names the file, the key and the reason."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source = source
        self.key = shorten(str(key), MAX_KEY_CHARS)
        self.reason = shorten(str(reason), MAX_REASON_CHARS)
        super().__init__(f"{self.source}: {self.key}: {self.reason}")
