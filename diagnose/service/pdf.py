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


def _one_line_widths(pdf, header: Sequence[str], rows: Sequence[Sequence[str]], padding: float) -> list[float]:
    """Each column's width (mm) with every cell on one line (headers may wrap between words)."""
    out = []
    for j, h in enumerate(header):
        pdf.set_font(style="B")   # the header row's face
        words = [pdf.get_string_width(w) for w in latin1(str(h)).split()]
        pdf.set_font(style="")
        cells = [pdf.get_string_width(latin1(str(r[j]))) for r in rows if j < len(r)]
        out.append(max(words + cells + [0.0]) + 2 * padding + 0.5)
    return out


def to_pdf(blocks: Sequence[Block], figures: Mapping[str, bytes] | None = None, *,
           title: str | None = None, subject: str | None = None) -> bytes:
    """Render blocks to PDF bytes; ``figures`` maps a figure block's name to its PNG bytes;
    ``title`` and ``subject`` go into the document's properties."""
    from fpdf import FPDF
    from fpdf.fonts import FontFace

    figures = figures or {}
    pdf = FPDF(orientation="P", unit="mm", format="A4")
    pdf.set_auto_page_break(auto=True, margin=15)
    pdf.set_margins(15, 15, 15)
    if title:
        pdf.set_title(latin1(title))
    if subject:
        pdf.set_subject(latin1(subject))
    pdf.set_creator("stiction")
    pdf.add_page()
    epw = pdf.epw
    head = FontFace(emphasis="BOLD", fill_color=(225, 230, 240))
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
            header, rows = b[1], b[2]
            small = len(header) > 4 or len(rows) > 8
            pdf.set_font("Helvetica", "", 8 if small else 9)
            # column widths by content (long text columns wrap, short numeric ones stay narrow)
            lens = [max([len(latin1(str(h)))] + [len(latin1(str(r[j]))) for r in rows if j < len(r)])
                    for j, h in enumerate(header)]
            # short headers ("Named") stay on one line; the last column, the sentence ("Why",
            # "Finding", "Value"), may take most of the width
            widths = [min(max(n, 8), 110 if j == len(lens) - 1 else 60) + 2 for j, n in enumerate(lens)]
            fit = _one_line_widths(pdf, header, rows, padding=0.8)
            if sum(fit) <= epw:
                # every cell fits on one line: widths as measured, so a short column ("#", "S %")
                # does not take the room a file name needs (counted characters broke it mid-word)
                widths = fit
            with pdf.table(headings_style=head, line_height=3.9 if small else 4.4, text_align="LEFT", padding=0.8,
                           col_widths=tuple(widths)) as table:
                r = table.row()
                for h in header:
                    r.cell(latin1(h))
                for row in rows:
                    r = table.row()
                    for c in row:
                        r.cell(latin1(c))
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
        else:  # pragma: no cover - programming error
            raise ValueError(f"unknown block kind {kind!r}")
    return bytes(pdf.output())
