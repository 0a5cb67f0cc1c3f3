"""The report's "learning in pictures" page: fixed tasks by checkpoints, beside the convergence page."""
from __future__ import annotations

import shutil
from pathlib import Path

from pypdf import PdfReader

from compare.report.learning_pages import chosen_checkpoints, learning_figures
from compare.report.report import build_report
from synthetic_run import write_run


def _texts(pdf: Path) -> list[str]:
    return [p.extract_text() or "" for p in PdfReader(str(pdf)).pages]


def test_checkpoints_spread_from_first_to_last_with_the_kept_one():
    steps = list(range(0, 11_000_001, 1_000_000))  # 0, 1 M, ..., 11 M: 12 recorded
    assert chosen_checkpoints(steps, None) == [0, 3_000_000, 6_000_000, 8_000_000, 11_000_000]
    assert chosen_checkpoints(steps, 9_000_000) == [0, 3_000_000, 6_000_000, 8_000_000, 9_000_000, 11_000_000]
    assert chosen_checkpoints([0, 512], 512) == [0, 512]
    assert chosen_checkpoints(steps, 1234) == chosen_checkpoints(steps, None)  # not recorded: not added


def test_report_shows_the_learning_page_beside_the_convergence_page(tiny_flights_policy, tmp_path):
    policy = tmp_path / "policy"
    shutil.copytree(tiny_flights_policy, policy)
    run_dir = tmp_path / "run"
    write_run(run_dir, policy)  # its own reward curve and provenance; the recorded flights stay
    texts = _texts(build_report(run_dir))
    at = next(i for i, t in enumerate(texts) if "reward convergence" in t)
    page = texts[at + 1]
    assert "Learning in pictures" in page
    for needle in ("0 steps", "512 steps", "1,024 steps", "task 0: short", "task 1: long", "timed out"):
        assert needle in page, needle
    assert (run_dir / "figures" / "learning_in_pictures.png").is_file()


def test_a_policy_without_flights_gets_no_page(tmp_path):
    assert learning_figures(tmp_path) == []
    (tmp_path / "training_flights").mkdir()  # there, but unreadable: one page saying why
    figs = learning_figures(tmp_path)
    assert len(figs) == 1 and "could not be read" in " ".join(t.get_text() for t in figs[0].texts)
