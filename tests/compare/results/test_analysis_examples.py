"""The analysis examples of the README ("## Analysis") and of docs/comparison.md ("### Reading a run", "### Decisions")
run as written against a real run folder, with the `analysis` extra the set-up installs (pandas, DuckDB, polars),
and compare pilots per vehicle: every grouping of episodes names the vehicle."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SECTIONS = [(ROOT / "README.md", "## Analysis"), (ROOT / "docs" / "comparison.md", "### Reading a run"),
            (ROOT / "docs" / "comparison.md", "### Decisions")]


def _section(path: Path, heading: str) -> str:
    """The text of `path` under the heading that starts with `heading`, up to the next heading of any level."""
    text = path.read_text(encoding="utf-8")
    start = next(m.end() for m in re.finditer(rf"^{re.escape(heading)}.*$", text, re.M))
    end = re.search(r"^#{1,6} ", text[start:], re.M)
    return text[start:start + end.start()] if end else text[start:]


def _python_blocks(path: Path, heading: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", _section(path, heading), re.S)


@pytest.mark.parametrize(("path", "heading"), SECTIONS, ids=["readme", "reading-a-run", "decisions"])
def test_the_examples_run_as_written_against_a_run_folder(path: Path, heading: str, flown_tiny_run: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    for module in ("pandas", "duckdb", "polars"):  # the `analysis` extra, in `.[test]` too
        pytest.importorskip(module)
    blocks = _python_blocks(path, heading)
    assert blocks, f"{path}: no Python example under {heading!r}"
    for block in blocks:
        assert "runs/mine" in block  # the run folder the examples name
        code = block.replace("runs/mine", str(flown_tiny_run))
        exec(compile(code, f"{path.name}: {heading}", "exec"), {"__name__": "example"})
    out = capsys.readouterr().out
    if "groupby" in "".join(blocks) or "GROUP BY" in "".join(blocks):
        assert "small_quad" in out  # grouped per vehicle: the tiny run's one vehicle is named


@pytest.mark.parametrize(("path", "heading"), SECTIONS[:2], ids=["readme", "reading-a-run"])
def test_every_grouping_of_episodes_names_the_vehicle(path: Path, heading: str) -> None:
    text = "".join(_python_blocks(path, heading))
    groupings = re.findall(r"groupby\(\[([^\]]*)\]\)", text) + re.findall(r"SELECT (.*?) FROM '[^']*episodes",
                                                                          text, re.S)
    assert groupings, f"{path}: no grouping of episodes under {heading!r}"
    assert all("vehicle" in g for g in groupings), groupings
