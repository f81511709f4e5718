"""Getting a table out of a source: the file or stream, its encoding, the separator, pandas' parser.

`open_source` looks at a path or file object once: Excel and binary files are refused, the
encoding is found (BOM, else UTF-8, else cp1252, else latin-1: the whole file must decode), and
the first part of the text is kept for layout detection. `read_frame` hands the rest to
`pandas.read_csv` (C engine) with positional columns, so that repeated headers (``Timestamp``
twice in a PI DataLink export) stay apart, and maps its errors to one-line `ConnectorError`\\ s
with the file line. `numbers` turns a column into floats and says which cells were text states,
blanks or NaN/inf; `quality_good` reads the vendors' quality-flag schemes.
"""

from __future__ import annotations

import codecs
import csv
import io
import os
import re
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd

from diagnose.errors import ConnectorError

DELIMITERS = "\t;,|"
_NAMES = {"\t": "tab", ";": "semicolon", ",": "comma", "|": "pipe"}
#: Bytes read for layout detection (always at least 65 536 characters of text).
HEAD_BYTES = 1 << 18
#: Sources at least this large report their progress on stderr unless told otherwise.
PROGRESS_MIN_BYTES = 32 << 20
_CHUNK = 1 << 22
csv.field_size_limit(1 << 24)


# ----------------------------------------------------------------------------------------- progress

class Progress:
    """Progress lines for one source: ``sink(line)`` at most every `every_s` seconds while reading.

    ``sink`` is a callable taking one line of text, ``True`` (stderr), ``False`` (silent) or
    ``None`` (stderr for sources of `PROGRESS_MIN_BYTES` or more).
    """

    def __init__(self, label: str, total: int, sink: Any = None, every_s: float = 2.0) -> None:
        if sink is None:
            sink = total >= PROGRESS_MIN_BYTES
        if sink is True:
            sink = _stderr_line
        self.sink: Callable[[str], None] | None = sink or None
        self.label, self.total, self.every_s = label, total, every_s
        self.t0 = self.last = time.perf_counter()

    def __bool__(self) -> bool:
        return self.sink is not None

    def say(self, message: str) -> None:
        if self.sink is not None:
            self.sink(f"{self.label}: {message} ({time.perf_counter() - self.t0:.1f} s)")
            self.last = time.perf_counter()

    def rows_read(self, rows: int, done: int | None) -> None:
        """After each chunk pandas parsed: rows so far and, for files, bytes read."""
        if self.sink is None or time.perf_counter() - self.last < self.every_s:
            return
        where = f", {done / 1e6:.0f} of {self.total / 1e6:.0f} MB ({100.0 * done / self.total:.0f} %)" \
            if done is not None and self.total else ""
        self.say(f"reading, {rows} rows{where}")


def _stderr_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class _Counting(io.RawIOBase):
    """A binary file that counts the bytes pandas has read from it (``done``)."""

    def __init__(self, fh) -> None:
        self.fh, self.done = fh, 0

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        n = self.fh.readinto(b)
        self.done += n or 0
        return n

    def close(self) -> None:
        self.fh.close()
        super().close()


# ------------------------------------------------------------------------------------------- source

@dataclass
class Source:
    """One file or stream, opened: how it decodes and the start of its text.

    ``data`` holds the whole content for file objects and small files (``None``: read ``path``
    again when parsing). ``head`` is the decoded start of the text without the BOM.
    """

    label: str
    path: str | None
    data: bytes | str | None
    head: str
    encoding: str
    bom: bool
    size: int
    complete: bool
    progress: Progress = field(default=None)  # type: ignore[assignment]
    _found: set[str] | None = None
    _delimiter: str | None = None

    @property
    def delimiter(self) -> str:
        """The separator of a delimited export (`sniff_delimiter` on its first lines, ``#`` lines left out)."""
        if self._delimiter is None:
            head = self.head[:20000].splitlines()
            self._delimiter = sniff_delimiter([ln for ln in head if not ln.startswith("#")])
        return self._delimiter

    @property
    def pandas_encoding(self) -> str | None:
        """The codec to name to pandas (None: its default, UTF-8, which also drops a UTF-8 BOM)."""
        return None if self.encoding in ("str", "utf-8") else self.encoding

    def buffer(self):
        """A fresh file object for pandas (text for str sources, else binary)."""
        if isinstance(self.data, str):
            return io.StringIO(self.data[1:] if self.data.startswith("\ufeff") else self.data)
        if isinstance(self.data, bytes):
            return io.BytesIO(self.data)
        fh = open(self.path, "rb")  # noqa: SIM115 - closed by pandas / the caller
        return io.BufferedReader(_Counting(fh)) if self.progress else fh

    def contains(self, char: str) -> bool:
        """Whether ``char`` (a double quote or ``#``) occurs anywhere in the source."""
        if self._found is None:
            probes = ('"', "#")
            if isinstance(self.data, str):
                self._found = {c for c in probes if c in self.data}
            else:
                raw = {c: c.encode(self.encoding) for c in probes}
                found: set[str] = set()
                if self.encoding == "utf-16":
                    found = set(probes)
                elif isinstance(self.data, bytes):
                    found = {c for c, b in raw.items() if b in self.data}
                else:
                    with open(self.path, "rb") as fh:
                        while (chunk := fh.read(_CHUNK)) and len(found) < len(raw):
                            found |= {c for c, b in raw.items() if b in chunk}
                self._found = found
        return char in self._found

    def lines(self, wanted: set[int]) -> dict[int, str]:
        """Raw text of the given 1-based file lines (universal newlines, as pandas counts them)."""
        out: dict[int, str] = {}
        if not wanted:
            return out
        last = max(wanted)
        raw = self.buffer()
        text = raw if isinstance(raw, io.StringIO) else io.TextIOWrapper(
            raw, encoding="utf-8-sig" if self.encoding == "utf-8" else self.encoding, newline=None)
        with text:
            for k, line in enumerate(text, start=1):
                if k in wanted:
                    out[k] = line.rstrip("\n")
                if k >= last:
                    break
        return out


def _strip_bom(text: str) -> str:
    return text[1:] if text.startswith("\ufeff") else text


def open_source(source: Any, progress: Any = None) -> Source:
    """Open a path or file object (text or binary) and find its encoding."""
    if hasattr(source, "read"):
        label = str(getattr(source, "name", "<stream>"))
        try:
            raw = source.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise ConnectorError(f"cannot read: {exc}", path=label) from None
        if isinstance(raw, str):
            src = Source(label, None, raw, _strip_bom(raw), "str", raw.startswith("\ufeff"), len(raw), True)
        else:
            raw = bytes(raw)
            enc, bom = _codec(raw[:HEAD_BYTES], lambda: [raw], label)
            src = Source(label, None, raw, _strip_bom(raw.decode(enc)), enc, bom, len(raw), True)
    else:
        path = os.fspath(source)
        label = path
        if not os.path.exists(path):
            raise ConnectorError("file not found", path=label)
        if os.path.isdir(path):
            raise ConnectorError("is a folder, not a file", path=label)
        try:
            size = os.path.getsize(path)
            with open(path, "rb") as fh:
                head = fh.read(HEAD_BYTES)
            complete = len(head) < HEAD_BYTES
            enc, bom = _codec(head, (lambda: [head]) if complete else (lambda: _chunks(path)), label)
        except ConnectorError:  # _codec's own verdict on the content, which names the file already
            raise
        except OSError as exc:
            raise ConnectorError(f"cannot read: {exc.strerror or exc}", path=label) from None
        text = codecs.getincrementaldecoder(enc)().decode(head, final=complete)
        src = Source(label, path, head if complete else None, _strip_bom(text), enc, bom, size, complete)
    sample = src.head[:65536]
    if "\x00" in sample or _mostly_control(sample):
        raise ConnectorError("looks like a binary file, not a text export; export the data as CSV/text",
                             path=label)
    src.progress = Progress(label, src.size, progress)
    return src


def _chunks(path: str):
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            yield chunk


def _codec(head: bytes, chunks, label: str) -> tuple[str, bool]:
    """(codec, BOM) of a source: by its BOM, else the first of UTF-8 and cp1252 that decodes all
    of it (``chunks()`` yields its bytes from the start), else latin-1 (which decodes anything)."""
    if head.startswith(b"PK\x03\x04"):
        raise ConnectorError("is a zip/Excel (.xlsx) file, not a text export; save it as CSV", path=label)
    if head.startswith(b"\xd0\xcf\x11\xe0"):
        raise ConnectorError("is an old Excel (.xls) file, not a text export; save it as CSV", path=label)
    bom = head.startswith((b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff"))
    if bom:
        candidates = ["utf-8"] if head.startswith(b"\xef") else ["utf-16"]
    elif b"\x00" in head[:65536]:
        raise ConnectorError("looks like a binary file, not a text export; export the data as CSV/text",
                             path=label)
    else:
        candidates = ["utf-8", "cp1252"]
    for enc in candidates:
        dec, pos = codecs.getincrementaldecoder(enc)(), 0
        try:
            for chunk in chunks():
                dec.decode(chunk)
                pos += len(chunk)
            dec.decode(b"", final=True)
            return enc, bom
        except UnicodeDecodeError as exc:
            if enc == "utf-8" and bom:
                raise ConnectorError(f"has a UTF-8 BOM but invalid UTF-8 at byte {pos + exc.start}",
                                     path=label) from None
            if bom:
                raise ConnectorError("has a UTF-16 BOM but is not valid UTF-16", path=label) from None
    return "latin-1", False


_CONTROL = re.compile("[\x00-\x08\x0e-\x1f\x7f-\x9f]")


def _mostly_control(text: str) -> bool:
    if not text:
        return False
    return len(_CONTROL.findall(text)) > 0.05 * len(text)


# ---------------------------------------------------------------------------------------- separator

def sniff_delimiter(lines: list[str]) -> str:
    """The separator whose count is the same on most lines (header included).

    Not `csv.Sniffer` (what ``pandas.read_csv(sep=None)`` uses): it gives up on exports whose rows
    hold text states or a cut-off line, where the commonest count still tells.
    """
    sample = [ln for ln in lines[:60] if ln.strip()]
    if not sample:
        return ","
    best, best_score = ",", -1.0
    for d in DELIMITERS:
        counts = [_count_outside_quotes(ln, d) for ln in sample]
        if max(counts) == 0:
            continue
        mode = max(set(counts), key=counts.count)
        if mode == 0:
            continue
        score = counts.count(mode) / len(counts) + 0.001 * mode
        if score > best_score + 1e-9:
            best, best_score = d, score
    return best


def _count_outside_quotes(line: str, d: str) -> int:
    if '"' not in line:
        return line.count(d)
    n, q = 0, False
    for c in line:
        if c == '"':
            q = not q
        elif c == d and not q:
            n += 1
    return n


def delimiter_name(d: str) -> str:
    return _NAMES.get(d, repr(d))


def split_line(line: str, delimiter: str) -> list[str]:
    """The fields of one row of text (quotes respected; the row may span lines)."""
    try:
        return next(csv.reader(io.StringIO(line), delimiter=delimiter), [])
    except csv.Error:
        return line.split(delimiter)


# -------------------------------------------------------------------------------------------- frame

@dataclass
class Frame:
    """Rows of a file as parsed by pandas: one array per column (float64 where pandas read numbers,
    else object: text, NaN where empty) and the file line where each row ends."""

    columns: list[np.ndarray]
    lines: np.ndarray

    def __len__(self) -> int:
        return int(self.lines.size)


_EXPECTED = re.compile(r"Expected (\d+) fields in line (\d+), saw (\d+)")
_EOF_QUOTE = re.compile(r"EOF inside string starting at row (\d+)")


def read_frame(src: Source, *, sep: str, skiprows: int, width: int, decimal: str = ".",
               str_columns: tuple[int, ...] = (), allow_short: bool = False,
               drop_comments: bool = True) -> Frame:
    """Parse the rows after the first ``skiprows`` lines into ``width`` positional columns.

    Blank rows (and ``#`` comment rows) are dropped. A row with more fields than ``width`` is an
    error unless the extra fields are empty (trailing separators); a row with fewer is an error
    unless ``allow_short``. Numbers with a decimal comma need ``decimal=","``. Columns in
    ``str_columns`` are kept as text.
    """
    names = list(range(width))
    for _ in range(8):
        try:
            cols = _read_csv(src, sep, skiprows, names, decimal, str_columns)
            break
        except _TooWide as exc:
            names = list(range(max(exc.saw, len(names) + 1)))
    else:
        raise ConnectorError(f"rows have more fields than the header ({width}); fix or delete them",
                             path=src.label)
    n = cols[0].size
    lines = skiprows + 1 + np.arange(n)               # the file line where each row ends
    spans = None
    if n and src.contains('"'):                       # quoted cells may hold line breaks
        breaks = np.zeros(n, np.int64)
        for c in cols:
            if c.dtype == object:
                breaks = breaks + np.array([v.count("\n") + v.count("\r") - v.count("\r\n")
                                            if isinstance(v, str) else 0 for v in c], dtype=np.int64)
        if breaks.any():
            lines = lines + np.cumsum(breaks)
            spans = breaks
    if n:
        keep = ~_blank_rows(cols)
        if drop_comments and src.contains("#") and cols[0].dtype == object:
            keep &= ~np.array([isinstance(v, str) and v.startswith("#") for v in cols[0]], dtype=bool)
        if not keep.all():
            cols = [c[keep] for c in cols]
            lines = lines[keep]
            spans = spans[keep] if spans is not None else None
    wide_line = None
    if len(names) > width:       # more fields than the header: fine where the extra ones are empty
        blank = np.stack([_blank(c) for c in cols[width:]], axis=1)
        filled = np.flatnonzero(~blank.all(axis=1))
        if filled.size:
            k = int(filled[0])
            wide_line = (int(lines[k]), width + int(np.flatnonzero(~blank[k])[-1]) + 1)
        cols = cols[:width]
    short_line = None
    if not allow_short and width > 1 and lines.size:
        short_line = _short_row(src, cols[width - 1], lines, spans, sep, width,
                                before=wide_line[0] if wide_line else None)
    bad = min((p for p in (wide_line, short_line) if p), default=None)
    if bad:
        raise ConnectorError(f"row has {bad[1]} fields but the header has {width}; a ragged or cut-off row "
                             "(fix or delete it)", path=src.label, line=bad[0])
    return Frame(cols, lines)


class _TooWide(Exception):
    def __init__(self, line: int, saw: int) -> None:
        self.line, self.saw = line, saw


#: Rows pandas parses at a time (progress is reported between chunks).
CHUNK_ROWS = 500_000


def _read_csv(src: Source, sep: str, skiprows: int, names: list[int], decimal: str,
              str_columns: tuple[int, ...]) -> list[np.ndarray]:
    """The columns of the rows after ``skiprows`` lines: float64 arrays where pandas read numbers
    in every chunk, else object arrays (text; NaN where empty)."""
    dtype = {j: str for j in str_columns if j < len(names)} or None
    kwargs = dict(sep=sep, header=None, names=names, skiprows=skiprows, skip_blank_lines=False,
                  index_col=False, keep_default_na=False, na_values=[""], decimal=decimal, dtype=dtype,
                  engine="c", encoding=src.pandas_encoding, quotechar='"', chunksize=CHUNK_ROWS)
    parts: list[list[np.ndarray]] = [[] for _ in names]
    booleans: set[int] = set()
    try:
        with src.buffer() as fh, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", pd.errors.ParserWarning)
            rows = 0
            for chunk in pd.read_csv(fh, **kwargs):
                if caught and any(issubclass(w.category, pd.errors.ParserWarning) for w in caught):
                    # the first row is wider than the names: pandas would drop its extra fields silently
                    raise _TooWide(skiprows + 1, _first_row_width(src, sep, skiprows, len(names)))
                for j, (_, col) in enumerate(chunk.items()):
                    if col.dtype == bool:
                        booleans.add(j)
                    elif col.dtype.kind in "fiu":
                        parts[j].append(np.array(col.to_numpy(dtype=float), dtype=float))
                    else:
                        parts[j].append(np.array(col.to_numpy(dtype=object, na_value=np.nan), dtype=object))
                rows += len(chunk)
                done = getattr(fh, "raw", None)
                src.progress.rows_read(rows, getattr(done, "done", None))
    except pd.errors.EmptyDataError:
        return [np.zeros(0, object) for _ in names]
    except pd.errors.ParserError as exc:
        msg = str(exc).strip()
        m = _EXPECTED.search(msg)
        if m:
            raise _TooWide(int(m.group(2)), int(m.group(3))) from None
        m = _EOF_QUOTE.search(msg)
        if m:
            raise ConnectorError("malformed CSV (unexpected end of data); an unterminated quote or a "
                                 "cut-off row?", path=src.label, line=int(m.group(1)) + 1) from None
        raise ConnectorError(f"malformed CSV ({msg.splitlines()[-1][:120]})", path=src.label) from None
    except (UnicodeDecodeError, ValueError, OverflowError) as exc:
        raise ConnectorError(f"cannot parse: {str(exc).splitlines()[0][:120]}", path=src.label) from None
    if booleans:   # pandas reads True/False columns as booleans: read them as the text they are
        return _read_csv(src, sep, skiprows, names, decimal, tuple(set(str_columns) | booleans))
    cols = []
    for p in parts:
        if not p:
            cols.append(np.zeros(0, float))
        elif len(p) == 1:
            cols.append(p[0])
        elif all(a.dtype == float for a in p):
            cols.append(np.concatenate(p))
        else:
            cols.append(np.concatenate([a.astype(object) for a in p]))
    return cols


def _first_row_width(src: Source, sep: str, skiprows: int, at_least: int) -> int:
    """Fields of the first non-blank row after ``skiprows`` lines (more than ``at_least``)."""
    k = skiprows + 1
    while True:
        got = src.lines(set(range(k, k + 100)))
        if not got:
            return at_least + 1
        for j in sorted(got):
            if got[j].strip():
                return max(at_least + 1, len(split_line(got[j], sep)))
        k += 100


def _blank(col: np.ndarray) -> np.ndarray:
    """Empty or white-space cells of a column."""
    if col.dtype != object:
        return np.isnan(col)
    return np.array([not isinstance(v, str) or not v.strip() for v in col], dtype=bool)


def _blank_rows(cols: list[np.ndarray]) -> np.ndarray:
    """Rows whose every cell is empty or white space (pandas keeps them with ``skip_blank_lines=False``)."""
    cand = np.ones(cols[0].size, bool)
    text = []
    for c in cols:
        if c.dtype == object:
            text.append(c)
        else:
            cand &= np.isnan(c)
    idx = np.flatnonzero(cand)
    for c in text:
        if not idx.size:
            break
        idx = idx[_blank(c[idx])]
    out = np.zeros(cand.size, bool)
    out[idx] = True
    return out


def _short_row(src: Source, last: np.ndarray, lines: np.ndarray, spans: np.ndarray | None, sep: str,
               width: int, before: int | None = None) -> tuple[int, int] | None:
    """The first row with fewer fields than ``width`` (line, fields), or None.

    pandas fills a short row's missing cells with NaN, as it does empty cells: a row whose last
    cell is empty is looked up in the file itself and its fields counted.
    """
    cand = np.array(pd.isna(last), dtype=bool)
    if before is not None:
        cand &= lines < before
    rows = np.flatnonzero(cand)
    if not rows.size:
        return None
    first = lines[rows] - (spans[rows] if spans is not None else 0)
    raw = src.lines({int(k) for a, b in zip(first, lines[rows]) for k in range(a, b + 1)})
    for a, b in zip(first, lines[rows]):
        text = "\n".join(raw.get(int(k), "") for k in range(a, b + 1))
        n = len(split_line(text, sep))
        if n < width:
            return int(b), n
    return None


# ------------------------------------------------------------------------------------------ numbers

_DEC_COMMA = re.compile(r"^\s*[+-]?\d[\d.]*,\d+([eE][+-]?\d+)?\s*$")
_THOUSANDS = re.compile(r"^[+-]?\d{1,3}(,\d{3})+(\.\d+)?$")
_DEC_DOT = re.compile(r"^\s*[+-]?\d*\.\d+([eE][+-]?\d+)?\s*$")


def detect_decimal_comma(cells: list[str]) -> bool:
    """True when numbers are written with a decimal comma (``12,5``)."""
    comma = dot = 0
    for c in cells:
        if _DEC_COMMA.match(c):
            comma += 1
        elif _DEC_DOT.match(c):
            dot += 1
    return comma > dot


@dataclass
class Numbers:
    """A numeric column: values (NaN where bad/blank) and what was wrong.

    ``kind`` (only when something was wrong) marks each cell: 0 number, 1 blank, 2 text,
    3 NaN/inf. ``text`` holds the column's cells (object array) when some were text (mode states
    are read from it).
    """

    values: np.ndarray
    n_blank: int
    n_text: int
    n_nonfinite: int
    examples: list[str]
    kind: np.ndarray | None = None
    text: np.ndarray | None = None


def _classify(cell: str) -> tuple[float, int]:
    """Value and kind (0 number, 1 blank, 2 text, 3 NaN/inf) of one cell pandas did not read."""
    try:
        v = float(cell)
        return v, 0 if np.isfinite(v) else 3
    except (ValueError, OverflowError):
        s = cell.strip()
        if _THOUSANDS.match(s):
            return float(s.replace(",", "")), 0
        return np.nan, 1 if not s else 2


def numbers(col: Any, decimal_comma: bool = False) -> Numbers:
    """Floats from a parsed column; text states, blanks and NaN/inf become NaN and are counted.

    ``col`` is a float array (pandas read numbers: NaN means an empty cell) or an object array
    (text, NaN where empty). Text that Python's ``float`` reads is a number; so is ``1,234.5``
    (thousands commas). With a decimal comma, cells with a comma lose their dots (thousands) and
    the comma becomes the point.
    """
    col = np.asarray(col.to_numpy() if isinstance(col, pd.Series) else col)
    if col.dtype.kind not in "fiuO":
        col = col.astype(object)
    if col.dtype != object:
        vals = np.array(col, dtype=float)
        fin = np.isfinite(vals)
        if fin.all():
            return _numbers(vals, None, [], None)
        kind = np.where(np.isnan(vals), 1, np.where(fin, 0, 3)).astype(np.int8)   # NaN: an empty cell
        return _numbers(np.where(fin, vals, np.nan), kind, [], None)
    if decimal_comma or not any(_is_number(c) for c in col[:: max(1, col.size // 50)][:50]):
        vals = np.full(col.size, np.nan)  # text (or decimal commas): every cell goes through the rules below
    else:
        vals = np.array(pd.to_numeric(col, errors="coerce"), dtype=float)
    kind = np.where(np.isfinite(vals), 0, 3).astype(np.int8)
    miss = np.flatnonzero(np.isnan(vals))
    examples: list[str] = []
    textual = None
    if miss.size:
        # what pandas did not read, one distinct cell at a time: Python's float (nan, 1_000...),
        # thousands commas, decimal commas, blanks or text states
        codes, uniq = pd.factorize(col[miss], use_na_sentinel=False)
        looked = [_classify(_decimal(u) if decimal_comma else u) if isinstance(u, str) else _value(u)
                  for u in uniq]
        vals[miss] = np.array([v for v, _ in looked], dtype=float)[codes]
        u_kind = np.array([k for _, k in looked], dtype=np.int8)
        kind[miss] = u_kind[codes]
        if (u_kind == 2).any():
            counts = np.bincount(codes, minlength=len(uniq))
            tally: dict[str, int] = {}
            for u, k, n in zip(uniq, u_kind, counts):
                if k == 2:
                    key = u.strip()[:30]
                    tally[key] = tally.get(key, 0) + int(n)
            examples = [u for u, _ in sorted(tally.items(), key=lambda kv: -kv[1])[:4]]
            textual = col
    if not kind.any():
        return _numbers(vals, None, [], None)
    vals = np.where(kind == 0, vals, np.nan)
    return _numbers(vals, kind, examples, textual)


def _value(cell: Any) -> tuple[float, int]:
    """Value and kind of a cell that is not text: empty (NaN, None) or a number pandas read."""
    try:
        v = float(cell)
    except (TypeError, ValueError, OverflowError):
        return np.nan, 2
    return (v, 0) if np.isfinite(v) else (np.nan, 1) if v != v else (v, 3)


def _is_number(cell: Any) -> bool:
    try:
        float(cell)
        return True
    except (ValueError, TypeError, OverflowError):
        return False


def comma_times(cells: list[str]) -> list[str] | None:
    """Time cells written as numbers with a decimal comma (Excel serial days ``46023,5``) with a
    decimal point, or None when the first of them is not such a number (calendar times such as
    ``27.11.2024 23:59:00,000`` keep their comma for the time parser)."""
    first = next((c for c in cells if c.strip()), "")
    if not _DEC_COMMA.match(first):
        return None
    return [_decimal(c) for c in cells]


def _decimal(cell: str) -> str:
    """``1.234,5`` -> ``1234.5``; a cell without a comma is left as it is."""
    return cell.replace(".", "").replace(",", ".") if "," in cell else cell


def _numbers(vals, kind, examples, text) -> Numbers:
    if kind is None:
        return Numbers(vals, 0, 0, 0, examples, None, text)
    return Numbers(vals, int(np.count_nonzero(kind == 1)), int(np.count_nonzero(kind == 2)),
                   int(np.count_nonzero(kind == 3)), examples, kind, text)


def commonest(cells: Any, k: int = 4) -> list[str]:
    """The ``k`` commonest stripped texts (first 30 characters), ties in order of appearance."""
    codes, uniq = pd.factorize(np.asarray(cells, dtype=object))
    counts = np.bincount(codes[codes >= 0], minlength=len(uniq))
    tally: dict[str, int] = {}
    for u, n in zip(uniq, counts):
        key = str(u).strip()[:30]
        tally[key] = tally.get(key, 0) + int(n)
    return [u for u, _ in sorted(tally.items(), key=lambda kv: -kv[1])[:k]]


# ------------------------------------------------------------------------------------------ quality

_GOOD_TEXT = {"good", "ok", "valid", "g", "normal", "true", "good [non-specific]"}


def quality_good(cells: Any, column: str) -> tuple[np.ndarray, str]:
    """Which rows a quality column marks good, and the scheme used.

    Schemes: text (``Good``/``Bad``/``Questionable``/``Substituted``/``Uncertain``: only ``Good``
    passes), OPC (0-255, good when the two top bits are set: 192..255), IP.21 status (0 good, 1
    suspect, 2 bad), PHD confidence (0-100, good at 50 or above), WinCC ``Validity`` (1 good). The column name decides when the
    numbers fit several schemes (``status`` -> IP.21, ``conf`` -> PHD, ``quality`` -> OPC).
    """
    name = column.lower()
    col = np.asarray(cells.to_numpy() if isinstance(cells, pd.Series) else list(cells)
                     if not isinstance(cells, np.ndarray) else cells)
    if col.dtype != object and col.dtype.kind in "fiu":
        nums = np.array(col, dtype=float)
        blank = np.isnan(nums)
    else:
        text = [v if isinstance(v, str) else "" if v is None or v != v else str(v) for v in col]
        blank = np.array([not c.strip() for c in text], dtype=bool)
        try:
            nums = np.full(len(text), np.nan)
            nums[~blank] = np.array([c for c, b in zip(text, blank) if not b], dtype=float)
        except (ValueError, TypeError, OverflowError):
            low = [c.strip().lower() for c in text]
            return np.array([c in _GOOD_TEXT or c.startswith("good") or not c for c in low], dtype=bool), "text"
    if blank.all():
        return blank, "text"
    good, scheme = _numeric_quality(nums, name)
    return good | blank, scheme      # an empty quality cell flags nothing


def _numeric_quality(nums: np.ndarray, name: str) -> tuple[np.ndarray, str]:
    fin = nums[np.isfinite(nums)]
    vals = set(np.unique(fin).tolist()) if fin.size else set()
    if "conf" in name:
        return nums >= 50, "phd_confidence"
    if "validity" in name:      # Siemens WinCC archive exports: 1 valid, 0 not
        return nums == 1, "wincc_validity"
    if "status" in name or (vals and vals <= {0.0, 1.0, 2.0} and "quality" not in name):
        return nums == 0, "ip21_status"
    if fin.size and fin.max() >= 64 and fin.max() <= 255 and np.all(fin == np.round(fin)):
        q = np.where(np.isfinite(nums), nums, 0).astype(np.int64)
        return (q & 0xC0) == 0xC0, "opc"
    if "quality" in name and vals <= {0.0, 192.0}:
        return nums == 192, "opc"
    return (nums >= 50) & (nums <= 100), "phd_confidence"
