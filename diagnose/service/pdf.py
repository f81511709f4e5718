"""Report blocks (see `diagnose.service.report`) as a PDF, with fpdf2 and the PNG figures.

The same blocks as the Markdown report, laid out on A4 with the core Helvetica font. Text is
reduced to Latin-1 (the core fonts' repertoire) with readable replacements for the few symbols the
reports use.
"""

from __future__ import annotations

import io
import re
from typing import Mapping, Sequence

from .report import Block

_REPLACE = {"\u2264": "<=", "\u2265": ">=", "\u2248": "~", "\u00b1": "+/-", "\u2013": "-", "\u2014": "-",
            "\u2212": "-", "\u2018": "'", "\u2019": "'", "\u201c": '"', "\u201d": '"', "\u2026": "...",
            "\u03c4": "tau", "\u0394": "delta", "\u00b5": "u", "\u2192": "->"}
_LINK = re.compile(r"\[([^\]]+)\]\([^)]+\)")


def latin1(text: str) -> str:
    """Text the core PDF fonts can show: known symbols spelled out, the rest replaced by '?'."""
    text = _LINK.sub(r"\1", str(text))
    for k, v in _REPLACE.items():
        text = text.replace(k, v)
    return text.encode("latin-1", "replace").decode("latin-1")


def _figure_size_mm(png: bytes, epw: float) -> tuple[float, float]:
    """Printed size: an 8-inch-wide figure fills the text width, smaller ones keep their scale."""
    import struct

    from .figures import DPI

    w_px, h_px = struct.unpack(">II", png[16:24])  # the PNG IHDR chunk
    w_mm = min(epw, 180.0 * w_px / (8.0 * DPI))
    return w_mm, w_mm * h_px / w_px


#: where a word without spaces (a file's path) may break across lines: after each separator
_PATH_BREAK = re.compile(r"(?<=[/\\])")

#: the smallest font (pt) a table shrinks to before it lets a word break
_MIN_TABLE_PT = 6.5


def _pieces(text: str) -> list[str]:
    """The parts a cell may wrap between: its words, and a path's parts after each separator."""
    return [p for w in text.split() for p in _PATH_BREAK.split(w) if p]


def _column_bounds(pdf, header: Sequence[str], rows: Sequence[Sequence[str]], padding: float
                   ) -> tuple[list[float], list[float], list[float]]:
    """Each column's widths (mm) at the current font: the least, its widest unbreakable part (a
    header word in bold; a cell's word, or a path's part); the one that keeps its cells on one line
    (the header may wrap between words); and the one that keeps the header on one line too."""
    pad = 2 * padding + 0.5
    least, one_line, flat = [], [], []
    for j, h in enumerate(header):
        pdf.set_font(style="B")   # the header row's face
        head = [pdf.get_string_width(w) for w in latin1(str(h)).split()]
        whole = pdf.get_string_width(latin1(str(h)))
        pdf.set_font(style="")
        cells = [latin1(str(r[j])) for r in rows if j < len(r)]
        least.append(max(head + [pdf.get_string_width(p) for c in cells for p in _pieces(c)] + [0.0]) + pad)
        one_line.append(max(head + [pdf.get_string_width(c) for c in cells] + [0.0]) + pad)
        flat.append(max(one_line[-1], whole + pad))
    return least, one_line, flat


def _table_widths(least: Sequence[float], one_line: Sequence[float], flat: Sequence[float],
                  epw: float) -> list[float] | None:
    """Column widths (mm) that split no word, or None where the least widths exceed ``epw``: one
    line per cell where that fits (headers too where they fit), else each column's least width and
    the room left over shared by how much of each column's text would still wrap, so a sentence or
    a path takes what a number does not need (and the table is no taller than it must be)."""
    if sum(flat) <= epw:
        return list(flat)
    if sum(one_line) <= epw:
        return list(one_line)
    if sum(least) > epw:
        return None
    spare, want = epw - sum(least), [o - m for o, m in zip(one_line, least)]
    return [m + spare * w / sum(want) for m, w in zip(least, want)]


def _wrap_paths(pdf, text: str, width: float) -> str:
    """``text`` with each word wider than ``width`` (mm) broken into lines after its separators,
    where the table would otherwise cut it between two letters."""
    out = []
    for word in text.split(" "):
        if pdf.get_string_width(word) <= width:
            out.append(word)
            continue
        lines = [""]
        for p in _PATH_BREAK.split(word):
            if lines[-1] and pdf.get_string_width(lines[-1] + p) > width:
                lines.append("")
            lines[-1] += p
        out.append("\n".join(lines))
    return " ".join(out)


def _lines(pdf, text: str, width: float, cache: dict[str, float]) -> list[str]:
    """``text`` broken into lines no wider than ``width`` (mm) at the current font: between words,
    at its own line breaks, and inside a word only where the word alone is wider. The core fonts
    have no kerning, so a line's width is the sum of its words' and spaces' (each word measured
    once, ``cache``)."""
    def w(s: str) -> float:
        v = cache.get(s)
        if v is None:
            v = cache[s] = pdf.get_string_width(s)
        return v

    space = w(" ")
    out: list[str] = []
    for para in text.split("\n"):
        line, lw = "", 0.0
        for word in para.split(" "):
            ww = w(word)
            if line and lw + space + ww <= width:
                line, lw = f"{line} {word}", lw + space + ww
                continue
            if line:
                out.append(line)
            while ww > width and len(word) > 1:     # wider than the column: broken where it must
                k = len(word) - 1
                while k > 1 and w(word[:k]) > width:
                    k -= 1
                out.append(word[:k])
                word = word[k:]
                ww = w(word)
            line, lw = word, ww
        out.append(line)
    return out


def _table(pdf, header: Sequence[str], rows: Sequence[Sequence[str]], epw: float, fill) -> None:
    """A table whose columns split no word: the font shrinks (to `_MIN_TABLE_PT`) until the widest
    words fit; a path too long for its column wraps after a '/'. The header row is bold on
    ``fill`` (an RGB triple) and repeated at the top of each page the table runs onto.

    Drawn cell by cell rather than with fpdf's own table, whose line breaking measures each line
    again for every character added (most of a report's PDF time)."""
    size = 8.0 if len(header) > 4 or len(rows) > 8 else 9.0
    padding = 0.8
    while True:
        pdf.set_font("Helvetica", "", size)
        least, one_line, flat = _column_bounds(pdf, header, rows, padding)
        widths = _table_widths(least, one_line, flat, epw)
        if widths is not None or size <= _MIN_TABLE_PT:
            break
        size -= 0.5
    if widths is None:   # words wider than the page: they break rather than run off it
        widths = [w * epw / sum(least) for w in least]
    # the widths are proportions of the text width: a table that fits on one line is spread over it
    widths = [w * epw / sum(widths) for w in widths]
    line_h = 0.49 * size
    caches: dict[str, dict[str, float]] = {"": {}, "B": {}}

    def laid_out(cells: Sequence[str], style: str) -> tuple[list[list[str]], float]:
        pdf.set_font("Helvetica", style, size)
        lines = [_lines(pdf, _wrap_paths(pdf, latin1(c), wd - 2 * padding - 0.5) if style == "" else latin1(c),
                        wd - 2 * padding, caches[style])
                 for c, wd in zip(list(cells) + [""] * (len(widths) - len(cells)), widths)]
        return lines, max(len(ls) for ls in lines) * line_h + 2 * padding

    def draw(lines: list[list[str]], height: float, style: str) -> None:
        pdf.set_font("Helvetica", style, size)
        x, y = pdf.l_margin, pdf.get_y()
        for ls, wd in zip(lines, widths):
            if style == "B":
                pdf.set_fill_color(*fill)
            pdf.rect(x, y, wd, height, style="DF" if style == "B" else "D")
            top = y + (height - len(ls) * line_h) / 2     # vertically centred, as fpdf's tables
            for k, text in enumerate(ls):
                pdf.set_xy(x + padding, top + k * line_h)
                pdf.cell(wd - 2 * padding, line_h, text, align="L")
            x += wd
        pdf.set_xy(pdf.l_margin, y + height)

    head_lines, head_h = laid_out(header, "B")
    bottom = pdf.h - pdf.b_margin
    if pdf.get_y() + head_h > bottom:
        pdf.add_page()
    draw(head_lines, head_h, "B")
    for row in rows:
        lines, h = laid_out(row, "")
        if pdf.get_y() + h > bottom and h <= bottom - pdf.t_margin - head_h:
            pdf.add_page()
            draw(head_lines, head_h, "B")
        draw(lines, h, "")


def to_pdf(blocks: Sequence[Block], figures: Mapping[str, bytes] | None = None, *,
           title: str | None = None, subject: str | None = None) -> bytes:
    """Render blocks to PDF bytes; ``figures`` maps a figure block's name to its PNG bytes;
    ``title`` and ``subject`` go into the document's properties."""
    from fpdf import FPDF

    figures = figures or {}
    landscape = any(b[0] == "landscape" for b in blocks)
    pdf = FPDF(orientation="L" if landscape else "P", unit="mm", format="A4")
    pdf.set_auto_page_break(auto=True, margin=15)
    pdf.set_margins(15, 15, 15)
    if title:
        pdf.set_title(latin1(title))
    if subject:
        pdf.set_subject(latin1(subject))
    pdf.set_creator("stiction")
    pdf.add_page()
    epw = pdf.epw
    head = (225, 230, 240)     # the table header's fill
    for i, b in enumerate(blocks):
        kind = b[0]
        if kind == "title":
            pdf.set_font("Helvetica", "B", 16)
            pdf.multi_cell(epw, 8, latin1(b[1]), new_x="LMARGIN", new_y="NEXT")
            pdf.ln(2)
        elif kind == "h2":
            # keep a heading with what follows it (a figure: all of it; a paragraph: a few lines)
            nxt = blocks[i + 1] if i + 1 < len(blocks) else None
            need = 25.0 if nxt is not None and nxt[0] in ("p", "strong", "bullets") else 45.0
            if nxt is not None and nxt[0] == "figure" and nxt[1] in figures:
                need = 20.0 + _figure_size_mm(figures[nxt[1]], epw)[1]
            if pdf.get_y() + need > pdf.h - pdf.b_margin:
                pdf.add_page()
            pdf.ln(2)
            pdf.set_font("Helvetica", "B", 12)
            pdf.multi_cell(epw, 6, latin1(b[1]), new_x="LMARGIN", new_y="NEXT")
            pdf.ln(1)
        elif kind in ("p", "strong"):
            pdf.set_font("Helvetica", "B" if kind == "strong" else "", 9.5)
            pdf.multi_cell(epw, 4.8, latin1(b[1]), new_x="LMARGIN", new_y="NEXT")
            pdf.ln(1.5)
        elif kind == "bullets":
            pdf.set_font("Helvetica", "", 9)
            for item in b[1]:
                pdf.set_x(pdf.l_margin + 3)
                pdf.multi_cell(epw - 3, 4.5, latin1("- " + str(item)), new_x="LMARGIN", new_y="NEXT", align="L")
            pdf.ln(1.5)
        elif kind == "table":
            _table(pdf, b[1], b[2], epw, head)
            pdf.ln(2)
        elif kind == "figure":
            png = figures.get(b[1])
            if png is None:
                continue
            w_mm, h_mm = _figure_size_mm(png, epw)
            if pdf.get_y() + h_mm + 10 > pdf.h - pdf.b_margin:
                pdf.add_page()
            pdf.image(io.BytesIO(png), x=pdf.l_margin + (epw - w_mm) / 2, w=w_mm, h=h_mm)
            pdf.set_font("Helvetica", "I", 8)
            pdf.multi_cell(epw, 4, latin1(b[2]), new_x="LMARGIN", new_y="NEXT")
            pdf.ln(2)
        elif kind == "page":
            pdf.add_page()
        elif kind == "landscape":
            continue
        else:  # pragma: no cover - programming error
            raise ValueError(f"unknown block kind {kind!r}")
    return bytes(pdf.output())
