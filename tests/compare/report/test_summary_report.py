"""`uam-compare report RUN_DIR --summary`: the run rescored and a report of a few pages written beside the full one,
numbered and bookmarked, its numbers those the command prints."""
from __future__ import annotations

import json
from pathlib import Path

from pypdf import PdfReader

from compare.cli import main
from compare.report.report import SUMMARY_NAME
from synthetic_run import write_run


def test_report_summary_writes_a_short_report_and_prints_the_results(tmp_path: Path, capsys) -> None:
    run_dir = tmp_path / "run"
    write_run(run_dir, None)
    assert main(["report", str(run_dir), "--summary"]) == 0
    out = capsys.readouterr().out.splitlines()
    pdf = run_dir / SUMMARY_NAME
    assert str(pdf) in out and not (run_dir / "report.pdf").exists()  # the full report is not rebuilt
    reader = PdfReader(pdf)
    texts = [p.extract_text() or "" for p in reader.pages]
    assert 4 <= len(texts) <= 6  # headline, the run, the pilots' table, paired differences, failures
    assert all(f"page {k + 1}" in t for k, t in enumerate(texts))
    assert "This is the summary report" in texts[0].replace("\n", " ")
    assert [i.title for i in reader.outline if not isinstance(i, list)] == [
        "uam-compare report", "About this run", "small_quad", "Failures"]
    headline = json.loads(out[-1])  # the numbers the command prints are the report's
    success = headline["vehicles"]["small_quad"]["ppo"]["success"]
    cell = f"{100 * success['rate']:.0f} [{100 * success['ci95'][0]:.0f}, {100 * success['ci95'][1]:.0f}]"
    assert cell in texts[0]
    assert not (run_dir / "figures").exists()  # a summary writes no PNG pages
