"""Checks shared by the tests that run the CLI on bad or hostile inputs: one error line, the exit code, and
nothing under the test's folder written or changed."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from compare.cli import main


def snapshot(root: Path) -> dict[str, str]:
    """Every file and folder under `root` with a hash of its content: compared before and after a command."""
    return {str(p.relative_to(root)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))}


def error_line(err: str) -> str:
    """The single `uam-compare: error:` line of stderr (no traceback, no second error)."""
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("uam-compare: error:")]
    assert len(lines) == 1, err
    return lines[0]


def fails(argv: list[str], capsys: pytest.CaptureFixture, root: Path, *expected: str, code: int = 2) -> str:
    """Run the CLI: exit `code`, one error line holding every `expected` text, `root` unchanged."""
    before = snapshot(root)
    assert main(argv) == code
    line = error_line(capsys.readouterr().err)
    for text in expected:
        assert text in line, (text, line)
    assert snapshot(root) == before
    return line
