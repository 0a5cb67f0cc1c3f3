"""Writing the report's pages: each figure into the PDF with its page number (and as a PNG), the outline of
sections recorded as pages are added, then written into the PDF with pypdf (matplotlib's PdfPages has none)."""
from __future__ import annotations

import io
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from pypdf import PdfWriter

from compare.report.layout import FOOTER_IN
from uam_fdm.city.plot import missing_glyphs_unsaid, save_figure

PNG_DPI = 130
"""Resolution of the pages' PNG copies [dots per inch]."""


class PageWriter:
    """Adds figures to the PDF, each with its page number, saves each as a PNG (unless `fig_dir` is None), then
    releases it; records the outline: (section, title, page index) of each group's first page."""

    def __init__(self, pdf: PdfPages, fig_dir: Path | None, run_dir: Path | None = None, dpi: int = PNG_DPI) -> None:
        self.pdf, self.fig_dir, self.run_dir, self.count = pdf, fig_dir, run_dir, 0  # run_dir: no link in it followed
        self.dpi = dpi
        self.outline: list[tuple[str, str, int]] = []
        self.written: set[str] = set()

    def add(self, fig: Figure, name: str, section: str = "", *, bookmark: bool = True) -> None:
        """Add one page (`bookmark`: with an outline entry, under `section`'s; empty: a top-level entry)."""
        if bookmark:
            title = re.sub(r" \(continued\)$", "", fig.get_suptitle()) or section or f"page {self.count + 1}"
            self.outline.append((section, title, self.count))
        engine = fig.get_layout_engine()
        if isinstance(engine, ConstrainedLayoutEngine):  # a laid-out page keeps clear of the number's band
            band = FOOTER_IN / fig.get_figheight()
            engine.set(rect=(0.0, band, 1.0, 1.0 - band))
        fig.text(1.0 - 0.3 / fig.get_figwidth(), 0.12 / fig.get_figheight(), f"page {self.count + 1}",
                 ha="right", va="bottom", fontsize=8, color="0.3")
        if self.fig_dir is not None:
            path = save_figure(fig, self.fig_dir / f"{_slug(name)}.png", dpi=self.dpi, root=self.run_dir)
            self.written.add(path.name)
        with missing_glyphs_unsaid():
            self.pdf.savefig(fig)
        fig.clear()  # Figure-API figures are not registered with pyplot: clearing frees their artists
        self.count += 1

    def remove_stale_pngs(self) -> None:
        """Delete the PNGs of `fig_dir` this report did not write (pages of an earlier report of the folder, which
        no longer match it); files only, no link followed."""
        d = self.fig_dir
        if d is None or d.is_symlink() or not d.is_dir():
            return
        for path in d.glob("*.png"):
            if path.name not in self.written and path.is_file() and not path.is_symlink():
                path.unlink()

    def add_all(self, figs: Sequence[Figure], name: str, section: str = "") -> None:
        """Add pages (one group: one outline entry, at the first)."""
        for k, fig in enumerate(figs):
            self.add(fig, name if len(figs) == 1 else f"{name}_{k + 1}", section, bookmark=k == 0)


def add_outline(pdf_path: Path, outline: Sequence[tuple[str, str, int]]) -> None:
    """Give the PDF at `pdf_path` its outline (bookmarks, shown when it opens): one entry per section at its first
    page, and under it one per page group titled as its page; rewritten in place.

    Args:
        outline: (section, title, page index) in page order; an empty section makes the group a top-level entry.
    """
    writer = PdfWriter(clone_from=io.BytesIO(Path(pdf_path).read_bytes()))
    sections: dict[str, Any] = {}
    for section, title, page in outline:
        parent = None
        if section:
            if section not in sections:
                sections[section] = writer.add_outline_item(title=section, page_number=page)
            parent = sections[section]
            if title == section:
                continue
        writer.add_outline_item(title=title, page_number=page, parent=parent)
    writer.page_mode = "/UseOutlines"
    with open(pdf_path, "wb") as f:
        writer.write(f)


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)
