"""Pages that fit: every page of a default-shaped run's report (and its summary report) checked for tables and text
inside the page, page numbers, bookmarks, a headline on page 1 and no machine path; the table layout (split by
columns, continued by rows, wrapped cells); paths shown as the user knows them; 3D paths hidden behind buildings."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from default_shaped_run import write_default_shaped_run
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.table import Table
from pypdf import PdfReader

from compare.report import report as R
from compare.report.flight_figures import Occlusion, draw_path_3d, toward_viewer
from compare.report.layout import (
    PAGE_SIZE_IN,
    WIDTH_SAFETY,
    Heading,
    Paragraph,
    TableBlock,
    flow_pages,
    table_pages,
    text_width_pt,
)
from compare.report.title_page import shown_path
from compare.results.summary import summarize_run, write_summary_json
from synthetic_run import write_benchmark_run
from uam_fdm.city.buildings import Building, BuildingMap

TOLERANCE_PX = 1.0


def _inside(inner, outer, tol: float = TOLERANCE_PX) -> bool:
    return (inner.x0 >= outer.x0 - tol and inner.x1 <= outer.x1 + tol and inner.y0 >= outer.y0 - tol
            and inner.y1 <= outer.y1 + tol)


def layout_problems(fig: Figure) -> list[str]:
    """What crosses the page on `fig`: a table beyond the figure, a cell's text beyond its cell, a figure text
    (title, note, page number) beyond the page. Measured with Agg at the figure's own dpi (only the tables are
    drawn: their cells are placed when drawn)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    page = fig.bbox
    problems = []
    for ax in fig.axes:
        for table in ax.tables:
            assert isinstance(table, Table)
            table.draw(renderer)
            if not _inside(table.get_window_extent(renderer), page):
                problems.append(f"table beyond the page: {table.get_window_extent(renderer)} vs {page}")
            for (r, c), cell in table.get_celld().items():
                text = cell.get_text()
                if text.get_text().strip() and not _inside(text.get_window_extent(renderer),
                                                           cell.get_window_extent(renderer)):
                    problems.append(f"cell ({r}, {c}) {text.get_text()!r} overflows its cell")
    for text in fig.texts:  # the title among them
        if text.get_text().strip() and not _inside(text.get_window_extent(renderer), page):
            problems.append(f"text beyond the page: {text.get_text()[:60]!r}")
    return problems


def pdf_text_beyond_page(pdf: Path) -> list[tuple[int, str]]:
    """(page, text) of every horizontal text run of the PDF that starts left of the page or ends right of it (its
    end from the font's advances), read from the PDF itself."""
    out = []
    for k, page in enumerate(PdfReader(pdf).pages):
        width = float(page.mediabox.width)

        def visit(text, cm, tm, _font, size, k=k, width=width):
            a, b, c = (tm[0] * cm[0] + tm[1] * cm[2], tm[0] * cm[1] + tm[1] * cm[3],
                       tm[2] * cm[0] + tm[3] * cm[2])
            if not text.strip() or abs(b) > 1e-6 or abs(c) > 1e-6 or a <= 0:  # horizontal text only
                return
            x = tm[4] * cm[0] + tm[5] * cm[2] + cm[4]
            end = x + text_width_pt(text.rstrip(), size * a) / WIDTH_SAFETY  # the advances: the PDF's own width
            if x < -0.5 or end > width + 2.0:
                out.append((k + 1, text.strip()))

        page.extract_text(visitor_text=visit)
    return out


def _check_every_page(mp: pytest.MonkeyPatch, problems: list[str]) -> None:
    """While `mp` holds, every page the report writes is checked (`layout_problems`) into `problems`."""
    add = R._PageWriter.add

    def checked(self, fig, name, *args, **kwargs):
        problems.extend(f"{name}: {p}" for p in layout_problems(fig))
        add(self, fig, name, *args, **kwargs)

    mp.setattr(R._PageWriter, "add", checked)


# ---- every page of a default-shaped run ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def default_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[str], Path]:
    """The run folder, its report (every page's layout checked as it is written), its pages' text and its summary
    report."""
    run_dir = tmp_path_factory.mktemp("default") / "run"
    write_default_shaped_run(run_dir)
    problems: list[str] = []
    with pytest.MonkeyPatch.context() as mp:
        _check_every_page(mp, problems)
        pdf = R.build_report(run_dir)
        summary = R.build_report(run_dir, summary=True)
    assert problems == []
    return run_dir, pdf, [p.extract_text() or "" for p in PdfReader(pdf).pages], summary


def test_no_table_or_text_crosses_the_page_edge(default_run):
    _, pdf, _, summary = default_run
    assert pdf_text_beyond_page(pdf) == []
    assert pdf_text_beyond_page(summary) == []


def test_a_benchmark_quick_shaped_report_fits_its_pages(tmp_path: Path):
    """The benchmark-quick shape (2 vehicles x 6 scenarios x 3 legs, the three pilots, its difficulty pages): every
    page's tables and texts inside the page (few flights drawn: their pages' layout does not depend on how many)."""
    run_dir = tmp_path / "run"
    rows = write_benchmark_run(run_dir, scenarios_per_vehicle=6, episodes=3, seeds=(0,), samples=60,
                               pilots={"ppo": "PPO policy", "rrt_mpc": "RRT* + MPC", "apf": "Potential field"})
    write_summary_json(summarize_run(rows, resamples=200), run_dir / "summary.json")
    problems: list[str] = []
    with pytest.MonkeyPatch.context() as mp:
        _check_every_page(mp, problems)
        mp.setattr(R, "DRAWN_SCENARIOS_PER_VEHICLE", 1)
        mp.setattr(R, "DRAWN_FLIGHTS_PER_SCENARIO", 1)
        pdf = R.build_report(run_dir)
    assert problems == []
    assert pdf_text_beyond_page(pdf) == []


def test_the_tracker_table_shows_every_column_and_note(default_run):
    _, _, texts, _ = default_run
    page = " ".join(next(t for t in texts if "tracker per scenario" in t).split())
    for column in ("scenario", "episodes", "plan attempts", "replans", "solve"):
        assert column in page, column
    for name in ("downtown-quad", "suburb-quad", "suburb-uam"):
        assert name in page
    assert "Solve: median of the episodes' medians, largest episode p95. Failures and replans: summed over the " \
           "episodes." in page  # the last note, whole


def test_page_one_holds_the_headline_and_no_machine_path(default_run):
    run_dir, pdf, texts, _ = default_run
    first = texts[0].replace("\n", " ")
    assert "uam-compare report" in first
    for needle in ("Per vehicle and pilot: success and collisions, mean [Wilson 95 % interval]", "small_quad",
                   "uam_multicopter", "PPO policy", "RRT* + MPC", "Paired differences on the same tasks",
                   "100 [57, 100]", "0 [0, 43]", "n/a (n < 10)"):
        assert needle in first, needle
    whole = "\n".join(texts)
    root = str(Path(__file__).resolve().parents[3])
    for machine in (str(run_dir), str(run_dir.parent), root):
        assert machine not in whole.replace("\n", ""), machine
    assert "compare/scenarios/default/suburb-uam.yaml (shipped)" in whole.replace("\n", " ")
    assert "rl/policies/uam (shipped)" in whole.replace("\n", " ")
    assert "uam-compare report" not in texts[1] or "About this run" in texts[1]


def test_every_page_is_numbered_and_the_sections_are_bookmarked(default_run):
    _, pdf, texts, summary = default_run
    assert all(f"page {k + 1}" in t for k, t in enumerate(texts))
    reader = PdfReader(pdf)
    top = [item.title for item in reader.outline if not isinstance(item, list)]
    assert top[:4] == ["uam-compare report", "About this run", "small_quad", "uam_multicopter"]
    assert {"Metrics: the RRT* + MPC tracker per scenario", "Flights", "Training", "Failures"} <= set(top)
    children = [item for item in reader.outline if isinstance(item, list)]
    assert any(c.title == "small_quad: paired differences" for group in children for c in group)
    for item in reader.outline:  # every entry leads to the page whose title it bears
        if not isinstance(item, list) and item.title not in ("small_quad", "uam_multicopter", "Flights", "Training",
                                                              "Failures"):
            assert item.title in texts[reader.get_destination_page_number(item)]
    assert reader.page_mode == "/UseOutlines"
    short = PdfReader(summary)
    assert len(short.pages) <= 8 and len(short.pages) < len(texts) / 4
    assert [i.title for i in short.outline if not isinstance(i, list)][:2] == ["uam-compare report", "About this run"]


def test_the_report_of_twelve_episodes_says_they_are_few(default_run):
    _, _, texts, _ = default_run
    whole = " ".join(t.replace("\n", " ") for t in texts)
    assert "(n=5, no CI)" in whole and "(n=1, no CI)" in whole  # a mean of 5 and of 1 episode: no interval
    assert "[21.83, 21.83]" not in whole and "0 (no spread)" not in whole
    assert "n/a (every pair agreed)" in whole and "n/a (fewer than 10 pairs)" in whole


# ---- the table layout ---------------------------------------------------------------------------------------
def _cells(fig: Figure) -> list[list[str]]:
    """The rows of the tables of a page, top to bottom, each row's cell texts left to right."""
    rows = []
    for ax in fig.axes:
        for table in ax.tables:
            cells = table.get_celld()
            for r in sorted({r for r, _ in cells}):
                rows.append([cells[r, c].get_text().get_text() for c in sorted(c for rr, c in cells if rr == r)])
    return rows


def test_a_wide_table_splits_by_columns_and_repeats_its_row_names():
    header = ["scenario", "pilot"] + [f"a long metric column {k} [unit]" for k in range(14)]
    rows = [[f"scenario-{r}", "RRT* + MPC"] + [f"{r * k:.3f} [{k:.2f}, {r + k:.2f}]" for k in range(14)]
            for r in range(3)]
    figs = table_pages("Wide", header, rows, keep_columns=2)
    cells = [row for fig in figs for row in _cells(fig)]
    assert all(not layout_problems(fig) for fig in figs)
    headers = [row for row in cells if row[0] == "scenario"]
    assert len(headers) >= 2 and all(row[1] == "pilot" for row in headers)  # each part names its rows
    shown = {" ".join(c.split()) for row in headers for c in row[2:]}
    assert shown == {h for h in header[2:]}  # every column once, none lost
    assert sum(row[0] == "scenario-2" for row in cells) == len(headers)


def test_a_long_table_continues_with_its_header_and_notes_on_every_page():
    rows = [[f"s{r}", str(r)] for r in range(120)]
    figs = table_pages("Long", ["scenario", "episodes"], rows, notes=["What the cells mean."])
    assert len(figs) >= 3
    firsts = [_cells(fig)[0] for fig in figs]
    assert all(row == ["scenario", "episodes"] for row in firsts)
    body = [row[0] for fig in figs for row in _cells(fig)[1:]]
    assert body == [f"s{r}" for r in range(120)]
    assert all(any(t.get_text() == "What the cells mean." for t in fig.texts) for fig in figs)
    assert figs[1].get_suptitle() == "Long (continued)"
    assert all(not layout_problems(fig) for fig in figs)


def test_a_cell_too_wide_for_any_page_wraps_and_text_wraps_to_the_page():
    long = "a failure detail that goes on " * 12 + "and_one_word_longer_than_any_column_could_ever_hold_" * 3
    figs = flow_pages("Mixed", [Heading("Heading"), Paragraph("word " * 400),
                                TableBlock(("scenario", "detail"), (("s", long),), keep_columns=1)])
    assert all(not layout_problems(fig) for fig in figs)
    (cell,) = [row[1] for fig in figs for row in _cells(fig) if row[0] == "s"]
    assert cell.count("\n") >= 2 and cell.replace("\n", "").replace(" ", "") == long.replace(" ", "")


@pytest.mark.parametrize("dpi", [100, R.PNG_DPI])
def test_measured_widths_hold_what_matplotlib_draws(dpi):
    """The measure is never narrower than the text drawn, at the figures' dpi and the PNG copies' (hinting widens
    text there), and not much wider."""
    fig = Figure(figsize=PAGE_SIZE_IN, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    for text, size, weight in (("21.83 (n=1, no CI)", 8.5, "normal"), ("plan attempts max / >1", 8.5, "bold"),
                               ("Wide WWW text, iiii", 12.0, "normal"), ("1111111111 lllll", 7.5, "bold")):
        t = fig.text(0.1, 0.5, text, fontsize=size, fontweight=weight)
        canvas.draw()
        drawn_pt = t.get_window_extent(canvas.get_renderer()).width * 72.0 / fig.dpi
        assert drawn_pt <= text_width_pt(text, size, weight) <= 1.2 * drawn_pt, text


# ---- paths as the user knows them ---------------------------------------------------------------------------
def test_shown_path_never_shows_the_machine_that_made_the_run(tmp_path):
    run_dir = tmp_path / "runs" / "mine"
    root = Path(__file__).resolve().parents[3]
    assert shown_path(str(run_dir / "maps" / "a.yaml"), run_dir) == "maps/a.yaml"
    # a shipped file, recorded on another machine's checkout
    assert shown_path("/home/someone/uam/compare/scenarios/default/suburb-uam.yaml", run_dir) == \
        "compare/scenarios/default/suburb-uam.yaml (shipped)"
    assert shown_path(str(root / "rl" / "policies" / "uam"), run_dir) == "rl/policies/uam (shipped)"
    # as typed on the command line (the longest argument that ends like it)
    command = "uam-compare run scenarios/my.yaml --policy runs/robust --out runs/mine"
    assert shown_path("/home/someone/work/scenarios/my.yaml", run_dir, command) == "scenarios/my.yaml"
    assert shown_path("/home/someone/work/runs/robust", run_dir, command) == "runs/robust"
    # else relative to the run folder
    assert shown_path(str(tmp_path / "data" / "city.geojson"), run_dir) == "../../data/city.geojson"
    assert shown_path("relative/as/given.yaml", run_dir) == "relative/as/given.yaml" and shown_path("", run_dir) == ""


# ---- 3D views: buildings in front of paths --------------------------------------------------------------------
def test_a_path_behind_a_building_is_hidden_and_drawn_dotted():
    tower = BuildingMap([Building(0, (50.0, 50.0), (10.0, 10.0), 60.0)], (0.0, 0.0, 0.0), (100.0, 100.0, 80.0))
    occ = Occlusion(tower)
    toward = toward_viewer()
    assert toward[2] > 0 and np.isclose(np.linalg.norm(toward), 1.0)
    behind = np.array([50.0, 50.0, 10.0]) - 12.0 * np.array([toward[0], toward[1], 0.0]) / math.hypot(*toward[:2])
    in_front = np.array([50.0, 50.0, 10.0]) + 12.0 * np.array([toward[0], toward[1], 0.0]) / math.hypot(*toward[:2])
    above = np.array([50.0, 50.0, 75.0])
    assert list(occ.hidden(np.array([behind, in_front, above]))) == [True, False, False]
    assert not Occlusion(None).hidden(np.array([behind])).any()
    # a straight path passing behind the tower: solid where seen, dotted where hidden, meeting at the edges
    path = np.linspace(behind - [40.0, -25.0, 0.0], behind + [40.0, -25.0, 0.0], 201)
    hidden = occ.hidden(path)
    assert hidden.any() and not hidden.all()
    ax = Figure().add_subplot(projection="3d")
    draw_path_3d(ax, path, hidden, "tab:blue", 1.5)
    dotted, solid = ax.get_lines()
    assert dotted.get_linestyle() == ":" and solid.get_linestyle() == "-"
    seen_x = np.asarray(solid.get_data_3d()[0])
    assert np.array_equal(np.isfinite(seen_x)[~hidden], np.ones(int((~hidden).sum()), bool))
    assert not np.isfinite(seen_x[hidden]).any()
