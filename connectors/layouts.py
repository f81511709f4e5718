"""Historian export layouts: each parser turns text into named time series (`Table`).

Layouts (``fmt=`` names): ``wide``, ``long``, ``ragged`` (PI DataLink, a timestamp column per
tag), ``influx`` (InfluxDB annotated CSV), ``dcs`` (the DCS text export starting with
``PROCESSDATA``). Exports with a BOM, separate date and time columns, newest row first, ``t,OP,PV``
files in seconds, comma/semicolon/tab separators and decimal commas are variants of these that
`detect_layout` and the parsers handle without options.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from diagnose.errors import ConnectorError

from .columns import TIME_NAMES, role_of
from .textio import (Rows, Text, delimiter_name, detect_decimal_comma, quality_good, sniff_delimiter,
                     split_rows, to_numbers)
from .timebase import parse_times

LAYOUTS = ("wide", "long", "ragged", "influx", "dcs")
TIME_HEADERS = TIME_NAMES | {"date", "t_stamp", "time_stamp", "sampletime", "sample_time", "date/time",
                             "timestamp_utc", "time_utc", "zeit", "datum/zeit", "zeitstempel"}
TAG_HEADERS = {"tag", "tagname", "tag_name", "name", "point", "pointname", "point_name", "series",
               "signal", "item", "itemid", "item_id", "variable", "sensor", "tagpath", "tag_path"}
VALUE_HEADERS = {"value", "val", "_value", "reading", "wert", "valeur"}
QUALITY_HEADERS = {"quality", "q", "status", "confidence", "qualitycode", "quality_code",
                   "opc_quality", "qualitat", "qualität"}
PI_FLAG_HEADERS = {"questionable", "substituted", "isquestionable", "issubstituted"}
SKIP_HEADERS = {"id", "index", "row", "#", "no", "nr", "unnamed: 0", ""}


@dataclass
class Series:
    """One signal read from a file.

    ``t`` is seconds (UTC epoch when ``Table.absolute``) per row, NaN where a row has no time;
    ``x`` is the value, NaN where bad. Counts say what was turned into NaN.
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
    cells: list[str] | None = None


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


def _is_time_header(h: str) -> bool:
    s = h.strip().lower()
    return (s in TIME_HEADERS or s.endswith((" time", " timestamp", "_timestamp", ".timestamp",
                                               " zeit")) or s.startswith("timestamp"))


# ----------------------------------------------------------------------------------------- detection

def detect_layout(text: Text) -> str:
    """The layout name of a decoded export (see `LAYOUTS`)."""
    head = text.text[:20000].splitlines()
    first = next((ln for ln in head if ln.strip()), "")
    if first.lstrip().upper().startswith("PROCESSDATA"):
        return "dcs"
    if any(ln.startswith(("#datatype", "#group", "#default")) for ln in head[:20]):
        return "influx"
    d = sniff_delimiter([ln for ln in head if not ln.startswith("#")])
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
    is_t = [_is_time_header(h) for h in header]
    idx = [j for j, v in enumerate(is_t) if v]
    if len(idx) < 2:
        return False
    return all(j + 1 < len(is_t) and not is_t[j + 1] for j in idx) and 2 * len(idx) >= len(header) - 1


# ------------------------------------------------------------------------------------------- helpers

def _prepare(text: Text, skip_comments: bool = True) -> tuple[Rows, str]:
    head = text.text[:20000].splitlines()
    d = sniff_delimiter([ln for ln in head if not (skip_comments and ln.startswith("#"))])
    src = text.text
    if skip_comments and (src.startswith("#") or "\n#" in src):
        src = "\n".join("" if ln.startswith("#") else ln for ln in src.splitlines())
    return split_rows(src, d, text.label), d


def _check_rect(rows: Rows, width: int, label: str, *, allow_short: bool = False) -> None:
    """Ragged/unterminated rows are errors: every data row must have the header's field count."""
    for row, line in zip(rows.rows, rows.lines):
        n = len(row)
        if n == width:
            continue
        if n > width and not any(c.strip() for c in row[width:]):
            continue  # trailing empty fields
        if n < width and allow_short:
            continue
        raise ConnectorError(f"row has {n} fields but the header has {width}; a ragged or cut-off row "
                             "(fix or delete it)", path=label, line=line)


def _column(rows: list[list[str]], j: int) -> list[str]:
    return [r[j] if j < len(r) else "" for r in rows]


class _Columns:
    """Column access to rows, transposed once when every row is long enough."""

    def __init__(self, rows: list[list[str]], width: int) -> None:
        self.rows = rows
        self.cols = list(zip(*rows)) if rows and min(map(len, rows)) >= width else None

    def __call__(self, j: int) -> list[str]:
        if self.cols is not None and j < len(self.cols):
            return list(self.cols[j])
        return _column(self.rows, j)


def _decimal_comma(rows: list[list[str]], cols: list[int], delimiter: str) -> bool:
    sample = rows[:: max(1, len(rows) // 100)][:100]
    cells = [r[j] for r in sample for j in cols if j < len(r)]
    return detect_decimal_comma(cells) if (delimiter != "," or any("," in c for c in cells)) else False


def _times(cells: list[str], lines: list[int], label: str, column: str, options: dict) -> tuple[np.ndarray, bool, str]:
    pt = parse_times(cells, tz=options.get("tz"), dst=options.get("dst", "infer"), label=label,
                     column=column, lines=lines)
    return pt.seconds, pt.absolute, pt.fmt


def _series_from_column(name: str, t: np.ndarray | None, cells: list[str], decimal_comma: bool,
                        first_line: int | None) -> Series:
    num = to_numbers(cells, decimal_comma)
    return Series(name=name, t=t, x=num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                  n_blank=num.n_blank, examples=num.examples, first_line=first_line, column=name,
                  cells=cells if num.n_text else None)


# ---------------------------------------------------------------------------------------------- wide

def parse_wide(text: Text, options: dict, *, rows: Rows | None = None, delimiter: str | None = None,
               fmt: str = "wide", extra_meta: dict | None = None) -> Table:
    """A header row, one or two time columns (date + time), one column per signal."""
    label = text.label
    if rows is None:
        rows, delimiter = _prepare(text)
    if not rows.rows:
        raise ConnectorError("file is empty", path=label)
    header = [h.strip().strip('"').strip() for h in rows.rows[0]]
    body, lines = rows.rows[1:], rows.lines[1:]
    if not body:
        raise ConnectorError("header only, no data rows", path=label, line=rows.lines[0])
    if len(header) < 2:
        raise ConnectorError(f"only one column ({header[0]!r}) with separator "
                             f"{delimiter_name(delimiter or ',')}; need a time/OP/PV column each",
                             path=label, line=rows.lines[0])
    _check_rect(Rows(body, lines), len(header), label)
    col = _Columns(body, len(header))
    lower = [h.lower() for h in header]
    ts_col = options.get("ts")
    time_idx: list[int] = []
    if ts_col:
        if ts_col not in header:
            raise ConnectorError(f"no column named {ts_col!r} for the time (columns: {', '.join(header)})",
                                 path=label, line=rows.lines[0])
        time_idx = [header.index(ts_col)]
    elif _date_time_pair(lower):
        time_idx = _date_time_pair(lower)
    else:
        named = [j for j, h in enumerate(header) if _is_time_header(h) and role_of(h) is None
                 or h.lower() in TIME_NAMES]
        if named:
            rel = {"t", "ts", "t_s", "time_s"}
            named.sort(key=lambda j: lower[j] in rel)  # a calendar column beats a seconds column
            time_idx = [named[0]]
        elif role_of(header[0]) is None and body[0][0].strip():
            try:
                parse_times([body[0][0]])
                if not re.fullmatch(r"[+-]?[\d.eE+-]+", body[0][0].strip()):
                    time_idx = [0]
            except ConnectorError:
                pass
    t = None
    absolute = False
    tfmt = None
    if time_idx:
        if len(time_idx) == 2:
            cells = [f"{a.strip()} {b.strip()}".strip() for a, b in zip(col(time_idx[0]), col(time_idx[1]))]
            tname = f"{header[time_idx[0]]}+{header[time_idx[1]]}"
        else:
            cells = col(time_idx[0])
            tname = header[time_idx[0]]
        t, absolute, tfmt = _times(cells, lines, label, tname, options)
    value_idx = [j for j in range(len(header)) if j not in time_idx and lower[j] not in SKIP_HEADERS
                 and not (lower[j] in TIME_HEADERS and role_of(header[j]) in (None, "time"))]
    dec = _decimal_comma(body, value_idx, delimiter or ",")
    series = [_series_from_column(header[j], t, col(j), dec, lines[0]) for j in value_idx]
    meta = {"format": fmt, "delimiter": delimiter_name(delimiter or ","), "decimal": "," if dec else ".",
            "encoding": text.encoding, "bom": text.bom, "time_format": tfmt,
            "time_columns": [header[j] for j in time_idx]}
    if extra_meta:
        meta.update(extra_meta)
    return Table(series, label, absolute, meta, raw_columns=header)


# ---------------------------------------------------------------------------------------------- long

def parse_long(text: Text, options: dict) -> Table:
    """``tag, time, value[, quality]`` rows: one row per tag per time."""
    label = text.label
    rows, d = _prepare(text)
    if not rows.rows:
        raise ConnectorError("file is empty", path=label)
    header = [h.strip().strip('"').strip() for h in rows.rows[0]]
    lower = [h.lower() for h in header]
    body, lines = rows.rows[1:], rows.lines[1:]
    if not body:
        raise ConnectorError("header only, no data rows", path=label, line=rows.lines[0])
    _check_rect(Rows(body, lines), len(header), label)
    col = _Columns(body, len(header))
    tag_j = next((j for j, h in enumerate(lower) if h in TAG_HEADERS), None)
    val_j = next((j for j, h in enumerate(lower) if h in VALUE_HEADERS), None)
    if tag_j is None or val_j is None:
        raise ConnectorError(f"long layout needs a tag column and a value column (columns: {', '.join(header)})",
                             path=label, line=rows.lines[0])
    ts_col = options.get("ts")
    if ts_col and ts_col in header:
        time_j = [header.index(ts_col)]
    elif _date_time_pair(lower):
        time_j = _date_time_pair(lower)
    else:
        time_j = [j for j, h in enumerate(header) if _is_time_header(h) and j not in (tag_j, val_j)][:1]
    if not time_j:
        raise ConnectorError(f"long layout without a time column (columns: {', '.join(header)}); "
                             "name it with --ts", path=label, line=rows.lines[0])
    q_j = next((j for j, h in enumerate(lower) if h in QUALITY_HEADERS), None)
    if len(time_j) == 2:
        tcells = [f"{a.strip()} {b.strip()}" for a, b in zip(col(time_j[0]), col(time_j[1]))]
    else:
        tcells = col(time_j[0])
    t, absolute, tfmt = _times(tcells, lines, label, header[time_j[0]], options)
    dec = _decimal_comma(body, [val_j], d)
    num = to_numbers(col(val_j), dec)
    bad_q = np.zeros(len(body), bool)
    scheme = None
    if q_j is not None:
        good, scheme = quality_good(col(q_j), header[q_j])
        bad_q = ~good & np.isfinite(num.values)
    for j, h in enumerate(lower):  # PI flag columns: Questionable / Substituted = True -> bad
        if h in PI_FLAG_HEADERS:
            flag = np.array([c.strip().lower() in ("true", "1", "yes", "y") for c in col(j)])
            bad_q |= flag & np.isfinite(num.values)
            if "pi_flags" not in (scheme or ""):
                scheme = (scheme + "+" if scheme else "") + "pi_flags"
    codes: dict[str, int] = {}
    inverse = np.fromiter((codes.setdefault(c.strip(), len(codes)) for c in col(tag_j)), dtype=np.int64,
                          count=len(body))
    names = list(codes)                                   # in order of first appearance
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(len(names) + 1))
    first_row = {names[g]: int(order[bounds[g]]) for g in range(len(names))}
    vcells = col(val_j)
    series: list[Series] = []
    for g in range(len(names)):
        tag = names[g]
        if not tag:
            continue
        idx = order[bounds[g]:bounds[g + 1]]
        x = num.values[idx].copy()
        bq = bad_q[idx]
        x[bq] = np.nan
        kind = num.kind[idx] if num.kind is not None else None
        n_text = int(np.count_nonzero(kind == 2)) if kind is not None else 0
        examples: list[str] = []
        if n_text:
            seen: dict[str, int] = {}
            for k in idx[kind == 2][:1000]:
                c = vcells[k].strip()[:30]
                seen[c] = seen.get(c, 0) + 1
            examples = [k for k, _ in sorted(seen.items(), key=lambda kv: -kv[1])[:4]]
        series.append(Series(str(tag), t[idx], x, n_text=n_text,
                             n_nonfinite=int(np.count_nonzero(kind == 3)) if kind is not None else 0,
                             n_bad_quality=int(np.count_nonzero(bq)),
                             n_blank=int(np.count_nonzero(kind == 1)) if kind is not None else 0,
                             examples=examples, first_line=lines[first_row[tag]], column=header[val_j],
                             cells=[vcells[k] for k in idx] if n_text else None))
    meta = {"format": "long", "delimiter": delimiter_name(d), "decimal": "," if dec else ".",
            "encoding": text.encoding, "bom": text.bom, "time_format": tfmt, "quality_scheme": scheme}
    return Table(series, label, absolute, meta, raw_columns=header)


# -------------------------------------------------------------------------------------------- ragged

def parse_ragged(text: Text, options: dict) -> Table:
    """PI DataLink compressed data: ``time, value`` column pairs, one pair per tag.

    The tag name is the value column's header, or (two header rows) the cell above the pair.
    """
    label = text.label
    rows, d = _prepare(text)
    if len(rows.rows) < 2:
        raise ConnectorError("header only, no data rows", path=label)
    h0 = [h.strip().strip('"').strip() for h in rows.rows[0]]
    h1 = [h.strip().strip('"').strip() for h in rows.rows[1]]
    two_rows = _pairs([h.lower() for h in h1]) and not _pairs([h.lower() for h in h0])
    header = h1 if two_rows else h0
    body, lines = (rows.rows[2:], rows.lines[2:]) if two_rows else (rows.rows[1:], rows.lines[1:])
    if not body:
        raise ConnectorError("header only, no data rows", path=label, line=rows.lines[0])
    _check_rect(Rows(body, lines), len(header), label, allow_short=True)
    series: list[Series] = []
    absolute = False
    tfmt = None
    j = 0
    while j < len(header):
        if not _is_time_header(header[j]) or j + 1 >= len(header):
            j += 1
            continue
        if two_rows:
            name = h0[j] or (h0[j + 1] if j + 1 < len(h0) else "")
        else:
            name = header[j + 1]
            if _is_time_header(name):
                j += 1
                continue
        name = name.strip() or f"column{j + 2}"
        tcells = _column(body, j)
        vcells = _column(body, j + 1)
        keep = [k for k, c in enumerate(tcells) if c.strip()]
        if keep:
            tc = [tcells[k] for k in keep]
            tl = [lines[k] for k in keep]
            tt, absolute, tfmt = _times(tc, tl, label, header[j], options)
            dec = _decimal_comma([[vcells[k]] for k in keep], [0], d)
            num = to_numbers([vcells[k] for k in keep], dec)
            series.append(Series(name, tt, num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                                 n_blank=num.n_blank, examples=num.examples, first_line=tl[0],
                                 column=name, cells=[vcells[k] for k in keep] if num.n_text else None))
        j += 2
    if not series:
        raise ConnectorError("no timestamp/value column pairs found for the ragged layout", path=label,
                             line=rows.lines[0])
    meta = {"format": "ragged", "delimiter": delimiter_name(d), "encoding": text.encoding,
            "bom": text.bom, "time_format": tfmt}
    return Table(series, label, absolute, meta, raw_columns=[s.name for s in series])


# -------------------------------------------------------------------------------------------- influx

def parse_influx(text: Text, options: dict) -> Table:
    """InfluxDB annotated CSV (``#datatype``/``#group``/``#default`` rows, ``_time``, ``_value``)."""
    label = text.label
    rows = split_rows(text.text, ",", label)
    header: list[str] | None = None
    groups: dict[str, tuple[list[str], list[str], list[int]]] = {}
    for row, line in zip(rows.rows, rows.lines):
        if row[0].startswith("#"):
            header = None
            continue
        cells = [c.strip() for c in row]
        if header is None or ("_time" in cells and "_value" in cells):
            header = cells
            if "_time" not in header or "_value" not in header:
                raise ConnectorError("InfluxDB CSV table without _time and _value columns", path=label,
                                     line=line)
            continue
        if len(cells) != len(header):
            raise ConnectorError(f"row has {len(cells)} fields but the table header has {len(header)}",
                                 path=label, line=line)
        rec = dict(zip(header, cells))
        tagcols = [h for h in header if h and not h.startswith("_") and h not in ("result", "table")]
        base = ".".join(rec[h] for h in tagcols if rec[h]) or rec.get("_measurement", "")
        name = f"{base}.{rec['_field']}" if base and rec.get("_field") else (rec.get("_field") or base or "value")
        g = groups.setdefault(name, ([], [], []))
        g[0].append(rec["_time"])
        g[1].append(rec["_value"])
        g[2].append(line)
    if not groups:
        raise ConnectorError("InfluxDB CSV without data rows", path=label)
    series = []
    absolute, tfmt = True, None
    for name, (tc, vc, ln) in groups.items():
        tt, absolute, tfmt = _times(tc, ln, label, "_time", options)
        num = to_numbers(vc)
        series.append(Series(name, tt, num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                             n_blank=num.n_blank, examples=num.examples, first_line=ln[0], column=name))
    meta = {"format": "influx", "delimiter": "comma", "encoding": text.encoding, "bom": text.bom,
            "time_format": tfmt}
    return Table(series, label, absolute, meta, raw_columns=list(groups))


# ----------------------------------------------------------------------------------------------- dcs

def parse_dcs(text: Text, options: dict) -> Table:
    """The DCS text export: ``PROCESSDATA`` line, ``<cols> <Ts> <start> <N>``, tag names,
    descriptions, a parameter line, then tab-separated rows (``<tag>.MV`` is the controller output)."""
    label = text.label
    lines = text.text.splitlines()
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
    body = split_rows("\n".join(lines[start:]), "\t", label, start_line=start + 1)
    rows = Rows([names] + body.rows, [tag_line + 1] + body.lines)
    table = parse_wide(text, options, rows=rows, delimiter="\t", fmt="dcs",
                       extra_meta={"dcs_header": lines[0].strip()[:80]})
    table.ts_s = ts_s if ts_s and ts_s > 0 else None
    return table


PARSERS = {"wide": parse_wide, "long": parse_long, "ragged": parse_ragged, "influx": parse_influx,
           "dcs": parse_dcs}


def parse(text: Text, options: dict) -> Table:
    """Detect (or take ``options['fmt']``) and run the layout parser."""
    if not text.text.strip():
        raise ConnectorError("file is empty", path=text.label)
    fmt = options.get("fmt") or options.get("format")
    if fmt in (None, "auto"):
        fmt = detect_layout(text)
    elif fmt not in PARSERS:
        raise ConnectorError(f"unknown format {fmt!r}; choose one of auto, {', '.join(LAYOUTS)}")
    return PARSERS[fmt](text, options)
