"""Which code produced an output: the package version and, in a git checkout, its commit."""
from __future__ import annotations

import subprocess
from importlib import metadata
from pathlib import Path


def _git_commit() -> str | None:
    """The commit of the checkout the package runs from, or None (an installed package, no git)."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        r = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                           timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() or None


def code_version() -> dict[str, str | None]:
    """The package version and, in a git checkout, its commit (uncommitted edits are not seen)."""
    try:
        version: str | None = metadata.version("uam-compare")
    except metadata.PackageNotFoundError:
        version = None
    return {"uam-compare": version, "commit": _git_commit()}
