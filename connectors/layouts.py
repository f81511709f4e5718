"""Historian export layouts: each parser turns a source into named time series (`Table`).

Layouts (``fmt=`` names): ``wide``, ``long``, ``ragged`` (PI DataLink, a timestamp column per
tag), ``influx`` (InfluxDB annotated CSV), ``dcs`` (the DCS text export starting with
``PROCESSDATA``). Exports with a BOM, separate date and time columns, newest row first, ``t,OP,PV``
files in seconds, comma/semicolon/tab separators and decimal commas are variants of these that
`detect_layout` and the parsers handle without options. What a layout looks like (which header
names mean time, tag, value and quality, where the DCS export's rows start) is decided here from
the start of the file; pandas parses the rows (`connectors.textio.read_frame`).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from diagnose.errors import ConnectorError

from .columns import TIME_NAMES, role_of, strip_units
from .textio import (Source, comma_times, commonest, delimiter_name, detect_decimal_comma, numbers, quality_good,
                     read_frame, split_line)
from .timebase import parse_times

LAYOUTS = ("wide", "long", "ragged", "influx", "dcs")
TIME_HEADERS = TIME_NAMES | {"date", "t_stamp", "time_stamp", "sampletime", "sample_time", "date/time",
                             "timestamp_utc", "time_utc", "zeit", "datum/zeit", "zeitstempel",
                             "datum", "fecha", "ip_trend_time", "timestring"}
TAG_HEADERS = {"tag", "tagname", "tag_name", "name", "point", "pointname", "point_name", "series",
               "signal", "item", "itemid", "item_id", "variable", "sensor", "tagpath", "tag_path",
               "varname"}
VALUE_HEADERS = {"value", "val", "_value", "reading", "wert", "valeur", "ip_trend_value", "varvalue"}
QUALITY_HEADERS = {"quality", "q", "status", "confidence", "qualitycode", "quality_code",
                   "opc_quality", "qualitat", "qualität", "qualitydetail", "opcquality",
                   "ip_trend_qstatus", "ip_trend_qlevel", "validity"}
#: OPC-coded quality columns, taken before any other quality column of the same file: AVEVA
#: (Wonderware) Historian writes ``Quality`` (its own code, 0 = good) beside ``QualityDetail`` and
#: ``OPCQuality`` (192 = good), and OPC rules read that ``Quality`` 0 as bad.
OPC_QUALITY_HEADERS = ("qualitydetail", "opcquality", "opc_quality")
PI_FLAG_HEADERS = {"questionable", "substituted", "isquestionable", "issubstituted"}
SKIP_HEADERS = {"id", "index", "row", "#", "no", "nr", "unnamed: 0", ""}
#: A PHD (Uniformance) confidence column (0-100, 100 good) of a wide export: ``FIC101.PV Confidence``
#: (``.Confidence``, ``_Conf``, ``(Confidence)``), or a bare ``Confidence`` right after its value column.
_CONFIDENCE = re.compile(r"^(.*?)[\s._:-]*\(?(?:confidence|conf)(?:[\s_]*factor)?\)?$", re.I)
_NEWLINE = re.compile(r"\r\n|\r|\n")
_HEAD_LINES = 5000          # lines of the file's start looked at for headers and number formats


@dataclass
class Series:
    """One signal read from a file.

    ``t`` is seconds (UTC epoch when ``Table.absolute``) per row, NaN where a row has no time;
    ``x`` is the value, NaN where bad. Counts say what was turned into NaN; ``cells`` keeps the
    column's text when some cells were text (mode states are read from it).
    """

    name: str
    t: np.ndarray | None
    x: np.ndarray
    n_text: int = 0
    n_nonfinite: int = 0
    n_bad_quality: int = 0
    n_blank: int = 0
    examples: list[str] = field(default_factory=list)
    first_line: int | None = None
    column: str | None = None
    cells: pd.Series | None = None
    units: str | None = None
    quality_column: str | None = None    # the column whose codes made ``n_bad_quality`` gaps (wide layout)
    blank: np.ndarray | None = None      # True per row whose cell was empty (None: no empty cell, or not kept)


@dataclass
class Table:
    """Everything one file gave: series, and how the file was read."""

    series: list[Series]
    label: str
    absolute: bool
    meta: dict[str, Any]
    ts_s: float | None = None
    raw_columns: list[str] = field(default_factory=list)


_DATE_NAMES = ("date", "datum", "fecha", "data", "dato", "day")
_CLOCK_NAMES = ("time", "zeit", "uhrzeit", "hora", "ora", "tid", "heure", "clock")


def _date_time_pair(lower: list[str]) -> list[int]:
    """Indices of separate date and time-of-day columns (``date``/``time``, ``Datum``/``Zeit``...)."""
    d = next((lower.index(n) for n in _DATE_NAMES if n in lower), None)
    c = next((lower.index(n) for n in _CLOCK_NAMES if n in lower), None)
    return [d, c] if d is not None and c is not None else []


def is_time_header(h: str) -> bool:
    """Does a column header name a timestamp (``Time``, ``TimeStamp``, ``FIC101 Time``, ...)?"""
    s = h.strip().lower()
    return (s in TIME_HEADERS or s.endswith((" time", " timestamp", "_timestamp", ".timestamp",
                                               " zeit")) or s.startswith("timestamp"))


# ----------------------------------------------------------------------------------------- detection

def detect_layout(src: Source) -> str:
    """The layout name of an opened export (see `LAYOUTS`), from the start of its text."""
    head = src.head[:20000].splitlines()
    first = next((ln for ln in head if ln.strip()), "")
    if first.lstrip().upper().startswith("PROCESSDATA"):
        return "dcs"
    if any(ln.startswith(("#datatype", "#group", "#default")) for ln in head[:20]):
        return "influx"
    d = src.delimiter
    rows = [r for r in (ln.split(d) for ln in head[:40] if ln.strip() and not ln.startswith("#"))]
    if not rows:
        return "wide"
    header = [c.strip().strip('"').strip().lower() for c in rows[0]]
    if "_time" in header and "_value" in header:
        return "influx"
    if any(h in TAG_HEADERS for h in header) and any(h in VALUE_HEADERS for h in header):
        return "long"
    if _pairs(header):
        return "ragged"
    if len(rows) > 1:
        second = [c.strip().strip('"').strip().lower() for c in rows[1]]
        if _pairs(second):
            return "ragged"
    return "wide"


def _pairs(header: list[str]) -> bool:
    """Two or more time columns, each followed by a value column: (time, value) pairs."""
    is_t = [is_time_header(h) for h in header]
    idx = [j for j, v in enumerate(is_t) if v]
    if len(idx) < 2:
        return False
    return all(j + 1 < len(is_t) and not is_t[j + 1] for j in idx) and 2 * len(idx) >= len(header) - 1


# ------------------------------------------------------------------------------------------- helpers

@dataclass
class _Head:
    """The header row(s) of a delimited export and the first rows after them, from the file's start."""

    delimiter: str
    header_lines: list[int]          # 0-based line index of each header row
    headers: list[list[str]]         # the header rows' fields
    rows: list[list[str]]            # up to 100 data rows spread over the head, the first one first
    first: list[tuple[int, list[str]]] = field(default_factory=list)   # the first rows: (line index, fields)


def _head(src: Source, n_headers: int = 1) -> _Head:
    lines = _split_lines(src.head, _HEAD_LINES)
    if not src.complete or len(lines) > _HEAD_LINES:
        lines = lines[:-1]                       # the last piece may be a cut line or the rest
    d = src.delimiter
    content = [k for k, ln in enumerate(lines) if ln and not ln.isspace() and not ln.startswith("#")]
    hl = content[:n_headers]
    headers = [split_line(lines[k], d) for k in hl]
    body = content[n_headers:]
    sample = [lines[k] for k in body[:: max(1, len(body) // 100)][:100]]
    try:
        rows = [r for r in csv.reader(sample, delimiter=d) if r]
    except csv.Error:
        rows = [ln.split(d) for ln in sample]
    first = [(k, split_line(lines[k], d)) for k in body[:_LABEL_ROWS + 1]]
    return _Head(d, hl, headers, rows, first)


#: Rows under the header that may hold descriptions, units or other labels instead of data.
_LABEL_ROWS = 5
_UNITS_LABELS = {"units", "unit", "eng units", "eng. units", "engineering units", "engunits", "eu", "uom",
                 "einheit", "einheiten", "unidad", "unidades", "unité", "unités"}


def _label_rows(header: list[str], first: list[tuple[int, list[str]]]) -> list[list[str]]:
    """The rows right under the header that label the columns (description, units, descriptor
    rows that Aspen Process Explorer, PHD and PI DataLink exports can carry): no cell is a number
    or a time, the first column is the time (or a label) column, and some value cell is filled."""
    if not header or role_of(header[0]) not in (None, "time"):
        return []
    out = []
    for _, fields in first[:_LABEL_ROWS]:
        cells = _clean(fields)
        values = [c for c in cells[1:] if c]
        if not values or any(_numeric_cell(c) or _time_cell(c) for c in cells if c):
            break
        out.append(cells)
    return out


def _confidence_columns(header: list[str], value_idx: list[int]) -> dict[int, int]:
    """Value column -> its PHD confidence column, in a wide header. A column is one only when its
    value column is there (named before the word, or right before a bare ``Confidence``); read as
    a signal it was ignored, and a sample with no confidence passed for a good one."""
    names = {j: strip_units(header[j])[0].strip().lower() for j in value_idx}
    out: dict[int, int] = {}
    for j in value_idx:
        m = _CONFIDENCE.match(header[j].strip())
        if not m:
            continue
        base = strip_units(m.group(1))[0].strip().lower()
        if base:
            owner = next((k for k in value_idx if k != j and names[k] == base), None)
        else:
            owner = j - 1 if j - 1 in names and not _CONFIDENCE.match(header[j - 1].strip()) else None
        if owner is not None and owner not in out:
            out[owner] = j
    return out


def _numeric_cell(cell: str) -> bool:
    c = cell.replace(",", ".") if re.fullmatch(r"[+-]?\d+,\d+", cell) else cell
    try:
        float(c.replace(",", ""))
        return True
    except ValueError:
        return False


def _time_cell(cell: str) -> bool:
    try:
        parse_times([cell])
        return True
    except ConnectorError:
        return False


_OTHER_BREAKS = "\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"     # str.splitlines() breaks there, pandas not


def _split_lines(text: str, limit: int) -> list[str]:
    """Lines as pandas counts them (``\\r\\n``, ``\\r``, ``\\n``), the first ``limit`` and the rest."""
    if any(c in text for c in _OTHER_BREAKS):
        return _NEWLINE.split(text, maxsplit=limit)
    lines = text.splitlines()
    if text.endswith(("\n", "\r")):
        lines.append("")
    return lines if len(lines) <= limit else lines[:limit] + ["\n".join(lines[limit:])]


def _clean(header: list[str]) -> list[str]:
    return [h.strip().strip('"').strip() for h in header]


def _decimal_comma(rows: list[list[str]], cols: list[int], delimiter: str) -> bool:
    """Decimal commas in the value cells of up to 100 rows spread over ``rows``."""
    sample = rows[:: max(1, len(rows) // 100)][:100]
    cells = [r[j] for r in sample for j in cols if j < len(r)]
    return any("," in c for c in cells) and detect_decimal_comma(cells)


def _times(cells: Any, lines: np.ndarray, label: str, column: str, options: dict,
           decimal_comma: bool = False, notes: dict | None = None) -> tuple[np.ndarray, bool, str, str | None]:
    """A time column read with the file's options; ``notes`` (the table's meta) gets
    ``date_order_guessed`` when the dates read alike day first and month first, and ``dates``
    (the dates looked at, and whether they were read day first) when their format orders day and
    month, for a folder's files to decide their order together."""
    if decimal_comma:   # the file's decimal comma holds for a time column of numbers too
        cells = comma_times(_text(cells)) or cells
    pt = parse_times(cells, tz=options.get("tz"), dst=options.get("dst", "infer"), label=label,
                     column=column, lines=lines, dayfirst=options.get("dayfirst"))
    if pt.order_guessed is not None and notes is not None:
        notes.setdefault("date_order_guessed", dict(pt.order_guessed, column=column))
    if pt.dates and notes is not None:
        notes.setdefault("dates", {"dates": list(pt.dates), "dayfirst": pt.fmt.startswith("%d"), "column": column})
    return pt.seconds, pt.absolute, pt.fmt, pt.tz


def _text(col: np.ndarray) -> list[str]:
    """A parsed column as text, empty where the cell was empty."""
    return [v if isinstance(v, str) else "" if v is None or v != v else str(v) for v in col]


def blank_cells(num: Any) -> np.ndarray | None:
    """True per cell of a `numbers` column that was empty; None when none was."""
    k = num.kind
    if k is None or not (k == 1).any():
        return None
    return k == 1


def _series(name: str, t: np.ndarray | None, col: np.ndarray, decimal_comma: bool, first_line: int | None) -> Series:
    num = numbers(col, decimal_comma)
    return Series(name=name, t=t, x=num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                  n_blank=num.n_blank, examples=num.examples, first_line=first_line, column=name,
                  cells=num.text, blank=blank_cells(num))


# ---------------------------------------------------------------------------------------------- wide

def parse_wide(src: Source, options: dict, *, header: list[str] | None = None, header_line: int | None = None,
               skiprows: int | None = None, delimiter: str | None = None, first_row: list[str] | None = None,
               sample_rows: list[list[str]] | None = None, fmt: str = "wide",
               extra_meta: dict | None = None) -> Table:
    """A header row, one or two time columns (date + time), one column per signal."""
    label = src.label
    units: dict[str, str] = {}
    labels: list[list[str]] = []
    if header is None:
        head = _head(src)
        if not head.headers:
            raise ConnectorError("file is empty", path=label)
        header = head.headers[0]
        header_line = head.header_lines[0] + 1
        skiprows = head.header_lines[0] + 1
        delimiter = head.delimiter
        sample_rows = head.rows
        labels = _label_rows(_clean(header), head.first)
        if labels:
            # read from the first data row on; the label rows would be unreadable times otherwise
            skiprows = head.first[len(labels) - 1][0] + 1
            data = [fields for _, fields in head.first[len(labels):]]
            sample_rows = data[:1] + [r for r in head.rows[1:] if _clean(r) not in labels]
            for cells in labels:
                if cells[0].lower() in _UNITS_LABELS:
                    units = {h: u for h, u in zip(_clean(header)[1:], cells[1:]) if u}
    d = delimiter or ","
    rows = sample_rows or []
    first_row = first_row if first_row is not None else (rows[0] if rows else None)
    header = _clean(header)
    if first_row is None and src.complete:
        raise ConnectorError("header only, no data rows", path=label, line=header_line)
    if len(header) < 2:
        raise ConnectorError(f"only one column ({header[0]!r}) with separator {delimiter_name(d)}; "
                             "need a time/OP/PV column each", path=label, line=header_line)
    lower = [h.lower() for h in header]
    ts_col = options.get("ts")
    time_idx: list[int] = []
    if ts_col:
        if ts_col not in header:
            raise ConnectorError(f"no column named {ts_col!r} for the time (columns: {', '.join(header)})",
                                 path=label, line=header_line)
        time_idx = [header.index(ts_col)]
    elif _date_time_pair(lower):
        time_idx = _date_time_pair(lower)
    else:
        named = [j for j, h in enumerate(header) if is_time_header(h) and role_of(h) is None
                 or h.lower() in TIME_NAMES]
        if named:
            rel = {"t", "ts", "t_s", "time_s"}
            named.sort(key=lambda j: lower[j] in rel)  # a calendar column beats a seconds column
            time_idx = [named[0]]
        elif role_of(header[0]) is None and first_row and first_row[0].strip():
            try:
                parse_times([first_row[0]])
                if not re.fullmatch(r"[+-]?[\d.eE+-]+", first_row[0].strip()):
                    time_idx = [0]
            except ConnectorError:
                pass
    value_idx = [j for j in range(len(header)) if j not in time_idx and lower[j] not in SKIP_HEADERS
                 and not (lower[j] in TIME_HEADERS and role_of(header[j]) in (None, "time"))]
    confidence = _confidence_columns(header, value_idx)
    value_idx = [j for j in value_idx if j not in confidence.values()]
    dec = _decimal_comma(rows, value_idx, d)
    frame = read_frame(src, sep=d, skiprows=skiprows or 0, width=len(header), decimal="," if dec else ".",
                       str_columns=tuple(time_idx) if dec or len(time_idx) == 2 else ())
    cols, lines = frame.columns, frame.lines
    if not len(frame):
        raise ConnectorError("header only, no data rows", path=label, line=header_line)
    src.progress.say(f"{len(frame)} rows parsed; reading the times")
    t = None
    absolute = False
    tfmt = tzone = None
    notes: dict[str, Any] = {}
    if time_idx:
        if len(time_idx) == 2:
            cells = [f"{a.strip()} {b.strip()}".strip()
                     for a, b in zip(_text(cols[time_idx[0]]), _text(cols[time_idx[1]]))]
            tname = f"{header[time_idx[0]]}+{header[time_idx[1]]}"
        else:
            cells = cols[time_idx[0]]
            tname = header[time_idx[0]]
        t, absolute, tfmt, tzone = _times(cells, lines, label, tname, options, dec, notes)
    series = [_series(header[j], t, cols[j], dec, int(lines[0])) for j in value_idx]
    schemes = set()
    for j, s in zip(value_idx, series):
        s.units = units.get(s.name) or strip_units(s.name)[1]
        if j in confidence:   # low confidence is bad quality, as a long export's quality column
            good, scheme = quality_good(cols[confidence[j]], header[confidence[j]])
            bad = ~good & np.isfinite(s.x)
            s.x[bad] = np.nan
            s.n_bad_quality, s.quality_column = int(np.count_nonzero(bad)), header[confidence[j]]
            schemes.add(scheme)
    meta = {"format": fmt, "delimiter": delimiter_name(d), "decimal": "," if dec else ".",
            "encoding": src.encoding, "bom": src.bom, "time_format": tfmt, "time_zone": tzone,
            "time_columns": [header[j] for j in time_idx], **notes}
    if confidence:
        meta["quality_scheme"] = "+".join(sorted(schemes))
        meta["quality_columns"] = {header[v]: header[c] for v, c in confidence.items()}
    if labels:
        meta["label_rows"] = [cells[0] for cells in labels]
    if extra_meta:
        meta.update(extra_meta)
    return Table(series, label, absolute, meta, raw_columns=header)


# ---------------------------------------------------------------------------------------------- long

def _tags(col: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Tag codes per row and the tags (stripped; an empty cell is tag ""), in order of appearance."""
    codes, uniq = pd.factorize(col, use_na_sentinel=False)
    stripped = [u.strip() if isinstance(u, str) else "" if u is None or u != u else str(u).strip() for u in uniq]
    remap, names = pd.factorize(np.array(stripped, dtype=object))
    return remap[codes], [str(n) for n in names]


def parse_long(src: Source, options: dict) -> Table:
    """``tag, time, value[, quality]`` rows: one row per tag per time."""
    label = src.label
    head = _head(src)
    if not head.headers:
        raise ConnectorError("file is empty", path=label)
    header = _clean(head.headers[0])
    header_line = head.header_lines[0] + 1
    lower = [h.lower() for h in header]
    if not head.rows and src.complete:
        raise ConnectorError("header only, no data rows", path=label, line=header_line)
    tag_j = next((j for j, h in enumerate(lower) if h in TAG_HEADERS), None)
    val_j = next((j for j, h in enumerate(lower) if h in VALUE_HEADERS), None)
    ts_col = options.get("ts")
    if ts_col and ts_col in header:
        time_j = [header.index(ts_col)]
    elif _date_time_pair(lower):
        time_j = _date_time_pair(lower)
    else:
        time_j = [j for j, h in enumerate(header) if is_time_header(h) and j not in (tag_j, val_j)][:1]
    q_j = next((lower.index(h) for h in OPC_QUALITY_HEADERS if h in lower),
               next((j for j, h in enumerate(lower) if h in QUALITY_HEADERS), None))
    flags = [j for j, h in enumerate(lower) if h in PI_FLAG_HEADERS]
    dec = _decimal_comma(head.rows, [val_j], head.delimiter) if val_j is not None else False
    text_cols = tuple(j for j in [tag_j, *time_j, *flags] if j is not None)
    frame = read_frame(src, sep=head.delimiter, skiprows=head.header_lines[0] + 1, width=len(header),
                       decimal="," if dec else ".", str_columns=text_cols)
    cols, lines = frame.columns, frame.lines
    if not len(frame):
        raise ConnectorError("header only, no data rows", path=label, line=header_line)
    if tag_j is None or val_j is None:
        raise ConnectorError(f"long layout needs a tag column and a value column (columns: {', '.join(header)})",
                             path=label, line=header_line)
    if not time_j:
        raise ConnectorError(f"long layout without a time column (columns: {', '.join(header)}); "
                             "name it with --ts", path=label, line=header_line)
    src.progress.say(f"{len(frame)} rows parsed; reading the times")
    if len(time_j) == 2:
        tcells = [f"{a.strip()} {b.strip()}" for a, b in zip(_text(cols[time_j[0]]), _text(cols[time_j[1]]))]
    else:
        tcells = cols[time_j[0]]
    notes: dict[str, Any] = {}
    t, absolute, tfmt, tzone = _times(tcells, lines, label, header[time_j[0]], options, dec, notes)
    num = numbers(cols[val_j], dec)
    finite = np.isfinite(num.values)
    bad_q = np.zeros(len(frame), bool)
    scheme = None
    if q_j is not None:
        good, scheme = quality_good(cols[q_j], header[q_j])
        bad_q = ~good & finite
    for j in flags:   # PI flag columns: Questionable / Substituted = True -> bad
        codes, uniq = pd.factorize(cols[j])
        true = np.array([isinstance(u, str) and u.strip().lower() in ("true", "1", "yes", "y") for u in uniq] + [False])
        bad_q = bad_q | (true[codes] & finite)
        if "pi_flags" not in (scheme or ""):
            scheme = (scheme + "+" if scheme else "") + "pi_flags"
    inverse, names = _tags(cols[tag_j])
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(len(names) + 1))
    kind = num.kind
    text = num.text
    series: list[Series] = []
    for g, tag in enumerate(names):
        if not tag:
            continue
        idx = order[bounds[g]:bounds[g + 1]]
        x = num.values[idx].copy()
        bq = bad_q[idx]
        x[bq] = np.nan
        k = kind[idx] if kind is not None else None
        n_text = int(np.count_nonzero(k == 2)) if k is not None else 0
        examples: list[str] = []
        cells = None
        if n_text:
            examples = commonest(text[idx[k == 2][:1000]])
            cells = text[idx]
        series.append(Series(str(tag), t[idx], x, n_text=n_text,
                             n_nonfinite=int(np.count_nonzero(k == 3)) if k is not None else 0,
                             n_bad_quality=int(np.count_nonzero(bq)),
                             n_blank=int(np.count_nonzero(k == 1)) if k is not None else 0,
                             examples=examples, first_line=int(lines[idx[0]]), column=header[val_j],
                             cells=cells, blank=(k == 1) if k is not None and (k == 1).any() else None))
    meta = {"format": "long", "delimiter": delimiter_name(head.delimiter), "decimal": "," if dec else ".",
            "encoding": src.encoding, "bom": src.bom, "time_format": tfmt, "time_zone": tzone, "quality_scheme": scheme,
            "quality_column": header[q_j] if q_j is not None else None, **notes}
    return Table(series, label, absolute, meta, raw_columns=header)


# -------------------------------------------------------------------------------------------- ragged

def parse_ragged(src: Source, options: dict) -> Table:
    """PI DataLink compressed data: ``time, value`` column pairs, one pair per tag.

    The tag name is the value column's header, or (two header rows) the cell above the pair.
    """
    label = src.label
    head = _head(src, n_headers=2)
    if len(head.headers) < 2:
        raise ConnectorError("header only, no data rows", path=label)
    h0, h1 = _clean(head.headers[0]), _clean(head.headers[1])
    two_rows = _pairs([h.lower() for h in h1]) and not _pairs([h.lower() for h in h0])
    header = h1 if two_rows else h0
    header_line = head.header_lines[1 if two_rows else 0] + 1
    frame = read_frame(src, sep=head.delimiter, skiprows=header_line, width=len(header),
                       str_columns=tuple(range(len(header))), allow_short=True)
    cols, lines = frame.columns, frame.lines
    if not len(frame):
        raise ConnectorError("header only, no data rows", path=label, line=head.header_lines[0] + 1)
    series: list[Series] = []
    absolute = False
    tfmt = tzone = None
    notes: dict[str, Any] = {}
    j = 0
    while j < len(header):
        if not is_time_header(header[j]) or j + 1 >= len(header):
            j += 1
            continue
        if two_rows:
            name = h0[j] or (h0[j + 1] if j + 1 < len(h0) else "")
        else:
            name = header[j + 1]
            if is_time_header(name):
                j += 1
                continue
        name = name.strip() or f"column{j + 2}"
        tcells = _text(cols[j])
        keep = np.array([k for k, c in enumerate(tcells) if c.strip()], dtype=np.int64)
        if keep.size:
            tl = lines[keep]
            vcells = np.array(_text(cols[j + 1]), dtype=object)[keep]
            dec = _decimal_comma([[c] for c in vcells[:: max(1, keep.size // 100)][:100]], [0], head.delimiter)
            tt, absolute, tfmt, tzone = _times([tcells[k] for k in keep], tl, label, header[j], options, dec, notes)
            num = numbers(vcells, dec)
            series.append(Series(name, tt, num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                                 n_blank=num.n_blank, examples=num.examples, first_line=int(tl[0]),
                                 column=name, cells=num.text, blank=blank_cells(num)))
        j += 2
    if not series:
        raise ConnectorError("no timestamp/value column pairs found for the ragged layout", path=label,
                             line=head.header_lines[0] + 1)
    meta = {"format": "ragged", "delimiter": delimiter_name(head.delimiter), "encoding": src.encoding,
            "bom": src.bom, "time_format": tfmt, "time_zone": tzone, **notes}
    return Table(series, label, absolute, meta, raw_columns=[s.name for s in series])


# -------------------------------------------------------------------------------------------- influx

def parse_influx(src: Source, options: dict) -> Table:
    """InfluxDB annotated CSV (``#datatype``/``#group``/``#default`` rows, ``_time``, ``_value``).

    Each table starts after its annotation rows with a header row (or at a row naming ``_time``
    and ``_value``); the series name is ``<tag values or _measurement>.<_field>``.
    """
    label = src.label
    width = max((len(split_line(ln, ",")) for ln in _NEWLINE.split(src.head, maxsplit=400)[:400] if ln.strip()),
                default=1)
    frame = read_frame(src, sep=",", skiprows=0, width=width, str_columns=tuple(range(width)),
                       allow_short=True, drop_comments=False)
    cols = [np.array([c.strip() for c in _text(col)], dtype=object) for col in frame.columns]
    line = frame.lines
    if not len(frame):
        raise ConnectorError("InfluxDB CSV without data rows", path=label)
    annot = np.array([c.startswith("#") for c in cols[0]], dtype=bool)
    named = np.logical_or.reduce([c == "_time" for c in cols]) & np.logical_or.reduce([c == "_value" for c in cols])
    after = np.concatenate([[True], annot[:-1]])
    is_header = ~annot & (after | named)
    table = np.cumsum(is_header)
    groups: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for h in np.flatnonzero(is_header):
        hdr = _trim([c[h] for c in cols])
        if "_time" not in hdr or "_value" not in hdr:
            raise ConnectorError("InfluxDB CSV table without _time and _value columns", path=label,
                                 line=int(line[h]))
        rows = np.flatnonzero((table == table[h]) & ~is_header & ~annot)
        if not rows.size:
            continue
        sub = [c[rows] for c in cols]
        filled = np.stack([c != "" for c in sub], axis=1)
        used = np.where(filled.any(axis=1), filled.shape[1] - np.argmax(filled[:, ::-1], axis=1), 0)
        if (used > len(hdr)).any():
            k = int(np.argmax(used > len(hdr)))
            raise ConnectorError(f"row has {int(used[k])} fields but the table header has {len(hdr)}",
                                 path=label, line=int(line[rows[k]]))
        pos = {name: j for j, name in enumerate(hdr)}       # a repeated header name: the last one wins
        empty = np.full(rows.size, "", dtype=object)

        def col(name: str) -> np.ndarray:
            return sub[pos[name]] if name in pos else empty

        base = empty
        for name in (c for c in hdr if c and not c.startswith("_") and c not in ("result", "table")):
            v = col(name)
            base = np.where(v == "", base, np.where(base == "", v, base + "." + v))
        base = np.where(base != "", base, col("_measurement"))
        fld = col("_field")
        full = np.where((base != "") & (fld != ""), base + "." + fld,
                        np.where(fld != "", fld, np.where(base != "", base, "value")))
        codes, uniques = pd.factorize(full, sort=False)
        for g, name in enumerate(uniques):
            idx = np.flatnonzero(codes == g)
            groups.setdefault(str(name), []).append((col("_time")[idx], col("_value")[idx], rows[idx]))
    if not groups:
        raise ConnectorError("InfluxDB CSV without data rows", path=label)
    series = []
    absolute, tfmt, tzone = True, None, None
    notes: dict[str, Any] = {}
    for name, parts in groups.items():
        tc = np.concatenate([p[0] for p in parts])
        vc = np.concatenate([p[1] for p in parts])
        rows = np.concatenate([p[2] for p in parts])
        tt, absolute, tfmt, tzone = _times(tc, line[rows], label, "_time", options, notes=notes)
        num = numbers(vc)
        series.append(Series(name, tt, num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                             n_blank=num.n_blank, examples=num.examples, first_line=int(line[rows[0]]),
                             column=name))
    meta = {"format": "influx", "delimiter": "comma", "encoding": src.encoding, "bom": src.bom,
            "time_format": tfmt, "time_zone": tzone, **notes}
    return Table(series, label, absolute, meta, raw_columns=list(groups))


def _trim(cells: list[str]) -> list[str]:
    """A header row without the empty cells after its last name."""
    out = list(cells)
    while len(out) > 1 and out[-1] == "":
        out.pop()
    return out


# ----------------------------------------------------------------------------------------------- dcs

def parse_dcs(src: Source, options: dict) -> Table:
    """The DCS text export: ``PROCESSDATA`` line, ``<cols> <Ts> <start> <N>``, tag names,
    descriptions, a parameter line, then tab-separated rows (``<tag>.MV`` is the controller output)."""
    label = src.label
    lines = src.head.splitlines()                 # as the DCS writes it: the text's own line breaks
    if not src.complete:
        lines = lines[:-1]
    if len(lines) < 3:
        raise ConnectorError("DCS export without a tag-name line (line 3)", path=label, line=len(lines))
    ts_s = None
    parts = lines[1].split("\t") if len(lines) > 1 else []
    if len(parts) >= 2:
        try:
            ts_s = float(parts[1])
        except ValueError:
            ts_s = None
    tag_line = next((k for k in range(1, min(len(lines), 10))
                     if lines[k].lower().startswith(("tagname", "tag\t", "tags\t"))), 2)
    names = [c.strip() for c in lines[tag_line].split("\t")]
    names[0] = "time"
    start = tag_line + 1
    while start < len(lines):
        first = lines[start].split("\t")[0].strip()
        if re.match(r"^\d{4}[-/]\d{1,2}[-/]\d{1,2}", first):
            break
        start += 1
    if start >= len(lines):
        raise ConnectorError("header only, no data rows", path=label, line=len(lines))
    data = [ln for ln in lines[start:] if ln.strip()]
    rows = [ln.split("\t") for ln in data[:: max(1, len(data) // 100)][:100]]
    table = parse_wide(src, options, header=names, header_line=tag_line + 1, skiprows=start, delimiter="\t",
                       first_row=rows[0] if rows else None, sample_rows=rows, fmt="dcs",
                       extra_meta={"dcs_header": lines[0].strip()[:80]})
    table.ts_s = ts_s if ts_s and ts_s > 0 else None
    return table


PARSERS = {"wide": parse_wide, "long": parse_long, "ragged": parse_ragged, "influx": parse_influx,
           "dcs": parse_dcs}


def parse(src: Source, options: dict) -> Table:
    """Detect (or take ``options['fmt']``) and run the layout parser."""
    if src.complete and not src.head.strip():
        raise ConnectorError("file is empty", path=src.label)
    fmt = options.get("fmt") or options.get("format")
    if fmt in (None, "auto"):
        fmt = detect_layout(src)
    elif fmt not in PARSERS:
        raise ConnectorError(f"unknown format {fmt!r}; choose one of auto, {', '.join(LAYOUTS)}")
    src.progress.say(f"reading {src.size / 1e6:.0f} MB, {fmt} layout")
    return PARSERS[fmt](src, options)
