"""Pages of text and tables that fit their page: measured, wrapped, split and paginated before anything is drawn.

A page is A4 landscape (`PAGE_SIZE_IN`) with a title at the top, a band at the bottom kept free for the page
number (`FOOTER_IN`, drawn by the report's page writer) and, above it, notes repeated on every page. In between,
`flow_pages` lays out blocks top to bottom: headings, paragraphs (wrapped to the page's width by the font's own
glyph advances) and tables. A table is measured cell by cell; one wider than the page is split by columns into
parts that each repeat its first `keep_columns` columns (its row names), and a cell that cannot fit even then is
wrapped; a table longer than the page continues on the next one with its header repeated; content that would
leave a last page nearly blank is set a little smaller when that saves the page. Nothing is clipped:
every table is a `matplotlib.table.Table` whose cells sit inside the page by construction.

Measuring text without drawing it: `text_width_pt` sums the font's unhinted advances (kerning left out, which
only narrows text) and adds `WIDTH_SAFETY` for the PNG copies' hinting; a column is as wide as its widest cell plus
padding.
"""
from __future__ import annotations

import dataclasses
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties, findfont, get_font
from matplotlib.table import Table
from matplotlib.transforms import Bbox

PAGE_SIZE_IN = (11.69, 8.27)
"""A4 landscape [inch]."""
MARGIN_IN = 0.45
"""Left and right margin of text and tables [inch]."""
TITLE_IN = 0.85
"""From the page's top edge to where the content starts, below the title [inch]."""
FOOTER_IN = 0.38
"""Band at the bottom of every page kept free for the page number [inch]."""
WIDTH_SAFETY = 1.08
"""Measured widths are enlarged by this factor: the sum of the unhinted advances is the PDF's width; a PNG drawn with
hinting at 100-130 dpi is up to 7.6 % wider (digits and narrow letters round up to whole pixels)."""
LINE_SPACING = 1.25
"""Height of a text line in units of its font size."""
CELL_VPAD = 0.28
"""Space above and below a cell's text, in units of its font size."""
SPILL_FRACTION = 0.3
MIN_SCALE = 0.8
"""Content that spills onto a last page filled to `SPILL_FRACTION` or less is set smaller, down to `MIN_SCALE` of
its size, when that keeps it off that page."""
HEADER_MIN_IN = 0.85
"""A column header wraps to its cells' width, but never narrower than this (nor than its longest word) [inch]."""
TITLE_SIZE = 15.0
NOTE_SIZE = 8.0


# ---- measuring text ---------------------------------------------------------------------------------------
_ADVANCE_EM: dict[tuple[str, str], float] = {}


def _font_file(weight: str, style: str) -> str:
    return str(findfont(FontProperties(weight=weight, style=cast(Any, style))))


def text_width_pt(text: str, size: float, weight: str = "normal", style: str = "normal") -> float:
    """Width of one line of `text` in the default font at `size` points [pt], including `WIDTH_SAFETY`."""
    path = _font_file(weight, style)
    total = 0.0
    for ch in text:
        key = (path, ch)
        em = _ADVANCE_EM.get(key)
        if em is None:
            font = get_font(path)
            font.set_size(100.0, 72.0)  # 100 px per em: the linear advance in 1/65536 px, unhinted
            em = font.load_char(ord(ch)).linearHoriAdvance / 65536.0 / 100.0
            _ADVANCE_EM[key] = em
        total += em
    return total * size * WIDTH_SAFETY


def wrap_to_width(text: str, width_pt: float, size: float, weight: str = "normal", style: str = "normal",
                  indent_pt: float = 0.0) -> list[str]:
    """`text` broken into lines no wider than `width_pt` (words kept whole where they fit; a longer word is cut).

    Explicit line breaks in `text` are kept; lines after the first of each paragraph may be narrower by
    `indent_pt` (a hanging indent, drawn by the caller).
    """
    lines: list[str] = []
    for para in text.split("\n"):
        line = ""
        for word in para.split():
            room = width_pt - (indent_pt if lines else 0.0)  # every line but the very first hangs
            candidate = f"{line} {word}" if line else word
            if text_width_pt(candidate, size, weight, style) <= room:
                line = candidate
                continue
            if line:
                lines.append(line)
                line, room = "", width_pt - indent_pt
            while text_width_pt(word, size, weight, style) > room and len(word) > 1:
                cut = _longest_prefix(word, room, size, weight, style)
                lines.append(word[:cut])
                word, room = word[cut:], width_pt - indent_pt
            line = word
        lines.append(line)
    return lines


def _longest_prefix(word: str, room_pt: float, size: float, weight: str, style: str) -> int:
    """Characters of `word` that fit in `room_pt` (at least one)."""
    lo, hi = 1, len(word)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if text_width_pt(word[:mid], size, weight, style) <= room_pt:
            lo = mid
        else:
            hi = mid - 1
    return lo


def _line_in(size: float) -> float:
    return size * LINE_SPACING / 72.0


# ---- blocks -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Heading:
    """A bold line; kept on the page of what follows it."""

    text: str
    size: float = 11.5


@dataclass(frozen=True)
class Paragraph:
    """Text wrapped to the page; leading spaces indent it, wrapped lines hang `hanging_in` further in."""

    text: str
    size: float = 9.5
    style: str = "normal"
    weight: str = "normal"
    hanging_in: float = 0.25


@dataclass(frozen=True)
class TableBlock:
    """A table: header and rows of cell texts; split by columns when wider than the page, each part repeating
    the first `keep_columns` columns; `caption` (optional) is printed above it, and above each part."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    font_size: float = 8.5
    keep_columns: int = 1
    caption: str = ""


@dataclass(frozen=True)
class Gap:
    """Vertical space [inch] (dropped at the top of a page)."""

    height_in: float = 0.12


Block = Heading | Paragraph | TableBlock | Gap


def as_blocks(items: Sequence[tuple[str, str]]) -> list[Block]:
    """("h", heading) / ("p", paragraph) items as blocks, a small gap before each heading."""
    out: list[Block] = []
    for kind, text in items:
        out += [Gap(), Heading(text)] if kind == "h" else [Paragraph(text)]
    return out


# ---- laying out -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Line:
    """One line of text to draw at the left edge + `x_in`."""

    text: str
    size: float
    weight: str = "normal"
    style: str = "normal"
    x_in: float = 0.0
    keep_with_next: bool = False

    @property
    def height_in(self) -> float:
        return _line_in(self.size)


@dataclass(frozen=True)
class _Cells:
    """One row of one part of a table (its header when `header`), with the part's column widths; `repeat`: what a
    page that continues the part starts with (its caption lines and header)."""

    texts: tuple[tuple[str, ...], ...]
    widths_in: tuple[float, ...]
    heights_in: tuple[float, ...]
    font_size: float
    header: bool
    repeat: tuple[_Line | _Cells, ...] = ()

    @property
    def height_in(self) -> float:
        return sum(self.heights_in)


@dataclass(frozen=True)
class _Space:
    height_in: float


_Item = _Line | _Cells | _Space


def content_width_in() -> float:
    """Width of the text column [inch]."""
    return PAGE_SIZE_IN[0] - 2.0 * MARGIN_IN


def _paragraph_lines(p: Paragraph | Heading, width_in: float) -> list[_Line]:
    if isinstance(p, Heading):
        return [_Line(line, p.size, "bold", keep_with_next=True)
                for line in wrap_to_width(p.text, 72.0 * width_in, p.size, "bold")]
    body = p.text.lstrip(" ")
    lead_in = text_width_pt(p.text[:len(p.text) - len(body)], p.size) / 72.0
    lines = wrap_to_width(body, 72.0 * (width_in - lead_in), p.size, p.weight, p.style, 72.0 * p.hanging_in)
    return [_Line(line, p.size, p.weight, p.style, lead_in + (p.hanging_in if k else 0.0))
            for k, line in enumerate(lines)]


def footer_lines(notes: Sequence[str], width_in: float | None = None) -> list[_Line]:
    """Notes under the content of every page, wrapped to the text column (small italic)."""
    width = content_width_in() if width_in is None else width_in
    return [line for n in notes for line in _paragraph_lines(Paragraph(n, NOTE_SIZE, "italic", hanging_in=0.0),
                                                             width)]


def _pad_pt(size: float) -> float:
    return 0.55 * size


def _cell_lines(text: str) -> list[str]:
    return str(text).split("\n")


def _natural_width_in(text: str, size: float, weight: str) -> float:
    return (max(text_width_pt(s, size, weight) for s in _cell_lines(text)) + 2.0 * _pad_pt(size)) / 72.0


def _wrapped_cell(text: str, width_in: float, size: float, weight: str) -> str:
    room = 72.0 * width_in - 2.0 * _pad_pt(size)
    return "\n".join(line for s in _cell_lines(text) for line in wrap_to_width(s, room, size, weight))


def _table_parts(t: TableBlock, width_in: float) -> list[tuple[list[int], list[list[str]], list[float]]]:
    """The table split by columns to fit `width_in`: per part its column indices, its cell texts (header row
    first, wrapped where needed) and its column widths [inch]."""
    n_cols = len(t.header)
    rows = [list(t.header)] + [list(r) + [""] * (n_cols - len(r)) for r in t.rows]
    size = t.font_size

    def body_width(c: int) -> float:
        return max((_natural_width_in(r[c], size, "normal") for r in rows[1:]), default=0.0)

    # a header wider than its column's cells wraps, at its longest word at least
    for c in range(n_cols):
        words = max((text_width_pt(w, size, "bold") for w in rows[0][c].split()), default=0.0)
        natural = _natural_width_in(rows[0][c], size, "bold")
        target = max(body_width(c), (words + 2.0 * _pad_pt(size)) / 72.0, min(natural, HEADER_MIN_IN))
        if natural > target:
            rows[0][c] = _wrapped_cell(rows[0][c], target, size, "bold")
    widths = [max(_natural_width_in(r[c], size, "bold" if k == 0 else "normal") for k, r in enumerate(rows))
              for c in range(n_cols)]
    # where the page has room, wrapped headers take fewer lines again: whole, those that need least room first,
    # then the rest share what is left
    whole = {c: max(_natural_width_in(t.header[c], size, "bold"), widths[c]) for c in range(n_cols)
             if "\n" in rows[0][c]}
    for c in sorted(whole, key=lambda c: whole[c] - widths[c]):
        if sum(widths) - widths[c] + whole[c] <= width_in:
            rows[0][c], widths[c] = t.header[c], whole[c]
    still = [c for c in whole if "\n" in rows[0][c]]
    spare = width_in - sum(widths)
    if still and spare > 0.05:
        for c in still:
            wider = min(widths[c] + spare / len(still), whole[c])
            rows[0][c] = _wrapped_cell(t.header[c], wider, size, "bold")
            widths[c] = max(widths[c], _natural_width_in(rows[0][c], size, "bold"))
    keep = list(range(min(max(t.keep_columns, 0), n_cols - 1)))
    while keep and sum(widths[c] for c in keep) > 0.45 * width_in:  # row names may not crowd out the data
        keep.pop()
    parts: list[list[int]] = []
    current: list[int] = list(keep)
    for c in range(len(keep), n_cols):
        if current != keep and sum(widths[i] for i in current) + widths[c] > width_in:
            parts.append(current)
            current = list(keep)
        current.append(c)
    parts.append(current)
    out = []
    for cols in parts:
        spare = width_in - sum(widths[c] for c in cols)
        part_widths = {c: widths[c] for c in cols}
        if spare < 0.0:  # one column too wide even beside the row names alone: its cells wrap
            widest = max((c for c in cols if c not in keep), key=lambda c: widths[c])
            part_widths[widest] = widths[widest] + spare
        texts = [[r[c] if part_widths[c] >= widths[c] else _wrapped_cell(r[c], part_widths[c], size,
                                                                          "bold" if k == 0 else "normal")
                  for c in cols] for k, r in enumerate(rows)]
        out.append((cols, texts, [part_widths[c] for c in cols]))
    return out


def _table_items(t: TableBlock, width_in: float) -> list[list[_Item]]:
    """Per column part: its caption line, then its header row and body rows as one-row `_Cells` each."""
    parts = _table_parts(t, width_in)
    size = t.font_size
    out = []
    for k, (cols, texts, widths) in enumerate(parts):
        items: list[_Item] = []
        caption = t.caption
        if len(parts) > 1:
            kept = ", ".join(t.header[c] for c in cols[:t.keep_columns] if c < t.keep_columns)
            split = f"part {k + 1} of {len(parts)} (split by columns to fit the page"
            split += f"; {kept} repeated)" if kept else ")"
            caption = f"{caption}: {split}" if caption else split[0].upper() + split[1:]
        captions = [_Line(line.text, size + 0.5, "bold", x_in=line.x_in, keep_with_next=True)
                    for line in _paragraph_lines(Paragraph(caption, size + 0.5, hanging_in=0.0), width_in)
                    ] if caption else []
        items += captions
        header: _Cells | None = None
        for r, row in enumerate(texts):
            lines = max(len(_cell_lines(s)) for s in row)
            height = lines * _line_in(size) + 2.0 * CELL_VPAD * size / 72.0
            cells = _Cells((tuple(row),), tuple(widths), (height,), size, header=r == 0,
                           repeat=() if header is None else (*captions, header))
            header = header or cells
            items.append(cells)
        out.append(items)
    return out


def _items(blocks: Sequence[Block], width_in: float) -> list[_Item]:
    items: list[_Item] = []
    for b in blocks:
        if isinstance(b, Gap):
            items.append(_Space(b.height_in))
        elif isinstance(b, TableBlock):
            for k, part in enumerate(_table_items(b, width_in)):
                if k:
                    items.append(_Space(0.12))
                items += part
            items.append(_Space(0.1))
        else:
            items += _paragraph_lines(b, width_in)
    return items


def _paginate(items: list[_Item], height_in: float) -> list[list[_Item]]:
    """Items per page: a heading or caption never ends a page, nor a table's header without its first row; a
    table row that starts a page brings its part's caption and header along; space at a page's top is dropped."""
    units: list[list[_Item]] = []
    i = 0
    while i < len(items):
        unit = [items[i]]
        while i + 1 < len(items) and (isinstance(unit[-1], _Line) and unit[-1].keep_with_next
                                      or isinstance(unit[-1], _Cells) and unit[-1].header):
            i += 1
            unit.append(items[i])
        units.append(unit)
        i += 1
    pages: list[list[_Item]] = [[]]
    used = 0.0
    for unit in units:
        if used + sum(u.height_in for u in unit) > height_in and pages[-1]:
            pages.append([])
            used = 0.0
            first = unit[0]
            if isinstance(first, _Cells) and first.repeat:
                pages[-1] += list(first.repeat)
                used += sum(r.height_in for r in first.repeat)
        for item in unit:
            if isinstance(item, _Space) and not pages[-1]:
                continue
            pages[-1].append(item)
            used += item.height_in
    return pages


# ---- drawing ----------------------------------------------------------------------------------------------
def _draw_line(fig: Figure, line: _Line, y_in: float) -> None:
    w, h = PAGE_SIZE_IN
    fig.text((MARGIN_IN + line.x_in) / w, 1.0 - y_in / h, line.text, fontsize=line.size, fontweight=line.weight,
             style=line.style, va="top", ha="left")


def _draw_cells(fig: Figure, rows: list[_Cells], y_in: float) -> None:
    """Consecutive rows of one table part as one `Table`, in an axes exactly its size, top at `y_in`."""
    w, h = PAGE_SIZE_IN
    widths = rows[0].widths_in
    total_w, total_h = sum(widths), sum(r.height_in for r in rows)
    ax = fig.add_axes((MARGIN_IN / w, 1.0 - (y_in + total_h) / h, total_w / w, total_h / h))
    ax.axis("off")
    table = Table(ax, bbox=Bbox.from_bounds(0.0, 0.0, 1.0, 1.0))  # the cells fill the axes
    size = rows[0].font_size
    r = 0
    for block in rows:
        for texts, height in zip(block.texts, block.heights_in):
            for c, (text, width) in enumerate(zip(texts, widths)):
                cell = table.add_cell(r, c, width=width, height=height, text=text, loc="left",
                                      facecolor="0.9" if block.header else "white", edgecolor="0.4")
                cell.set_linewidth(0.5)
                cell.PAD = _pad_pt(size) / 72.0 / width
                cell.get_text().set_fontsize(size)
                if block.header:
                    cell.get_text().set_fontweight("bold")
            r += 1
    table.auto_set_font_size(False)
    ax.add_table(table)


def _page_figure(title: str) -> Figure:
    fig = Figure(figsize=PAGE_SIZE_IN)
    # drawn first (below the axes' zorder 0): a PDF's text then reads title, tables, the rest, as a reader does
    fig.suptitle(title, fontsize=TITLE_SIZE, fontweight="bold", y=1.0 - 0.35 / PAGE_SIZE_IN[1], va="top", zorder=-1)
    return fig


def flow_pages(title: str, blocks: Sequence[Block], *, notes: Sequence[str] = ()) -> list[Figure]:
    """Pages holding `blocks` top to bottom under `title` ("(continued)" after the first), `notes` at the
    bottom of each.

    Args:
        title: the page title (shortened to fit the page's width).
        blocks: headings, paragraphs, tables and gaps, in order.
        notes: lines repeated at the bottom of every page (wrapped), e.g. what a table's cells mean.
    """
    width = content_width_in()
    foot = footer_lines(notes, width)
    foot_h = sum(f.height_in for f in foot) + (0.1 if foot else 0.0)
    height = PAGE_SIZE_IN[1] - TITLE_IN - FOOTER_IN - foot_h
    pages = _fewest_pages(blocks, width, height)
    figs = []
    for k, page in enumerate(pages):
        head = title if k == 0 else f"{title} (continued)"
        fig = _page_figure(fit_title(head))
        y = TITLE_IN
        run: list[_Cells] = []
        for item in page + [_Space(0.0)]:
            if isinstance(item, _Cells) and (not run or item.widths_in == run[0].widths_in) and not (
                    item.header and run):
                run.append(item)
                continue
            if run:
                _draw_cells(fig, run, y)
                y += sum(r.height_in for r in run)
                run = []
            if isinstance(item, _Cells):
                run = [item]
            elif isinstance(item, _Line):
                _draw_line(fig, item, y)
                y += item.height_in
            else:
                y += item.height_in
        y = PAGE_SIZE_IN[1] - FOOTER_IN - foot_h + 0.1
        for line in foot:
            _draw_line(fig, line, y)
            y += line.height_in
        figs.append(fig)
    return figs


def _fewest_pages(blocks: Sequence[Block], width_in: float, height_in: float) -> list[list[_Item]]:
    """The blocks paginated; when the last page would hold little (`SPILL_FRACTION` of a page or less), set a little
    smaller (down to `MIN_SCALE` of their size), if that saves the page: no page is left nearly blank."""
    pages = _paginate(_items(blocks, width_in), height_in)
    if len(pages) < 2 or sum(item.height_in for item in pages[-1]) > SPILL_FRACTION * height_in:
        return pages
    for scale in (0.95, 0.9, 0.85, MIN_SCALE):
        fewer = _paginate(_items([_scaled(b, scale) for b in blocks], width_in), height_in)
        if len(fewer) < len(pages):
            return fewer
    return pages


def _scaled(block: Block, scale: float) -> Block:
    """A block with its font `scale` times as large (a gap as high)."""
    if isinstance(block, Gap):
        return Gap(block.height_in * scale)
    if isinstance(block, TableBlock):
        return dataclasses.replace(block, font_size=block.font_size * scale)
    return dataclasses.replace(block, size=block.size * scale)


def fit_title(title: str, size: float = TITLE_SIZE) -> str:
    """`title` shortened with an ellipsis to fit the page's width in bold at `size`."""
    room = 72.0 * content_width_in()
    if text_width_pt(title, size, "bold") <= room:
        return title
    return textwrap.shorten(title, max(_longest_prefix(title, room, size, "bold", "normal") - 1, 10),
                            placeholder="…")


def text_pages(title: str, blocks: Sequence[tuple[str, str]]) -> list[Figure]:
    """Pages of wrapped text under a title: ("h", heading) or ("p", paragraph) items, in order."""
    return flow_pages(title, as_blocks(blocks))


def table_pages(title: str, header: Sequence[str], rows: Sequence[Sequence[str]], *,
                notes: Sequence[str] = (), font_size: float = 8.5, keep_columns: int = 1) -> list[Figure]:
    """Pages holding one table that fits: split by columns when wide (the first `keep_columns` repeated in each
    part), continued on further pages when long (header repeated); `notes` under it on every page.

    Args:
        title: page title. header: column titles (with units). rows: cell texts.
        notes: lines printed under the table on every page (wrapped).
        font_size: of the cells [pt].
        keep_columns: leading columns that name a row, repeated in every part of a split table.
    """
    if not rows:
        return flow_pages(title, [Paragraph("(no rows)")], notes=notes)
    block = TableBlock(tuple(header), tuple(tuple(str(c) for c in r) for r in rows), font_size, keep_columns)
    return flow_pages(title, [block], notes=notes)
